"""The deficit decision on the thesis's five participants (Table A.2 forces), at the shipped settings and with the
noise (kernel width) raised towards the model's misfit on real data (issue 31 item 2, issue 32).

    python benchmarks/bench_decision_participants.py [--noise 0.05 0.15 0.3] [--seeds 2]

One row per participant, noise and candidate set (stream 'bench_decision_participants/<participant>/<noise>' +
seed index): log Bayes factor, P(deficit) at the shipped prevalence, the decision, the group's posterior mean ratio
under each hypothesis, and the best candidate's RMS relative misfit under each hypothesis (how well either can
fit these forces at all), with the wall time.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import pandas as pd


def main() -> int:
    from neckstrength.config import (build_directions, decision_settings, derive_rng, full_model_from_config,
                                     joint_settings, load_config, model_from_config)
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.io import read_measurements
    from neckstrength.sequential.decision import decide

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--participants", nargs="+", default=["S003", "S004", "S005", "S006", "S007"])
    ap.add_argument("--noise", nargs="+", type=float, default=[0.05, 0.15, 0.3])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    cfg = load_config(a.config)
    seed = int(cfg["seed"])
    model = model_from_config(full_model_from_config(cfg), cfg, "s3m24")
    d, U = model_directions_table(model, build_directions(cfg))
    dirs, fs = list(d["name"]), d["force_scale"].to_numpy(float)
    meas = read_measurements(cfg["data"]["measurements"], list(build_directions(cfg)["name"]))
    base = decision_settings(cfg)
    print(f"bench_decision_participants: s3m24, seed {seed}, {time.strftime('%Y-%m-%d %H:%M:%S')}", flush=True)
    rows = []
    for p in a.participants:
        forces = meas[p].reindex(dirs).to_numpy(float)
        for nz in a.noise:
            s = replace(base, noise=nz, noise_source="bench")
            for k in range(a.seeds):
                t0 = time.time()
                dec, _ = decide(model, dirs, U, fs, model.strengths, forces, s, joint_settings(cfg),
                                derive_rng(seed, f"bench_decision_participants/{p}/{nz}", k), n_threads=a.threads)
                rms = {}
                for h, post in dec.posts.items():
                    tested = post._tested_cols()
                    wm = np.array([t["w_meas"] for t in sorted(post.tests, key=lambda t: t["i"])])
                    rel = (post.W[:, tested] - wm) / wm
                    rms[h] = float(np.sqrt((rel ** 2).mean(axis=1)).min())
                rows.append({"participant": p, "noise": nz, "seed_index": k, "log_bf": dec.log_bf(),
                             "log_bf_se": dec.log_bf_se(), "p_deficit": dec.p_deficit(), "decision": dec.decision(),
                             "ratio_deficit": dec.group_ratio_mean("deficit"),
                             "ratio_normal": dec.group_ratio_mean("normal"),
                             "best_rms_normal": rms["normal"], "best_rms_deficit": rms["deficit"],
                             "seconds": time.time() - t0})
                print(rows[-1], flush=True)
    df = pd.DataFrame(rows)
    print(df.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if a.out:
        df.to_csv(a.out, index=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
