"""Speed of the deficit-decision study (issue 31: the study, >= 200 patients per protocol, under 30 minutes on 2
cores): CPU seconds per patient of `run_decision_study` as the study runs it, against the reference path (the
code before the speed-ups: numpy's BLAS on its default threads, the dual simplex packed with every cached basis),
timed in the same run on the same patients (the study's own truths and candidate streams, participants i of
`clinician_decision`), and the numbers of both compared: the same test order and every test's log BF, its Monte
Carlo error and P(deficit) equal to ``--tol`` (relative). ``--reference bounded``: the reference is the current
code with only the LP-free bounds of the EMG tests off (`JointPosterior.dual_bound_bounded`), both on one BLAS thread.

    python benchmarks/bench_decision_speed.py [--patients 0 1 100 101] [--protocols forces] [--out speed.json]
        [--reference before|bounded]

Each patient runs in this process one after the other, reference and new path in alternating order (the first
patient's reference first, the next one's new path first), after a warm-up that loads the compiled solver. CPU
seconds are this process's (every thread's), so they count a multi-threaded BLAS's spinning too. Prints a row per
patient and protocol, the ratio of the summed CPU seconds, the load average before and after (on a busy machine
the CPU seconds are inflated), and the study's estimated length at the new path's mean: patients x CPU per patient
/ 2 cores (the study runs one patient per core: `clinician_decision` with ``n_threads = 2``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import time
from dataclasses import replace

import numpy as np


@contextlib.contextmanager
def reference_path(kind: str = "before"):
    """``before``: the solver's bookkeeping as before the speed-ups and no LP-free bounds for tests with activation
    bounds (the study's own switch, ``one_blas_thread``, is passed separately); ``bounded``: only the LP-free bounds
    of tests with activation bounds off (``JointPosterior.dual_bound_bounded``; the EMG protocols)."""
    from neckstrength.sequential.joint import JointPosterior
    from neckstrength.wrench import batched

    old = batched.SIMPLEX_PACK_STARTS, JointPosterior.dual_bound_bounded
    batched.SIMPLEX_PACK_STARTS = kind != "before" and old[0]
    JointPosterior.dual_bound_bounded = False
    try:
        yield
    finally:
        batched.SIMPLEX_PACK_STARTS, JointPosterior.dual_bound_bounded = old


def main() -> int:
    from neckstrength.config import (build_directions, decision_settings, decision_study_settings, derive_rng,
                                     full_model_from_config, joint_settings, load_config, model_from_config)
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.sequential.decision_study import run_decision_study
    from neckstrength.wrench import solve

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--model", default="s3m24")
    ap.add_argument("--patients", type=int, nargs="+", default=[0, 1, 100, 101],
                    help="cohort indices (the study's deficit patients come first: 0 .. n_deficit - 1)")
    ap.add_argument("--protocols", nargs="+", default=["forces"])
    ap.add_argument("--tol", type=float, default=1e-9, help="relative tolerance of the numbers' comparison")
    ap.add_argument("--reference", choices=("before", "bounded"), default="before",
                    help="before: every speed-up off (default); bounded: only the EMG tests' LP-free bounds off")
    ap.add_argument("--out", default=None, help="JSON with every row and the summary")
    a = ap.parse_args()

    cfg = load_config(a.config)
    model = model_from_config(full_model_from_config(cfg), cfg, a.model)
    d, U = model_directions_table(model, build_directions(cfg))
    dirs, fs = list(d["name"]), d["force_scale"].to_numpy(float)
    study, n_cand = decision_study_settings(cfg, a.model)
    # as clinician_decision: the model's own Bayes factor and the heuristic guard
    dec = decision_settings(cfg, n_candidates=n_cand, calibration=None, misfit_guard=None)
    joint = joint_settings(cfg)
    seed = int(cfg["seed"])
    if any("emg" in p for p in a.protocols) and not study.emg_groups:
        study = replace(study, emg_groups=tuple(cfg["chapter6"]["emg_groups"][a.model]))

    pset = None
    if "forces+postures" in a.protocols:                # as clinician_decision
        from neckstrength.postures.model import build_posture_set
        from neckstrength.postures.tables import load_posture_tables

        pset = build_posture_set(full_model_from_config(cfg), model,
                                 load_posture_tables(cfg["data"]["model_dir"], list(study.postures)),
                                 list(study.postures), cfg.get("postures", {}).get("force_length", "relative"))

    def rng_for(what, i):                   # the study's streams (pipeline.clinician.clinician_decision)
        return derive_rng(seed, f"decision/{a.model}/{what}", i)

    solve(model, model.strengths[None], U[:2], return_alpha=False)          # warm-up: the compiled solver loaded
    load0 = os.getloadavg()
    rows, k = [], 0
    for i in a.patients:
        for protocol in a.protocols:
            st = replace(study, protocols=(protocol,))
            out = {}
            for path in (("reference", "new") if k % 2 == 0 else ("new", "reference")):
                ctx = reference_path(a.reference) if path == "reference" else contextlib.nullcontext()
                c0, w0 = time.process_time(), time.perf_counter()
                with ctx:
                    r = run_decision_study(model, dirs, U, fs, model.strengths, dec, joint, st, rng_for,
                                           participants=[i], pset=pset,
                                           one_blas_thread=(path == "new" or a.reference == "bounded"))
                out[path] = (r, time.process_time() - c0, time.perf_counter() - w0)
            k += 1
            (ra, ca, wa), (rb, cb, wb) = out["reference"], out["new"]
            same_order = list(ra["direction"].fillna("")) == list(rb["direction"].fillna(""))
            diff = {}
            for col in ("log_bf", "log_bf_se", "p_deficit"):
                x, y = ra[col].to_numpy(float), rb[col].to_numpy(float)
                diff[col] = float(np.max(np.abs(x - y) / np.maximum(1.0, np.abs(x))))
            row = {"patient": i, "kind": ra["kind"].iloc[0], "protocol": protocol, "tests": int(ra["t"].max()),
                   "cpu_reference_s": ca, "cpu_new_s": cb, "ratio": ca / cb, "wall_reference_s": wa,
                   "wall_new_s": wb, "same_order": same_order, **{f"max_rel_diff_{c}": v for c, v in diff.items()},
                   "final_log_bf": float(rb["log_bf"].iloc[-1])}
            rows.append(row)
            print(f"patient {i:4d} ({row['kind']:7s}) {protocol:16s} CPU reference {ca:6.1f} s, new {cb:6.1f} s "
                  f"({ca / cb:.2f}x); same order {same_order}; max rel diff log BF {diff['log_bf']:.1e}, se "
                  f"{diff['log_bf_se']:.1e}, P {diff['p_deficit']:.1e}", flush=True)
    load1 = os.getloadavg()
    ok = all(r["same_order"] and max(r[f"max_rel_diff_{c}"] for c in ("log_bf", "log_bf_se", "p_deficit")) <= a.tol
             for r in rows)
    summary = {"date": time.strftime("%Y-%m-%d"), "patients": a.patients, "protocols": a.protocols,
               "reference": a.reference,
               "load_before": load0, "load_after": load1, "numbers_equal": ok, "tol": a.tol}
    n_all = study.cohort.n_deficit + study.cohort.n_normal
    for protocol in a.protocols:
        g = [r for r in rows if r["protocol"] == protocol]
        ca, cb = sum(r["cpu_reference_s"] for r in g), sum(r["cpu_new_s"] for r in g)
        n_p = len(study.participants(protocol))
        est = n_p * cb / len(g) / 2 / 60
        summary[protocol] = {"cpu_reference_per_patient_s": ca / len(g), "cpu_new_per_patient_s": cb / len(g),
                             "ratio": ca / cb, "study_patients": n_p, "study_minutes_2_cores_estimated": est,
                             "study_minutes_2_cores_reference_estimated": n_p * ca / len(g) / 2 / 60}
        print(f"{protocol}: CPU per patient {ca / len(g):.1f} s reference, {cb / len(g):.1f} s new: {ca / cb:.2f}x; "
              f"the study's {n_p} patients (of {n_all}) on 2 cores at this rate: {est:.0f} min (estimated; "
              f"reference {n_p * ca / len(g) / 2 / 60:.0f} min)")
    print(f"numbers equal (same test order, log BF / se / P to {a.tol:g} relative): {ok}")
    print(f"load average (1 / 5 / 15 min) before {load0[0]:.1f} / {load0[1]:.1f} / {load0[2]:.1f}, after "
          f"{load1[0]:.1f} / {load1[1]:.1f} / {load1[2]:.1f} on {os.cpu_count()} cores"
          + (" (busy machine: CPU seconds inflated)" if max(load0[0], load1[0]) > (os.cpu_count() or 1)
             else ""))
    if a.out:
        with open(a.out, "w") as fh:
            json.dump({"rows": rows, "summary": summary}, fh, indent=1)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
