#!/usr/bin/env python
"""Benchmark: cost and power of the calibration's screen (issue 17, items 1 and 6), refitted vs approximate CV.

Simulates noise-only data sets and data sets with one injected effect (s3m24 by default; individual strengths
baseline x exp(N(0, spread)) per free parameter, log-normal noise), screens all of them once with the settings
given (``gap.calibration.cv`` refit or one_step, ``max_iter``, effect grid), and reports the CPU per data set and
how often the injected effect is named by the maxT decision against the noise-only data sets (the effect with the
largest standardised improvement, and T above every noise-only T), and how many noise-only data sets have a T
above all the others (leave-one-out; about 1 expected for any valid screen). The numbers in
docs/gap_diagnosis.md ("Folds of the screen by approximate cross-validation") come from::

    .venv/bin/python benchmarks/bench_gap_screen.py --cv refit --max-iter 15
    .venv/bin/python benchmarks/bench_gap_screen.py --cv one_step --max-iter 15
    .venv/bin/python benchmarks/bench_gap_screen.py --cv one_step --max-iter 8
    .venv/bin/python benchmarks/bench_gap_screen.py --cv one_step --max-iter 8 --grid 3

Single-process CPU times; compare rows measured on the same machine and load only.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--model", default="s3m24")
    ap.add_argument("--cv", choices=["refit", "one_step"], default="one_step")
    ap.add_argument("--steps", type=int, default=1, help="cv_steps (one_step)")
    ap.add_argument("--max-iter", type=int, default=8)
    ap.add_argument("--grid", type=int, default=None, help="effect grid points (default: config gap.grid_points)")
    ap.add_argument("--nulls", type=int, default=20)
    ap.add_argument("--per-effect", type=int, default=8)
    ap.add_argument("--effects", default="asymmetry,direction_tolerance,finer_groups,origin_offset")
    ap.add_argument("--size", type=float, default=0.8, help="injected share of the way to the far bound")
    ap.add_argument("--noise", type=float, default=0.05)
    ap.add_argument("--spread", type=float, default=0.3)
    ap.add_argument("--seed", type=int, default=7, help="strengths and noise of the simulated data sets")
    ap.add_argument("--fold-seed", type=int, default=1, help="the data sets' fold splits")
    ap.add_argument("--out", default=None, help="JSON file for the result")
    a = ap.parse_args(argv)

    import numpy as np

    from neckstrength.config import build_directions, diagnosis_settings, gap_context, load_config
    from neckstrength.gap.calibrate import screen, size_theta
    from neckstrength.gap.effects import available_effects, base_instance, compose
    from neckstrength.gap.engine import BlindData, direction_folds
    from neckstrength.gap.fit import Simulator
    from neckstrength.seeds import derive_rng

    cfg = load_config(a.config)
    ctx = gap_context(cfg, a.model, build_directions(cfg))
    s = diagnosis_settings(cfg)
    if a.grid:
        s = replace(s, grid_points=a.grid)
    s = replace(s, calibration=replace(s.calibration, max_iter=a.max_iter, cv=a.cv, cv_steps=a.steps))
    effects = available_effects(ctx, s.effects)
    reg = {e.name: e for e in effects}
    inject = [x for x in a.effects.split(",") if x]
    sim = Simulator(ctx, base_instance(ctx))
    rng = np.random.default_rng(a.seed)
    p = int(sim.pidx.max()) + 1
    m = ctx.model
    theta = np.log(np.bincount(sim.pidx, weights=m.strengths, minlength=p) / np.bincount(sim.pidx, minlength=p))
    phis = theta + rng.normal(0, a.spread, (a.nulls + a.per_effect * len(inject), p))
    forces, labels = [], []
    for f in sim.forces(sim.muscles(phis[:a.nulls])):
        forces.append(f * np.exp(rng.normal(0, a.noise, ctx.K)))
        labels.append("none")
    for k, e in enumerate(inject):
        for r in range(a.per_effect):
            se = Simulator(ctx, compose(ctx, [reg[e]], [size_theta(reg[e], a.size, 1 if r % 2 == 0 else -1)]))
            f = se.forces(se.muscles(phis[a.nulls + k * a.per_effect + r][None]))[0]
            if np.any(f <= 0.05 * np.median(f)):          # a direction the truth cannot produce: skipped
                continue
            forces.append(f * np.exp(rng.normal(0, a.noise, ctx.K)))
            labels.append(e)
    data = [BlindData(f"d{i}", f) for i, f in enumerate(forces)]
    folds = np.array([direction_folds(ctx.K, s.folds, derive_rng(a.fold_seed, f"gap/folds/d{i}"))
                      for i in range(len(data))])
    c0, t0 = time.process_time(), time.perf_counter()
    sc = screen(ctx, data, folds, effects, s)
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    lab = np.array(labels)
    delta = sc.gap[:, :1] - sc.gap[:, 1:]
    nul = lab == "none"
    sd_floor = s.calibration.sd_floor

    def tstat(rows, ref):
        mu, sd = delta[ref].mean(0), np.maximum(delta[ref].std(0, ddof=1), sd_floor)
        z = (delta[rows] - mu) / sd
        return z, z.max(axis=1)

    above = 0
    for i in np.flatnonzero(nul):                          # leave-one-out among the noise-only data sets
        ref = nul.copy()
        ref[i] = False
        above += int(tstat([i], ref)[1][0] > tstat(ref, ref)[1].max())
    t_null = tstat(nul, nul)[1].max()
    names = [e.name for e in effects]
    out = {"model": a.model, "cv": a.cv, "cv_steps": a.steps, "max_iter": a.max_iter, "grid_points": s.grid_points,
           "seed": a.seed, "fold_seed": a.fold_seed, "noise": a.noise, "size": a.size, "data_sets": len(data), "cpu_s": cpu, "wall_s": wall,
           "cpu_per_data_set_s": cpu / len(data), "load": os.getloadavg()[0],
           "noise_only_above_the_others": above, "noise_only": int(nul.sum()), "named": {}}
    for e in inject:
        rows = np.flatnonzero(lab == e)
        z, t = tstat(rows, nul)
        out["named"][e] = {"cases": int(rows.size),
                           "named": int(((z.argmax(axis=1) == names.index(e)) & (t > t_null)).sum())}
    print(f"{a.model}, cv {a.cv} (steps {a.steps}), {a.max_iter} iterations, grid {s.grid_points}: {len(data)} data "
          f"sets, {cpu:.1f} s CPU ({cpu / len(data):.2f} s per data set), load {out['load']:.1f}")
    print("named: " + ", ".join(f"{e} {v['named']}/{v['cases']}" for e, v in out["named"].items())
          + f"; noise-only data sets above the other {int(nul.sum()) - 1}: {above} of {int(nul.sum())}")
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(out, fh, indent=2)
    return out


if __name__ == "__main__":
    main()
