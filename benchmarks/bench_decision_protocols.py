"""The deficit decision with EMG or postures (issue 31 item 4): the first ``--n`` deficit and normal patients of the
decision study (participants 0..n-1 and 100..100+n-1 of `clinician_decision` in the full config: the same truths,
forces and candidate streams), measured with surface EMG bounds of `chapter6.emg_groups` (`forces+emg`), with the
deep extensors recorded too (`forces+emg+deep`), or with the directions in `clinician.decision_study.postures` too
(`forces+postures`); compared, patient by patient, with the forces-only runs of the study's `decision_runs.csv`.
The model's own P(deficit) throughout (no recalibration: it was measured on forces only).

    python benchmarks/bench_decision_protocols.py --n 20 [--protocols forces+emg forces+emg+deep]
        [--runs results/clinician/s3m24/decision_runs.csv]

Prints the ROC area, the rule P >= 0.95 after 5 / 10 / 25 tests and the stopping rule per protocol; ``--out``
writes the runs.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import pandas as pd


def main() -> int:
    from neckstrength.config import (build_directions, decision_settings, decision_study_settings, derive_rng,
                                     full_model_from_config, joint_settings, load_config, model_from_config)
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.gap.forked import fork_map
    from neckstrength.sequential.decision_study import roc_table, run_decision_study, sequential_table

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--n", type=int, default=20, help="deficit and normal patients each")
    ap.add_argument("--runs", default="results/clinician/s3m24/decision_runs.csv", help="the study's forces-only runs")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--protocols", nargs="+", default=["forces+emg", "forces+emg+deep"])
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    cfg = load_config(a.config)
    model = model_from_config(full_model_from_config(cfg), cfg, "s3m24")
    d, U = model_directions_table(model, build_directions(cfg))
    dirs, fs = list(d["name"]), d["force_scale"].to_numpy(float)
    study, n_cand = decision_study_settings(cfg, "s3m24")
    n_def = study.cohort.n_deficit
    study = replace(study, protocols=tuple(a.protocols), emg_groups=tuple(cfg["chapter6"]["emg_groups"]["s3m24"]))
    dec = decision_settings(cfg, n_candidates=n_cand, calibration=None)
    pset = None
    if "forces+postures" in study.protocols:
        from neckstrength.postures.model import build_posture_set
        from neckstrength.postures.tables import load_posture_tables

        pset = build_posture_set(full_model_from_config(cfg), model,
                                 load_posture_tables(cfg["data"]["model_dir"], list(study.postures)),
                                 list(study.postures), cfg["postures"]["force_length"])
    seed = int(cfg["seed"])

    def rng_for(what, i):                       # the study's streams (pipeline.clinician.clinician_decision)
        return derive_rng(seed, f"decision/s3m24/{what}", i)

    idx = [j for k in range(a.n) for j in (k, n_def + k)]      # interleaved: a stop leaves both kinds

    def one(i):
        return run_decision_study(model, dirs, U, fs, model.strengths, dec, joint_settings(cfg), study, rng_for,
                                  participants=[i], progress=lambda s: print(s, flush=True), pset=pset)

    t0 = time.time()
    done = []
    for _, r in fork_map(one, idx, a.workers):
        done.append(r)
        if a.out:                                   # as each patient finishes: a stopped run keeps what it did
            pd.concat(done, ignore_index=True).to_csv(a.out, index=False)
    runs = pd.concat(done, ignore_index=True)
    print(f"{len(idx)} patients in {time.time() - t0:.0f} s", flush=True)
    forces = pd.read_csv(a.runs, comment="#")
    both = pd.concat([forces[forces["participant"].isin(idx)], runs], ignore_index=True)
    pd.set_option("display.width", 250)
    print(roc_table(both, (5, 10, 25), study.false_alarm, dec.p_decide).to_string(index=False))
    print(sequential_table(both, dec.p_decide, dec.min_tests)[1].to_string(index=False))
    if a.out:
        runs.to_csv(a.out, index=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
