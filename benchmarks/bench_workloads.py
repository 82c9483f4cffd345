#!/usr/bin/env python
"""Benchmark: the batched max-wrench solver on four workloads vs one HiGHS call per LP (s3m24 x 25 directions).

Workloads (strength vectors, one row each; every row is solved for all test directions):

* ``grid``     the 3^12 grid of Eq. 5.4 (left/right tied, ``{0.8, 1, 1.2} x f_0``; 531,441 candidates)
* ``prior``    Chapter 6 prior draws ``N(f_0, (0.3 f_0)^2)`` (clipped at 0), every column independent
* ``tied``     the same prior draws with left and right of each group tied (12 free values)
* ``local``    local draws ``f_1 exp(0.05 z)``, ``z ~ N(0, I)``, around one prior draw ``f_1``

Each workload runs with a fresh :class:`BasisCache` per thread count (default 1 and 2). The
reference is :func:`neckstrength.wrench.max_wrench` (one HiGHS call per LP, the model built each
time) on a random sample of the workload's LPs, timed in the same run; the sample also checks
exactness: ``max |w - w_HiGHS| / max(w_HiGHS, 1)`` and status mismatches. Ratios are rates
against that reference. Peak memory is the process's ``ru_maxrss``.

Run from the repository root::

    .venv/bin/python benchmarks/bench_workloads.py                       # 500,000 draws per workload
    .venv/bin/python benchmarks/bench_workloads.py --n 50000 --workloads prior,local --threads 1
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

from bench_maxwrench import grid_factors, pair_index


def load(model_name: str, config: str):
    from neckstrength.config import build_directions, load_config
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.model.full import load_full_model
    from neckstrength.model.reduction import named_model

    os.chdir(ROOT)
    cfg = load_config(config)
    try:
        from neckstrength.config import full_model_from_config, model_from_config

        model = model_from_config(full_model_from_config(cfg), cfg, model_name)
    except ImportError:
        full = load_full_model(cfg["data"]["model_dir"], cfg["data"]["thesis_dir"])
        model = named_model(full, model_name, cfg["data"]["thesis_dir"])
    _, U = model_directions_table(model, build_directions(cfg))
    return model, np.asarray(U, float)


def workload(kind: str, model, n: int, rng) -> np.ndarray:
    f0 = model.strengths
    pidx = pair_index(model)
    g = int(pidx.max()) + 1
    if kind == "grid":
        return np.ascontiguousarray(f0[None, :] * grid_factors(g, 0.2)[:, pidx])
    if kind == "prior":
        return np.ascontiguousarray(np.clip(f0 * (1 + 0.3 * rng.standard_normal((n, f0.size))), 0, None))
    if kind == "tied":
        return np.ascontiguousarray(f0 * np.clip(1 + 0.3 * rng.standard_normal((n, g)), 0, None)[:, pidx])
    if kind == "local":
        f1 = np.clip(f0 * (1 + 0.3 * rng.standard_normal(f0.size)), 0, None)
        return np.ascontiguousarray(f1 * np.exp(0.05 * rng.standard_normal((n, f0.size))))
    raise ValueError(kind)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="s3m24")
    ap.add_argument("--n", type=int, default=500_000, help="draws per random workload")
    ap.add_argument("--workloads", default="grid,prior,tied,local")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--sample", type=int, default=1000, help="LPs per workload solved one HiGHS call each")
    ap.add_argument("--seed", type=int, default=20261123)
    ap.add_argument("--config", default=str(ROOT / "config" / "config.yaml"))
    args = ap.parse_args(argv)

    from neckstrength.wrench import BasisCache, max_wrench, solve
    from neckstrength.wrench import batched as _batched

    model, U = load(args.model, args.config)
    K = U.shape[0]
    print(f"# bench_workloads: model {model.name} (n={model.n}, m={model.m}), {K} directions, seed {args.seed}, "
          f"{args.n} draws per random workload, reference sample {args.sample} LPs per workload")
    print(f"# machine: {platform.machine()} {platform.system()} {platform.release()}, python "
          f"{platform.python_version()}, numpy {np.__version__}, cpus {len(os.sched_getaffinity(0))}, "
          f"load average {os.getloadavg()[0]:.2f}; dual simplex "
          f"{'on' if _batched._simplex is not None else 'OFF (numba missing)'}")
    t0 = time.perf_counter()
    solve(model, model.strengths[None, :], U[:1], return_alpha=False)   # compile / load the compiled code
    print(f"first call (numba compile or cache load included): {time.perf_counter() - t0:.2f} s")
    codes = {"optimal": 0, "zero": 1, "infeasible": 2, "unbounded": 3, "error": 4}
    ok = True
    for wi, kind in enumerate(args.workloads.split(",")):
        rng = np.random.default_rng([args.seed, wi])
        F = workload(kind, model, args.n, rng)
        N = F.shape[0]
        S = min(args.sample, N * K)
        si, sk = np.divmod(rng.choice(N * K, size=S, replace=False), K)
        w_ref = np.empty(S)
        st_ref = np.empty(S, dtype=np.int8)
        t0 = time.perf_counter()
        c0 = time.process_time()
        for j in range(S):
            r = max_wrench(model.moment_arms, model.JT, F[si[j]], U[sk[j]])
            w_ref[j], st_ref[j] = r.w, codes[r.status]
        rate_ref = S / (time.perf_counter() - t0)
        cpu_ref = S / (time.process_time() - c0)
        print(f"\n[{kind}] {N} candidates x {K} = {N * K} LPs; reference max_wrench {rate_ref:,.0f} LPs/s "
              f"({cpu_ref:,.0f} LPs per CPU-second; {S} LPs; load average {os.getloadavg()[0]:.2f})")
        for nt in [int(x) for x in args.threads.split(",")]:
            cache = BasisCache()
            t0 = time.perf_counter()
            c0 = time.process_time()
            w, _, status = solve(model, F, U, return_alpha=False, cache=cache, n_threads=nt)
            t = time.perf_counter() - t0
            cpu = time.process_time() - c0
            rate = N * K / t
            err = float(np.max(np.abs(w[si, sk] - w_ref) / np.maximum(np.abs(w_ref), 1.0)))
            mis = int(np.sum(status[si, sk] != st_ref))
            ok &= err <= 1e-9 and mis == 0
            s = cache.stats()
            print(f"  n_threads={nt}: {t:.2f} s (CPU {cpu:.2f} s) = {rate:,.0f} LPs/s = {rate / rate_ref:,.0f}x "
                  f"(per CPU-second {N * K / cpu / cpu_ref:,.0f}x); "
                  f"cache {s['cache_hits'] / (N * K):.1%}, simplex {s['simplex_solved'] / (N * K):.1%} "
                  f"({s['simplex_pivots'] / max(s['simplex_solved'], 1):.1f} pivots), HiGHS {s['highs_calls']} "
                  f"({s['highs_calls'] / (N * K):.1e}; simplex failures {s['simplex_failed']}), bases {s['bases']} "
                  f"(learned {s['learned_bases']}); sample: max rel err {err:.1e}, status mismatches {mis}")
            del w, status
        del F
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\npeak memory (ru_maxrss): {rss:.0f} MiB; exactness on the samples {'OK' if ok else 'FAILED'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
