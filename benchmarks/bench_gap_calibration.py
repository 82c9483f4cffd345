#!/usr/bin/env python
"""Benchmark: a participant's calibration, the shipped path against the power in two stages (issue 32, speed).

The calibration (noise-only, sensitivity and power data sets, each screened with every effect) is most of a
calibrated diagnosis. Times, in one run on the same inputs (the data set's base fit on all directions):

- **shipped**: ``calibrate`` with the power data sets in the same screen as the null (every power data set
  screened with every effect), as the diagnosis does;
- **two_stage**: the null first (``calibrate`` without the power's data sets), then the power by ``power_for`` in
  two stages (each power data set with its own effect; only those that pass its necessary test with every effect),
  as the withheld-effect benchmark computes its power (:func:`two_stage` below; tried for a participant's diagnosis
  in issue 32 and not adopted: it saved CPU on p2m7 but cost more on s3m24, docs/gap_diagnosis.md, Speed);

and checks that they agree: decision, p-value, the null's screen gaps and every power table row. Prints wall and CPU
seconds (this process and its forked workers) and the ratio, with the machine load.

Run from the repository root::

    .venv/bin/python benchmarks/bench_gap_calibration.py --dataset S003 --workers 1 --out calibration_speed.json
"""

from __future__ import annotations

import argparse
import json
import os
import time


def two_stage(ctx, names, folds, T, f_fit, phi_fit, rms_obs, effects, s, say=None, workers: int = 1):
    """``calibrate`` without the power, then every effect's power table by ``power_for`` (two stages)."""
    from dataclasses import replace

    import numpy as np

    from neckstrength.gap.calibrate import calibrate, power_for
    from neckstrength.gap.engine import BlindData

    cs = s.calibration
    s0 = replace(s, calibration=replace(cs, power_replicates=0))
    cals = calibrate(ctx, names, folds, T, f_fit, phi_fit, rms_obs, effects, s0, say, workers)
    if cs.power_replicates > 0:
        data = [BlindData(n, np.asarray(t, float)) for n, t in zip(names, T)]
        for c, t in zip(cals, power_for(ctx, data, cals, [[e.name for e in effects]] * len(cals), s, say, workers)):
            c.power = t
    return cals


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--model", default=None, help="default: first of gap.models")
    ap.add_argument("--dataset", default="S003")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--order", default="shipped,two_stage", help="which path first")
    ap.add_argument("--replicates", type=int, default=None, help="noise-only replicates (default: the config's)")
    ap.add_argument("--no-sensitivity", action="store_true", help="without the sensitivity table's nulls")
    ap.add_argument("--out", default=None, help="JSON file for the timings (not overwritten)")
    a = ap.parse_args(argv)
    if a.out and os.path.exists(a.out):
        raise SystemExit(f"{a.out} exists; choose another --out")

    import numpy as np

    from neckstrength.config import build_directions, diagnosis_settings, gap_blind_dataset, gap_context, load_config
    from neckstrength.gap.calibrate import calibrate
    from neckstrength.gap.effects import available_effects
    from neckstrength.gap.engine import Engine, direction_folds
    from neckstrength.seeds import derive_rng
    from neckstrength.wrench.batched import single_threaded_blas

    cfg = load_config(a.config)
    model = a.model or cfg["gap"]["models"][0]
    directions = build_directions(cfg)
    ctx = gap_context(cfg, model, directions)
    data = gap_blind_dataset(cfg, ctx, directions, a.dataset)
    s = diagnosis_settings(cfg)
    from dataclasses import replace

    cal = s.calibration
    s = replace(s, calibration=replace(cal, replicates=a.replicates or cal.replicates,
                                       sensitivity=cal.sensitivity and not a.no_sensitivity))
    effects = available_effects(ctx, s.effects)
    folds = direction_folds(ctx.K, s.folds, derive_rng(s.seed, f"gap/folds/{data.name}"))[None, :]
    eng = Engine(ctx, [data], s, folds, {e.name: e for e in effects})
    with single_threaded_blas():
        eng.evaluate((), eng.prior)
    pf = [int(np.nonzero((eng.pds == 0) & (eng.pfold < 0))[0][0])]
    args = (ctx, [data.name], folds, eng.T[pf], eng.results[()]["forces"][pf], eng.results[()]["phi"][pf],
            np.full((1, len(effects) + 1), np.nan), effects, s)
    paths = {"shipped": calibrate, "two_stage": two_stage}
    out: dict = {"model": model, "dataset": a.dataset, "workers": a.workers, "effects": [e.name for e in effects],
                 "replicates": s.calibration.replicates, "power_replicates": s.calibration.power_replicates,
                 "noise": s.calibration.noise, "sensitivity": s.calibration.sensitivity}
    cals = {}
    for tag in a.order.split(","):
        t0, c0, l0 = time.perf_counter(), time.process_time(), os.getloadavg()[0]
        k0 = os.times().children_user + os.times().children_system
        with single_threaded_blas():
            cals[tag] = paths[tag](*args, say=None, workers=a.workers)[0]
        out[tag] = {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
                    "cpu_workers_s": os.times().children_user + os.times().children_system - k0,
                    "load_before": l0, "load_after": os.getloadavg()[0]}
        r = out[tag]
        print(f"{tag}: {r['wall_s']:.0f} s wall, {r['cpu_s']:.0f} s CPU + {r['cpu_workers_s']:.0f} s in workers, "
              f"load {l0:.1f} -> {r['load_after']:.1f}", flush=True)
    p, c = cals["shipped"], cals["two_stage"]
    dp, dc = p.decide(p.gap_obs), c.decide(c.gap_obs)
    same_power = p.power.reset_index(drop=True).equals(c.power.reset_index(drop=True))
    out["agree"] = {"best": dp["best"] == dc["best"], "p_adjusted": (dp["p_adjusted"], dc["p_adjusted"]),
                    "max_abs_null_gap_difference": float(np.max(np.abs(p.gap_null - c.gap_null))),
                    "power_tables_equal": bool(same_power)}
    if not same_power:
        diff = p.power.compare(c.power)
        out["agree"]["power_rows_differing"] = int(len(diff))
        print(diff.to_string(), flush=True)
    tot = {k: out[k]["cpu_s"] + out[k]["cpu_workers_s"] for k in paths}
    out["cpu_ratio_shipped_over_two_stage"] = tot["shipped"] / tot["two_stage"]
    out["wall_ratio_shipped_over_two_stage"] = out["shipped"]["wall_s"] / out["two_stage"]["wall_s"]
    print(f"agree: {out['agree']}", flush=True)
    print(f"shipped / two_stage: CPU {out['cpu_ratio_shipped_over_two_stage']:.2f}x, wall "
          f"{out['wall_ratio_shipped_over_two_stage']:.2f}x", flush=True)
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(out, fh, indent=2, default=float)
    return out


if __name__ == "__main__":
    main()
