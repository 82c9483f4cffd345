#!/usr/bin/env python
"""Benchmark: the clinician loop on the joint posterior (issue 18 item 4): step time and stability with N.

For a few simulated s3m24 participants (the deficit group at 25-50% of baseline, or normal at 80-120%; other
muscles from the prior; forces with log-normal noise sd 0.05) the joint posterior is driven through ``--n-max``
tests chosen by the joint expected information gain, for every candidate count N in ``--n`` and two independent
candidate sets per N (streams 'bench_clinician/candidates' + replicate). Recorded per step: the time to propose
(joint EIG over the remaining directions) and to update (tempering, resample-move: the new candidates' wrenches in
every direction). Recorded per run: P(deficit) and the group's posterior mean after t = 5, 10, n_max tests, and a
sampler check: the best candidate's log posterior density minus the truth's (negative: no candidate is as
probable as the truth, the candidates missed the posterior's high-density region) and the weighted mean kernel
log-likelihood of the candidates beside the truth's.

"Stable" is read from two numbers per N: the spread of P(deficit) between the two candidate sets of the same
participant (Monte Carlo error), and its distance from the largest N's answer. The Monte Carlo error the session
prints (``JointPosterior.mc_se``, from the candidates' genealogy) is checked against that spread: rms of
z = (P_1 - P_2) / sqrt(se_1^2 + se_2^2), about 1 if it is right (also for the naive sqrt(P (1 - P) / ESS)).

Run from the repository root (prints a table; ``--json`` also writes the rows)::

    python benchmarks/bench_clinician.py --n 2000 4000 8000 20000 --participants 4
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time

import numpy as np
import pandas as pd


def main(argv=None) -> int:
    from neckstrength.config import (
        build_directions,
        deficit_definition,
        derive_rng,
        full_model_from_config,
        joint_settings,
        load_config,
        model_from_config,
    )
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.sequential.deficit import draw_participant
    from neckstrength.sequential.joint import JointPosterior
    from neckstrength.wrench import solve
    from neckstrength.wrench.batched import BasisCache

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--model", default="s3m24")
    ap.add_argument("--n", type=int, nargs="+", default=[2000, 4000, 8000, 20000])
    ap.add_argument("--participants", type=int, default=4, help="half with a deficit, half normal")
    ap.add_argument("--replicates", type=int, default=2)
    ap.add_argument("--n-max", type=int, default=25)
    ap.add_argument("--seed", type=int, default=None, help="default: config seed")
    ap.add_argument("--json", default=None)
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1,
                    help="solver threads (the session's default: every core); the numbers do not depend on it")
    ap.add_argument("--shared-cache", action="store_true",
                    help="one basis cache for every run (as before 2026-11-24): later runs start from earlier bases")
    a = ap.parse_args(argv)

    cfg = load_config(a.config)
    seed = int(cfg["seed"] if a.seed is None else a.seed)
    model = model_from_config(full_model_from_config(cfg), cfg, a.model)
    d, U = model_directions_table(model, build_directions(cfg))
    names, dirs, fs = list(model.muscle_names), list(d["name"]), d["force_scale"].to_numpy(float)
    definition = deficit_definition(cfg)
    gidx = definition.indices(names)
    f0 = model.strengths
    cache = BasisCache()
    solve(model, f0[None], U, cache=cache)                     # compile / warm the solver outside the timings
    rows, steps = [], []
    checkpoints = sorted({5, 10, min(a.n_max, len(dirs))})
    for p in range(a.participants):
        kind = "deficit" if p % 2 == 0 else "normal"
        rt = derive_rng(seed, "bench_clinician/truth", p)
        fa = draw_participant(f0, 0.3, gidx, *((0.25, 0.5) if kind == "deficit" else (0.8, 1.2)), rt)
        w, _, _ = solve(model, fa[None], U, cache=cache)
        forces = w[0] * np.exp(0.05 * rt.standard_normal(len(dirs))) / fs
        for n in a.n:
            js = joint_settings(cfg, n_candidates=n)
            for r in range(a.replicates):
                # a fresh basis cache per run, as a session has (a cache shared over participants and N fills with
                # their bases and slows every later run: docs/clinician.md)
                post = JointPosterior(model, dirs, U, fs, f0, js, derive_rng(seed, "bench_clinician/candidates", r),
                                      cache=BasisCache() if not a.shared_cache else cache, n_threads=a.threads)
                prng = derive_rng(seed, "bench_clinician/propose", r)
                for t in range(1, a.n_max + 1):
                    t0 = time.perf_counter()
                    dd, _ = post.propose("joint_eig", prng)
                    t1 = time.perf_counter()
                    res0 = post.n_resamples
                    post.update(dd, float(forces[dirs.index(dd)]))
                    t2 = time.perf_counter()
                    steps.append({"participant": p, "n": n, "replicate": r, "t": t, "propose_s": t1 - t0,
                                  "update_s": t2 - t1, "step_s": t2 - t0, "resamples": post.n_resamples - res0})
                    if t in checkpoints:
                        wts = post.weights()
                        # sampler check: the truth's log posterior density (prior + kernel log-likelihood of the
                        # tests so far) against the best candidate's; far below = the candidates missed the region
                        ll_truth = sum(float(post._test_loglik(w[0, [x["i"]]], x["w_meas"])[0]) for x in post.tests)
                        lpost = post.log_prior(post.F) + post.loglik
                        rows.append({"participant": p, "kind": kind, "true_ratio": float(definition.ratio(
                            fa[None], f0, names)[0]), "n": n, "replicate": r, "t": t,
                            "p_deficit": definition.probability(post.F, wts, f0, names),
                            # Monte Carlo error estimates of P(deficit) from one candidate set: the genealogy
                            # (JointPosterior.mc_se, shown by the session) and the naive sqrt(p (1 - p) / ESS)
                            "p_se": post.mc_se(definition.ratio(post.F, f0, names) < definition.threshold),
                            "p_se_ess": float(np.sqrt(max(definition.probability(post.F, wts, f0, names) * (
                                1 - definition.probability(post.F, wts, f0, names)), 0.0)
                                / (1.0 / (wts ** 2).sum()))),
                            "ratio_mean": float(wts @ definition.ratio(post.F, f0, names)),
                            "best_minus_truth_logpost": float(lpost.max() - (post.log_prior(fa[None])[0] + ll_truth)),
                            "mean_loglik": float(wts @ post.loglik), "truth_loglik": ll_truth})
                print(f"participant {p} ({kind}) N {n} replicate {r}: P(deficit) "
                      + ", ".join(f"t={x['t']} {x['p_deficit']:.2f}" for x in rows[-len(checkpoints):]), flush=True)
    res, st = pd.DataFrame(rows), pd.DataFrame(steps)
    nmax = max(a.n)
    ref = res[res["n"] == nmax].groupby(["participant", "t"])["p_deficit"].mean()
    out = []
    for (n, t), g in res.groupby(["n", "t"]):
        spread = g.groupby("participant")["p_deficit"].agg(lambda x: x.max() - x.min()).mean()
        mean_p = g.groupby("participant")["p_deficit"].mean()
        dist = float(np.abs(mean_p - ref.xs(t, level="t").reindex(mean_p.index)).mean())
        ratio_spread = g.groupby("participant")["ratio_mean"].agg(lambda x: x.max() - x.min()).mean()
        # calibration of the printed Monte Carlo error: z = (p_1 - p_2) / sqrt(se_1^2 + se_2^2) between the first
        # two candidate sets; rms z about 1 if the se is right, > 1 if it understates the error
        z, z_ess = [], []
        for _, gp in g.groupby("participant"):
            if len(gp) >= 2:
                r1, r2 = gp.iloc[0], gp.iloc[1]
                for col, zz in (("p_se", z), ("p_se_ess", z_ess)):
                    den = math.hypot(r1[col], r2[col])
                    zz.append((r1["p_deficit"] - r2["p_deficit"]) / den if den > 0 else
                              (0.0 if r1["p_deficit"] == r2["p_deficit"] else np.inf))
        out.append({"n": n, "t": t, "p_spread_between_replicates": spread, "p_dist_to_largest_n": dist,
                    "ratio_mean_spread": ratio_spread, "mean_p_se": float(g["p_se"].mean()),
                    "rms_z_genealogy": float(np.sqrt(np.mean(np.square(z)))) if z else np.nan,
                    "rms_z_ess": float(np.sqrt(np.mean(np.square(z_ess)))) if z_ess else np.nan,
                    "median_best_minus_truth_logpost": float(g["best_minus_truth_logpost"].median()),
                    "median_mean_loglik": float(g["mean_loglik"].median()),
                    "median_truth_loglik": float(g["truth_loglik"].median())})
    stab = pd.DataFrame(out)
    tim = st.groupby("n").agg(step_median_s=("step_s", "median"), step_max_s=("step_s", "max"),
                              step_p90_s=("step_s", lambda x: float(np.quantile(x, 0.9))),
                              propose_median_s=("propose_s", "median"),
                              steps_with_resample=("resamples", lambda x: float((x > 0).mean())),
                              max_resample_step_s=("update_s", "max")).reset_index()
    load = os.getloadavg() if hasattr(os, "getloadavg") else (np.nan,) * 3
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cpus, load average "
          f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (at the end); seed {seed}; solver threads {a.threads}, "
          f"{'one shared' if a.shared_cache else 'a fresh'} basis cache per run")
    print(stab.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    print(tim.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"seed": seed, "load_end": load, "threads": a.threads, "shared_cache": a.shared_cache,
                       "cpus": os.cpu_count(), "runs": rows,
                       "stability": stab.to_dict("records"), "timing": tim.to_dict("records")}, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
