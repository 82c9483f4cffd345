#!/usr/bin/env python
"""Benchmark: how long the gap diagnosis of one participant takes (issue 17, item 6), and where the time goes.

Times, for one data set of the measurement table with the config's diagnosis settings (default: s3m24, all nine
effects): the diagnosis without calibration (the fits of the ranking, pairs, refinement, bootstrap, reach
envelope) with the exact Jacobian and, as the reference measured in the same run, with forward differences
(``--reference``); then the calibrated diagnosis (noise-only and power replicates, ``gap.calibration``).
Prints wall and CPU seconds per stage and the machine load (``os.getloadavg``), and writes them as JSON.
Timings on a shared machine are only comparable as ratios within one run.

Run from the repository root::

    .venv/bin/python benchmarks/bench_gap.py                                  # s3m24, S003, full config
    .venv/bin/python benchmarks/bench_gap.py --dataset S005 --reference --out bench_gap.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import replace


def run(cfg_path: str, model: str, dataset: str, reference: bool, calibrate: bool, effects=None,
        workers: int = 1) -> dict:
    from neckstrength.config import build_directions, diagnosis_settings, gap_blind_dataset, gap_context, load_config
    from neckstrength.gap.diagnose import diagnose

    cfg = load_config(cfg_path)
    if effects:
        cfg["gap"]["effects"] = list(effects)
    directions = build_directions(cfg)
    ctx = gap_context(cfg, model, directions)
    data = gap_blind_dataset(cfg, ctx, directions, dataset)
    s = diagnosis_settings(cfg)
    out: dict = {"model": model, "dataset": dataset, "effects": list(s.effects), "platform": platform.platform(),
                 "cpu_count": os.cpu_count(), "workers": workers}
    runs = [("exact_gradient", replace(s, calibration=replace(s.calibration, replicates=0)))]
    if reference:
        runs.append(("finite_differences", replace(s, calibration=replace(s.calibration, replicates=0),
                                                   fit=replace(s.fit, exact_gradient=False))))
    if calibrate and s.calibration.replicates > 0:
        runs.append(("calibrated", s))
    for tag, st in runs:
        t0, c0, l0 = time.perf_counter(), time.process_time(), os.getloadavg()[0]
        k0 = os.times().children_user + os.times().children_system
        stages = []

        def say(msg, t0=t0, stages=stages):
            stages.append((round(time.perf_counter() - t0, 1), msg))
            print(f"[{tag} {time.perf_counter() - t0:.0f} s] {msg}", flush=True)

        d = diagnose(ctx, [data], st, progress=say, workers=workers)[0]
        out[tag] = {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
                    "cpu_workers_s": os.times().children_user + os.times().children_system - k0,
                    "load_before": l0, "load_after": os.getloadavg()[0], "decision": d.summary.get("decision"),
                    "gap_before": d.summary["gap_before"], "gap_after": d.summary["gap_after"], "stages": stages}
        print(f"{tag}: {out[tag]['wall_s']:.0f} s wall, {out[tag]['cpu_s']:.0f} s CPU (+ "
              f"{out[tag]['cpu_workers_s']:.0f} s in worker processes), load "
              f"{l0:.1f} -> {out[tag]['load_after']:.1f}: {d.summary.get('decision')}", flush=True)
    if reference:
        out["speedup_cpu"] = out["finite_differences"]["cpu_s"] / out["exact_gradient"]["cpu_s"]
        print(f"exact Jacobian vs finite differences: {out['speedup_cpu']:.2f}x less CPU")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--model", default="s3m24")
    ap.add_argument("--dataset", default="S003")
    ap.add_argument("--reference", action="store_true", help="also time finite-difference Jacobians")
    ap.add_argument("--no-calibration", action="store_true")
    ap.add_argument("--effects", default=None, help="comma-separated effects (default: config gap.effects)")
    ap.add_argument("--out", default=None, help="JSON file for the timings")
    ap.add_argument("--workers", type=int, default=1, help="processes for the calibration's screen")
    a = ap.parse_args()
    res = run(a.config, a.model, a.dataset, a.reference, not a.no_calibration,
              a.effects.split(",") if a.effects else None, a.workers)
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(res, fh, indent=2)


if __name__ == "__main__":
    main()
