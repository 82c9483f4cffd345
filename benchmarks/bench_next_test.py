#!/usr/bin/env python
"""Benchmark: time to propose the next test (Algorithm 9) for s3m24 x 25 directions with N_F = 500,000.

The expensive part, the general simulated data set ``{w, alpha} = M(f_k, u_i)`` for N_F candidates x 25
directions, is computed once (and cached in ``--cache``, an .npz keyed by model, candidates and settings);
what a clinician waits for during testing is :meth:`SequentialState.propose` (Eq. 6.6 for every remaining
direction and muscle with N_S simulated measurements each, then Eq. 6.7) and :meth:`SequentialState.update`
(Algorithm 8 on the measured force). The script times both at several points of a simulated session on the
'norm' data set (f_a from Table 5.3, measurements M(f_a, u_i)), and checks the fast proposal against the
per-candidate reference on a subsample.

Run from the repository root::

    .venv/bin/python benchmarks/bench_next_test.py                      # N_F 500,000, N_S 100
    .venv/bin/python benchmarks/bench_next_test.py --n-candidates 50000 # quick
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="s3m24")
    ap.add_argument("--dataset", default="norm")
    ap.add_argument("--n-candidates", type=int, default=500_000)
    ap.add_argument("--n-sim", type=int, default=100)
    ap.add_argument("--n-bins", type=int, default=50)
    ap.add_argument("--n-wbins", type=int, default=512)
    ap.add_argument("--steps", type=int, default=5, help="measurements to simulate (proposal timed before each)")
    ap.add_argument("--repeat", type=int, default=3, help="timed proposals per step (median reported)")
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="directions solved concurrently")
    ap.add_argument("--cache", default=str(ROOT / "results" / "benchmarks" / "bench_next_test"))
    ap.add_argument("--no-emg", action="store_true", help="update without the simulated EMG bounds (as for the "
                    "participants): Algorithm 8 then reuses the general data set instead of re-simulating N_F "
                    "candidates with the bounds")
    ap.add_argument("--check-subsample-seed", type=int, default=0,
                    help="seed of the fast-vs-exact check's 20,000-candidate subsample")
    ap.add_argument("--check-propose-seed", type=int, default=1,
                    help="seed of the check's two proposals (the same for both)")
    ap.add_argument("--json", default=None, help="write the numbers here")
    args = ap.parse_args(argv)

    os.chdir(ROOT)
    sys.path.insert(0, str(ROOT / "src"))
    from neckstrength import sequential as sq
    from neckstrength.config import (
        build_directions,
        chapter6_settings,
        full_model_from_config,
        load_config,
        model_from_config,
    )
    from neckstrength.pipeline.chapter6 import chapter6_dataset

    cfg = load_config(ROOT / "config" / "config.yaml")
    model = model_from_config(full_model_from_config(cfg), cfg, args.model)
    data = chapter6_dataset(model, build_directions(cfg), args.dataset, cfg)
    s = chapter6_settings(cfg, args.model, n_candidates=args.n_candidates, n_sim=args.n_sim, n_bins=args.n_bins,
                          n_wbins=args.n_wbins)
    f0, a, _ = sq.scaled_baseline(model, data)
    F = sq.sample_prior(f0, s.prior_sd_rel, s.n_candidates, np.random.default_rng(cfg["seed"]))
    grid = sq.StrengthGrid.around(f0, s.prior_sd_rel, s.n_bins, s.bin_range_sd)
    key = f"{args.model}_{args.dataset}_N{s.n_candidates}_b{s.n_bins}_w{s.n_wbins}_seed{cfg['seed']}"
    cache = Path(args.cache) / f"{key}.npz"
    t0 = time.perf_counter()
    if cache.exists():
        sim = sq.SimulatedSet.load(cache)
        if sq.sim_key(sim) != sq.sim_key(sq.SimulatedSet(sim.directions, data.U, F, np.ones(len(F)), grid, *[None] * 7)):
            raise SystemExit(f"{cache} does not match the candidates; delete it")
        precompute = {"loaded_from_cache_s": time.perf_counter() - t0, **sim.meta}
    else:
        sim, = sq.SimulatedSet.build(model, data.directions, data.U, F, [grid], s.n_wbins, n_threads=args.threads,
                                     progress=print)
        sim.save(cache)
        precompute = {"computed_s": time.perf_counter() - t0, **sim.meta}
    print(f"precompute: {json.dumps(precompute, default=float)}")
    print(f"seeds: candidates, session and its proposals {cfg['seed']} (config); check subsample "
          f"{args.check_subsample_seed}, check proposals {args.check_propose_seed}")

    st = sq.SequentialState(model, sim, data.force_scale, s, seed=cfg["seed"])
    rng = np.random.default_rng(cfg["seed"])
    rows = []
    for step in range(args.steps + 1):
        times = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            prop = st.propose(rng)
            times.append(time.perf_counter() - t)
        row = {"measurements_so_far": step, "remaining": len(st.remaining), "propose_s_median": float(np.median(times)),
               "propose_s_max": float(np.max(times)), "choice": prop.choice}
        if step < args.steps:
            i = data.directions.index(prop.choice)
            b = None if (data.alpha_lb is None or args.no_emg) else (data.alpha_lb[i], data.alpha_ub[i])
            t = time.perf_counter()
            st.update(prop.choice, float(data.forces[i]), b)
            row["update_s"] = time.perf_counter() - t
        rows.append(row)
        print(row, flush=True)

    # check: fast vs per-candidate Algorithm 9 on a 20,000-candidate subsample of the same set
    sub = np.random.default_rng(args.check_subsample_seed).choice(sim.N, 20000, replace=False)
    small, = sq.SimulatedSet.build(model, data.directions, data.U, F[sub], [grid], s.n_wbins, keep_alpha=True,
                                   n_threads=args.threads)
    st_small = sq.SequentialState(model, small, data.force_scale, s)
    fast = st_small.propose(np.random.default_rng(args.check_propose_seed))
    exact = st_small.propose(np.random.default_rng(args.check_propose_seed), exact=True)
    check = {"max_abs_dS_diff": float(np.abs(fast.dS - exact.dS).max()),
             "max_dS": float(np.abs(exact.dS).max()), "same_choice": fast.choice == exact.choice}
    print(f"fast vs exact Algorithm 9 (20,000-candidate subsample): {check}")
    out = {"model": args.model, "dataset": args.dataset, "emg_bounds_in_update": not args.no_emg, "n_candidates": s.n_candidates, "n_sim": s.n_sim,
           "n_bins": s.n_bins, "n_wbins": s.n_wbins, "directions": sim.K, "muscles": sim.m, "precompute": precompute,
           "seed": cfg["seed"], "check_subsample_seed": args.check_subsample_seed,
           "check_propose_seed": args.check_propose_seed, "steps": rows, "fast_vs_exact": check,
           "cpu": platform.processor() or platform.machine(),
           "cpus": os.cpu_count(), "load_average_1_5_15": os.getloadavg(),
           "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
    print(f"peak RSS {out['peak_rss_mb']:.0f} MB on {out['cpus']} CPUs (load average {os.getloadavg()}: other "
          "processes on the machine slow the timings)")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
