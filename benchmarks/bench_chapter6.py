#!/usr/bin/env python
"""End-to-end benchmark: the Chapter 6 general simulated data set (``SimulatedSet.build``) for s3m24.

``N_F`` candidates from ``N(f_0, (0.3 f_0)^2)`` (``sample_prior``, the Chapter 6 prior, independent
columns), 25 test directions, the 50-bin strength grid and 512 wrench bins of ``config/config.yaml``:
``SimulatedSet.build`` (one solve per candidate and direction through :func:`neckstrength.wrench.solve`,
wrenches and activations together, then Algorithm 9's tables). Timed with the default solver (cached bases + compiled
dual simplex) at ``N_F`` and, for comparison in the same run, the default and the previous path
(``BasisCache(simplex=False)``: HiGHS for every cache miss) at ``--compare`` candidates.

    .venv/bin/python benchmarks/bench_chapter6.py                    # N_F = 500,000; comparison at 20,000
    .venv/bin/python benchmarks/bench_chapter6.py --n 100000 --compare 0
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_workloads import load


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="s3m24")
    ap.add_argument("--n", type=int, default=500_000, help="N_F")
    ap.add_argument("--compare", type=int, default=20_000, help="candidates for the old-vs-new comparison (0: none)")
    ap.add_argument("--threads", default="1", help="n_threads values for the N_F run (comma-separated)")
    ap.add_argument("--seed", type=int, default=20261123)
    ap.add_argument("--config", default=str(ROOT / "config" / "config.yaml"))
    args = ap.parse_args(argv)

    from neckstrength.sequential.algorithms import SimulatedSet, StrengthGrid, sample_prior
    from neckstrength.wrench import BasisCache, solve

    model, U = load(args.model, args.config)
    K = U.shape[0]
    names = [f"d{k}" for k in range(K)]
    f0 = model.strengths
    grid = StrengthGrid.around(f0, 0.3, 50, 4.0)
    print(f"# bench_chapter6: model {model.name} (m={model.m}), {K} directions, seed {args.seed}, 50 strength bins, "
          f"512 wrench bins")
    print(f"# machine: {platform.machine()} {platform.system()} {platform.release()}, python "
          f"{platform.python_version()}, numpy {np.__version__}, cpus {len(os.sched_getaffinity(0))}, "
          f"load average {os.getloadavg()[0]:.2f}")
    t0 = time.perf_counter()
    solve(model, f0[None, :], U[:1], return_alpha=False)
    print(f"first solve (compiled code loaded or compiled): {time.perf_counter() - t0:.2f} s")

    def run(N, nt, simplex):
        F = sample_prior(f0, 0.3, N, np.random.default_rng(args.seed))
        cache = BasisCache(simplex=simplex)
        t = time.perf_counter()
        c = time.process_time()
        sim, = SimulatedSet.build(model, names, U, F, [grid], 512, n_threads=nt, cache=cache)
        t, c = time.perf_counter() - t, time.process_time() - c
        s = cache.stats()
        print(f"  N_F={N} n_threads={nt} {'dual simplex' if simplex else 'HiGHS for misses (previous path)'}: "
              f"{t:.1f} s (CPU {c:.1f} s; solves {sim.meta['seconds_wrench']:.1f} s, tables "
              f"{sim.meta['seconds_activation']:.1f} s); {N * K} LPs solved, HiGHS calls {s['highs_calls']}, "
              f"simplex {s['simplex_solved']}, cache hits {s['cache_hits']}, bases {s['bases']}", flush=True)
        return t, sim

    if args.compare:
        print(f"comparison at N_F = {args.compare}:")
        t_new, s_new = run(args.compare, 1, True)
        t_old, s_old = run(args.compare, 1, False)
        same = np.array_equal(s_new.wbin, s_old.wbin) and np.array_equal(s_new.wcount, s_old.wcount)
        dA = np.abs(s_new.A.astype(float) - s_old.A.astype(float)).sum() / max(np.abs(s_old.A).sum(), 1e-300)
        print(f"  speed-up {t_old / t_new:.1f}x; max |w_new - w_old| / max(w_old, 1) = "
              f"{np.max(np.abs(s_new.w - s_old.w) / np.maximum(s_old.w, 1)):.1e}; wrench bins and counts equal: "
              f"{same}; activation tables differ by {dA:.1e} (L1, relative; optimal activations are not unique "
              f"where the LP is degenerate)")
    print(f"N_F = {args.n}:")
    for nt in [int(x) for x in args.threads.split(",")]:
        run(args.n, nt, True)
    print(f"peak memory (ru_maxrss): {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
