"""Which of prior, kernel and sampler sets the deficit answer on the thesis's 'weak' participant (issue 31 item 2),
and the decision's step time.

'weak' (Table 5.3 f_a: mf at 39% of f'_base) and 'norm' (mf at 158%), forces = the model's maximum force of f_a in
every direction (exact, as the thesis's simulated sets), optionally with 5% log-normal noise. Every test in the
directions' file order. One setting changed at a time from the shipped decision (``clinician.decision``), each run
with ``--seeds`` independent candidate sets (streams 'bench_decision/<variant>' + seed index), so the spread between
seeds shows the Monte Carlo error next to the effect of the setting. Also the session's earlier answer: P(deficit)
on the joint posterior (kernel 10%, the thesis's prior, fresh-draw resampling).

    python benchmarks/bench_decision.py --seeds 3 [--noisy] [--out docs/figures/bench_decision.csv]

Prints one row per variant and data set: log Bayes factor per seed, their mean and spread, P(deficit) at the
shipped prevalence, and per-step times (median / max) of the shipped decision.
"""

from __future__ import annotations

import argparse
import platform
import time
from dataclasses import replace

import numpy as np
import pandas as pd


def main() -> int:
    from neckstrength.config import (build_directions, decision_settings, derive_rng, full_model_from_config,
                                     joint_settings, load_config, model_from_config)
    from neckstrength.estimation.datasets import model_directions_table, thesis_f_actual
    from neckstrength.sequential.deficit import DeficitDefinition
    from neckstrength.sequential.decision import DeficitDecision
    from neckstrength.sequential.joint import JointPosterior
    from neckstrength.wrench import solve

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--datasets", nargs="+", default=["weak", "norm"])
    ap.add_argument("--noisy", action="store_true", help="5%% log-normal noise on the forces (stream 'noise')")
    ap.add_argument("--variants", nargs="+", default=None)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default=None, help="CSV of the rows")
    a = ap.parse_args()

    cfg = load_config(a.config)
    seed = int(cfg["seed"])
    model = model_from_config(full_model_from_config(cfg), cfg, "s3m24")
    d, U = model_directions_table(model, build_directions(cfg))
    dirs, fs = list(d["name"]), d["force_scale"].to_numpy(float)
    f0 = model.strengths
    base = decision_settings(cfg)
    joint = joint_settings(cfg)
    variants = {
        "shipped": base,
        "kernel 10% (noise 0.10)": replace(base, noise=0.10),
        "old sampler (fresh draws, ESS 0.05, 2 moves, 4 steps)": replace(base, sampler="fresh_draws",
                                                                         resample_ess=0.05, n_moves=2,
                                                                         max_resamples=4),
        "population sd 0.2": replace(base, population_sd=0.2),
        "population sd 0.4": replace(base, population_sd=0.4),
        "deficit 20-80%, normal >= 80%": replace(base, deficit_range=(0.2, 0.8)),
        "deficit 10-50%, normal >= 50%": replace(base, deficit_range=(0.1, 0.5)),
        "N 1000 per hypothesis": replace(base, n_candidates=1000),
    }
    if a.variants:
        variants = {k: v for k, v in variants.items() if any(x in k for x in a.variants)}
    print(f"bench_decision: s3m24, seed {seed}, {a.seeds} candidate sets per variant, forces "
          f"{'with 5% noise' if a.noisy else 'exact'}; machine {platform.node()} ({platform.processor() or '?'}), "
          f"threads {a.threads}; {time.strftime('%Y-%m-%d %H:%M:%S')}", flush=True)
    rows = []
    for ds in a.datasets:
        fa = thesis_f_actual(model, cfg["data"]["thesis_dir"], ds)
        w, _, _ = solve(model, fa[None], U)
        forces = w[0] / fs
        if a.noisy:
            forces = forces * np.exp(0.05 * derive_rng(seed, f"bench_decision/noise/{ds}").standard_normal(len(fs)))
        gi = base.group_indices(model.muscle_names)
        ratio = float(fa[gi].sum() / f0[gi].sum())
        # the session's earlier answer: P(deficit) on the joint posterior
        old = []
        for k in range(a.seeds):
            post = JointPosterior(model, dirs, U, fs, f0, replace(joint, n_candidates=20000),
                                  derive_rng(seed, "bench_decision/joint", k), n_threads=a.threads)
            for i, dn in enumerate(dirs):
                post.update(dn, float(forces[i]))
            old.append(DeficitDefinition(("mf",), 0.6).probability(post.F, post.weights(), f0, model.muscle_names))
        rows.append({"dataset": ds, "mf_ratio": ratio, "variant": "earlier session: joint posterior P(mf < 60%)",
                     "log_bf": "", "log_bf_mean": np.nan, "log_bf_sd": np.nan,
                     "p_deficit": " / ".join(f"{x:.2f}" for x in old), "step_median_s": np.nan,
                     "step_max_s": np.nan})
        print(rows[-1], flush=True)
        for name, s in variants.items():
            lbf, steps = [], []
            for k in range(a.seeds):
                dec = DeficitDecision(model, dirs, U, fs, f0, s, joint, derive_rng(seed, f"bench_decision/{name}", k),
                                      n_threads=a.threads)
                for i, dn in enumerate(dirs):
                    t0 = time.perf_counter()
                    dec.push(dn, float(forces[i]))
                    dec.propose() if dec.remaining else None
                    steps.append(time.perf_counter() - t0)
                lbf.append(dec.log_bf())
            m = float(np.mean(lbf))
            p = 1 / (1 + np.exp(-(m + np.log(s.prevalence / (1 - s.prevalence)))))
            rows.append({"dataset": ds, "mf_ratio": ratio, "variant": name,
                         "log_bf": " / ".join(f"{x:+.1f}" for x in lbf), "log_bf_mean": m,
                         "log_bf_sd": float(np.std(lbf, ddof=1)) if len(lbf) > 1 else np.nan,
                         "p_deficit": f"{p:.2f}", "step_median_s": float(np.median(steps)),
                         "step_max_s": float(np.max(steps))})
            print(rows[-1], flush=True)
    df = pd.DataFrame(rows)
    pd.set_option("display.width", 250)
    print(df.to_string(index=False, float_format=lambda v: f"{v:.2f}"))
    if a.out:
        df.to_csv(a.out, index=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
