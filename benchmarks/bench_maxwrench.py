#!/usr/bin/env python
"""Benchmark: batched max-wrench solver vs one HiGHS call per LP on the s3m24 candidate grid.

The grid of thesis Eq. 5.4 / Sec. 5.3.2.1: every muscle-group pair (left and right
tied, so 12 free values for the 24 groups of s3m24, whose columns are
``hyoids-R, hyoids-L, SCM-R, ...``) takes a strength in
``{1 - s, 1, 1 + s} x baseline``: 3^12 = 531441 candidates x 25 directions =
13.3 million LPs. A random sample of the LPs is solved with
:func:`neckstrength.wrench.max_wrench` (one HiGHS call each; the reference),
the whole grid with :func:`neckstrength.wrench.batched.max_wrench_batched`; the script
checks the batched ``w`` against HiGHS on the sample and prints rates, their
ratio, HiGHS fallbacks and cached bases per direction, wall time and peak memory.

Run from the repository root::

    .venv/bin/python benchmarks/bench_maxwrench.py                 # full grid, 2000 reference LPs
    .venv/bin/python benchmarks/bench_maxwrench.py --grid-size 8   # 3^8 candidates (quick)

The baseline strengths are the reduced model's (Table B.1 -> reduction); the
model comes from ``data/model`` + ``data/thesis`` and the directions from
``config/config.yaml`` (25 test directions).
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def grid_factors(n_free: int, sigma: float) -> np.ndarray:
    """All 3^n_free combinations of {1-s, 1, 1+s} (rows), last factor fastest."""
    levels = np.array([1.0 - sigma, 1.0, 1.0 + sigma])
    idx = np.indices((3,) * n_free, dtype=np.int8).reshape(n_free, -1).T
    return levels[idx]


def pair_index(model) -> np.ndarray:
    """Free-parameter index of every column: left and right of a group share one value."""
    names = list(model.muscle_names)
    if model.planar:
        return np.arange(len(names))
    bases = []
    for nm in names:
        base = nm[:-2] if nm.endswith(("-R", "-L")) else nm
        if base not in bases:
            bases.append(base)
    return np.array([bases.index(nm[:-2] if nm.endswith(("-R", "-L")) else nm) for nm in names])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="s3m24", help="named model (default s3m24)")
    ap.add_argument("--grid-size", type=int, default=None,
                    help="number of free strength values on the grid (default: all, 12 for s3m24); "
                         "the other free values stay at baseline")
    ap.add_argument("--sample", type=int, default=2000, help="LPs solved one HiGHS call each (reference)")
    ap.add_argument("--sigma", type=float, default=0.2, help="grid step s of {1-s, 1, 1+s}")
    ap.add_argument("--seed", type=int, default=20261123)
    ap.add_argument("--chunk-size", type=int, default=65536)
    ap.add_argument("--threads", default="1,2",
                    help="comma-separated n_threads values to run the batched solver with (default 1,2)")
    ap.add_argument("--config", default=str(ROOT / "config" / "config.yaml"))
    ap.add_argument("--tracemalloc", action="store_true",
                    help="also trace Python allocations during an extra, untimed batched run")
    args = ap.parse_args(argv)

    from neckstrength.config import build_directions, load_config
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.model.full import load_full_model
    from neckstrength.model.reduction import named_model
    from neckstrength.wrench.batched import BasisCache, max_wrench_batched
    from neckstrength.wrench.highs import max_wrench, max_wrench_batch

    os.chdir(ROOT)                                   # the config's paths are relative to the repository
    cfg = load_config(args.config)
    try:                                             # the pipeline's own loaders, where present
        from neckstrength.config import full_model_from_config, model_from_config

        model = model_from_config(full_model_from_config(cfg), cfg, args.model)
    except ImportError:
        full = load_full_model(cfg["data"]["model_dir"], cfg["data"]["thesis_dir"])
        model = named_model(full, args.model, cfg["data"]["thesis_dir"])
    dirs, U = model_directions_table(model, build_directions(cfg))
    K = U.shape[0]
    f_base = model.strengths
    pidx = pair_index(model)
    n_free = int(pidx.max()) + 1
    g = n_free if args.grid_size is None else min(args.grid_size, n_free)

    print(f"# bench_maxwrench: model {model.name} (n={model.n}, m={model.m}, d={U.shape[1]}), "
          f"{K} directions, grid {{1-s,1,1+s}}^{g} with s={args.sigma} over {n_free} free values "
          f"{'(left/right tied)' if not model.planar else ''}, seed {args.seed}")
    print(f"# machine: {platform.machine()} {platform.system()} {platform.release()}, "
          f"python {platform.python_version()}, numpy {np.__version__}, cpus {len(os.sched_getaffinity(0))}")

    t0 = time.perf_counter()
    factors = grid_factors(g, args.sigma)                     # (3^g, g)
    full_factors = np.ones((factors.shape[0], n_free))
    full_factors[:, :g] = factors
    del factors
    F = np.ascontiguousarray(f_base[None, :] * full_factors[:, pidx])   # (N, m), C order
    del full_factors
    N = F.shape[0]
    t_grid = time.perf_counter() - t0
    print(f"candidates: {N} x {K} directions = {N * K} LPs (grid built in {t_grid:.2f} s, "
          f"F {F.nbytes / 2**20:.0f} MiB)")

    # ---- reference: one HiGHS call per LP on a random sample
    rng = np.random.default_rng(args.seed)
    S = min(args.sample, N * K)
    flat = rng.choice(N * K, size=S, replace=False)
    si, sk = np.divmod(flat, K)
    w_ref = np.empty(S)
    st_ref = []
    t0 = time.perf_counter()
    for j in range(S):
        r = max_wrench(model.moment_arms, model.JT, F[si[j]], U[sk[j]])
        w_ref[j] = r.w
        st_ref.append(r.status)
    t_ref = time.perf_counter() - t0
    rate_ref = S / t_ref
    # the same sample with one warm-started HiGHS instance per direction (max_wrench_batch):
    # still one HiGHS call per LP, without rebuilding the LP each time
    w_warm = np.empty(S)
    t0 = time.perf_counter()
    for k in range(K):
        sel = np.flatnonzero(sk == k)
        if sel.size:
            w_warm[sel] = max_wrench_batch(model, F[si[sel]], U[k:k + 1])[0][:, 0]
    t_warm = time.perf_counter() - t0
    rate_warm = S / t_warm

    # ---- batched: whole grid, fresh cache per run
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    runs = []
    for nt in [int(x) for x in args.threads.split(",")]:
        cache = BasisCache()
        t0 = time.perf_counter()
        c0 = time.process_time()
        w, _, status = max_wrench_batched(model, F, U, chunk_size=args.chunk_size, cache=cache,
                                          return_alpha=False, n_threads=nt)
        runs.append((nt, time.perf_counter() - t0, time.process_time() - c0, cache,
                     w[si, sk].copy(), status[si, sk].copy()))
    nt, t_b, cpu_b, cache = runs[0][:4]
    rss_after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    py_peak = None
    if args.tracemalloc:                              # slows numpy allocations: untimed
        tracemalloc.start()
        max_wrench_batched(model, F, U, chunk_size=args.chunk_size, return_alpha=False)
        py_peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()

    codes = {"optimal": 0, "zero": 1, "infeasible": 2, "unbounded": 3, "error": 4}
    st_ref_codes = np.array([codes[s] for s in st_ref])
    rel = rel_warm = 0.0
    st_mis = 0
    for run in runs:                                  # every run against both references
        wb, sb = run[4], run[5]
        rel = max(rel, float(np.max(np.abs(wb - w_ref) / np.where(np.abs(w_ref) > 0, np.abs(w_ref), 1.0))))
        rel_warm = max(rel_warm, float(np.max(np.abs(wb - w_warm) / np.where(np.abs(w_warm) > 0,
                                                                              np.abs(w_warm), 1.0))))
        st_mis += int(np.sum(sb != st_ref_codes))

    print(f"reference (one HiGHS call per LP, maxwrench.max_wrench): {S} LPs in {t_ref:.2f} s "
          f"= {rate_ref:,.0f} LPs/s")
    print(f"reference (one warm-started HiGHS call per LP, maxwrench.max_wrench_batch): {S} LPs in "
          f"{t_warm:.2f} s = {rate_warm:,.0f} LPs/s")
    for nt_, t_, cpu_ in (r[:3] for r in runs):
        r_ = N * K / t_
        print(f"batched (max_wrench_batched, return_alpha=False, n_threads={nt_}): {N * K} LPs in {t_:.2f} s "
              f"(CPU {cpu_:.2f} s) = {r_:,.0f} LPs/s; speed-up {r_ / rate_ref:,.0f}x vs max_wrench, "
              f"{r_ / rate_warm:,.0f}x vs warm-started HiGHS")
    print(f"agreement on the sample (all runs): max |w - w_HiGHS| / w_HiGHS = {rel:.3e} (max_wrench), "
          f"{rel_warm:.3e} (warm-started); status mismatches {st_mis}")
    ent = cache.entries()
    print(f"per direction (n_threads={nt}): HiGHS fallbacks / cached bases / cache hits")
    for k, e in enumerate(ent):
        nm = dirs["name"].iat[k] if "name" in dirs else str(k)
        print(f"  {k:2d} {nm:>10s}: {e.stats.highs_calls:6d} / {e.stats.bases:5d} / {e.stats.cache_hits:9d}")
    tot = cache.stats()
    print(f"total: HiGHS fallbacks {tot['highs_calls']} ({tot['highs_calls'] / (N * K):.2e} of the LPs), "
          f"cached bases {tot['bases']}, rejected bases {tot['rejected_bases']}")
    counts = np.bincount(status.ravel(), minlength=5)
    print("statuses: " + ", ".join(f"{n} {c}" for n, c in zip(codes, counts)))
    print(f"peak memory: ru_maxrss {rss_after:.0f} MiB for the whole process (incl. the "
          f"{F.nbytes / 2**20:.0f} MiB grid and {w.nbytes / 2**20:.0f} + {status.nbytes / 2**20:.0f} MiB outputs; "
          f"{rss_before:.0f} MiB before the batched runs)"
          + (f"; tracemalloc peak {py_peak / 2**20:.0f} MiB" if py_peak is not None else ""))
    print(f"wall time: total {time.perf_counter() - T_START:.1f} s")
    ok = rel <= 1e-9 and st_mis == 0
    return 0 if ok else 1


T_START = time.perf_counter()

if __name__ == "__main__":
    sys.exit(main())
