#!/usr/bin/env python
"""How much the aiming-scatter shape test can see at best (issue 32): its power with the true strengths, no fit.

The diagnosis names ``direction_scatter`` when the remainder is not explained and the squared held-out residuals
grow with the tests' direction sensitivity (:mod:`neckstrength.gap.scatter`). Its power on the user benchmark is
low (direction errors 2 of 14 named). This script asks whether a better shape statistic would help, in the most
favourable case: the per-test log change of the user benchmark's ``direction_error`` truth (its own code,
:mod:`neckstrength.gap.truths`) plus measurement noise (3 trials, largest kept, noise 3-6 %), against the direction
sensitivity of the *true* strengths, with no fitted model in between. Each statistic's permutation p-value
(``--permutations`` reassignments of the sensitivities to the tests) is computed for the aim's change plus noise and
for the noise alone (the level check).

Statistics: ``slope_r2`` (shipped: slope of r^2 on v), ``slope_abs`` (|r| on v), ``spearman_abs`` (ranks of |r|
and v), ``logv_r2`` (r^2 on log v), ``sqrtv_abs`` (|r| on sqrt v).

    .venv/bin/python benchmarks/bench_gap_scatter_power.py --cases 30
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def _stats():
    from scipy import stats

    def centred(x):
        return x - x.mean()

    return {
        "slope_r2": lambda r, v: centred(v) @ r ** 2,
        "slope_abs": lambda r, v: centred(v) @ np.abs(r),
        "spearman_abs": lambda r, v: stats.rankdata(np.abs(r)) @ stats.rankdata(v),
        "logv_r2": lambda r, v: centred(np.log(v + 1e-6)) @ r ** 2,
        "sqrtv_abs": lambda r, v: centred(np.sqrt(v)) @ np.abs(r),
    }


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--cases", type=int, default=30, help="direction-error truths")
    ap.add_argument("--permutations", type=int, default=999)
    ap.add_argument("--seed", type=int, default=20261128)
    a = ap.parse_args(argv)

    from neckstrength.config import gap_truth_setup, load_config
    from neckstrength.gap import truths as T
    from neckstrength.gap.scatter import ScatterSettings, direction_sensitivity

    t0 = time.perf_counter()
    model, _, setup = gap_truth_setup(load_config(a.config))
    fc = T.TruthForces(setup)
    m = setup.model
    rng = np.random.default_rng(a.seed)
    s = T.CaseSettings()
    ss = ScatterSettings()
    st = _stats()

    def perm_p(stat, r, v):
        t = stat(r, v)
        ts = np.array([stat(r, rng.permutation(v)) for _ in range(a.permutations)])
        return (1 + (ts >= t - 1e-15).sum()) / (a.permutations + 1)

    p_aim = {k: [] for k in st}
    p_noise = {k: [] for k in st}
    for _ in range(a.cases):
        f = m.strengths * np.exp(rng.normal(0.0, s.strength_spread, m.m))
        p = T.draw_params(setup, "direction_error", s, rng, fc)
        lr = np.log(T.make_forces(setup, "direction_error", f, p, fc) / fc.base(f))
        nz = rng.uniform(*s.noise)
        noise = np.log(np.exp(rng.normal(0.0, nz, (len(lr), s.repeats))).max(axis=1))
        v = direction_sensitivity(m, f, fc.P, fc.N, ss)
        r, n0 = lr + noise, noise
        for k, fn in st.items():
            p_aim[k].append(perm_p(fn, r - r.mean(), v))
            p_noise[k].append(perm_p(fn, n0 - n0.mean(), v))
    out = {"model": model, "cases": a.cases, "seed": a.seed, "permutations": a.permutations, "stats": {}}
    print(f"{model}, {a.cases} direction-error truths (cones {s.cone_deg[0]:g}-{s.cone_deg[1]:g} deg), seed {a.seed}, "
          f"{a.permutations} permutations; true strengths, no fit")
    for k in st:
        x, y = np.array(p_aim[k]), np.array(p_noise[k])
        out["stats"][k] = {"aim_01": float(np.mean(x <= 0.01)), "aim_05": float(np.mean(x <= 0.05)),
                           "noise_01": float(np.mean(y <= 0.01)), "noise_05": float(np.mean(y <= 0.05))}
        print(f"  {k:13s} power at 0.01 {np.mean(x <= 0.01):.2f}, at 0.05 {np.mean(x <= 0.05):.2f} | noise alone "
              f"at 0.01 {np.mean(y <= 0.01):.2f}, at 0.05 {np.mean(y <= 0.05):.2f}")
    print(f"{time.perf_counter() - t0:.0f} s wall, load {os.getloadavg()[0]:.1f}")
    return out


if __name__ == "__main__":
    main()
