#!/usr/bin/env python
"""Benchmark: how long a clinician waits in `neckstrength session` (src/neckstrength/session/).

For each model a session is started in a temporary folder (the candidate set is built, or loaded from
``--cache`` when it holds one with the same key; ``--fresh`` ignores it), then driven through every
direction with simulated forces ``M(0.9 f'_base, u_i)``. Timed: ``start`` (``Session.start``: model,
candidates, candidate set, header), and per step the parts a clinician waits for after typing a force:
``log`` (the fsync'd log record), ``update`` (Algorithm 8 for the measurement), ``proposal`` (Eq. 6.6
for every remaining direction, Algorithm 9) and ``screen`` (rendering the estimate and the proposal).
Targets (issue 16, s3m24 at N_F = 500,000): start < 60 s, every step < 1 s.

Run from the repository root::

    .venv/bin/python benchmarks/bench_session.py                          # s3m24, N_F 500,000, fresh build
    .venv/bin/python benchmarks/bench_session.py --models p2m7 s3m24 --n-candidates p2m7=500000 s3m24=20000
    .venv/bin/python benchmarks/bench_session.py --criterion joint_eig --threads 2    # the s3m24 default session
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import tempfile
import time
from pathlib import Path

import numpy as np


def bench(model: str, n_candidates: int | None, cache: str, config: str, verbose: bool = True,
          criterion: str = "thesis", threads: int = 0) -> dict:
    from neckstrength.session import Entry, Session, SessionOptions
    from neckstrength.wrench import solve

    with tempfile.TemporaryDirectory() as tmp:
        c0 = time.process_time()
        t0 = time.perf_counter()
        s = Session.start(Path(tmp) / "s", SessionOptions(model=model, participant="bench", config=config,
                                                          n_candidates=n_candidates, cache=cache,
                                                          criterion=criterion),   # default: the thesis's scheme
                          progress=lambda x: print(x, flush=True) if verbose else None, threads=threads)
        t_start = time.perf_counter() - t0
        c_start = time.process_time() - c0
        print(f"start: {t_start:.1f} s (CPU {c_start:.1f} s, load average {os.getloadavg()[0]:.2f})", flush=True)
        U = s.U if s.joint else s.sim.U
        w, _, _ = solve(s.model, 0.9 * s.model.strengths[None], U)
        forces = w[0] / s.state.force_scale
        # time the parts of Session.accept: the log append and Algorithm 8 (state.likelihood)
        parts = {"log": 0.0, "update": 0.0}

        def timed(name, fn):
            def wrapper(*a, **k):
                t = time.perf_counter()
                try:
                    return fn(*a, **k)
                finally:
                    parts[name] += time.perf_counter() - t
            return wrapper

        s.log.append = timed("log", s.log.append)
        s.state.likelihood = timed("update", s.state.likelihood)
        t = time.perf_counter()
        s.proposal()
        t_first = time.perf_counter() - t
        t = time.perf_counter()
        s.render()
        print(f"first proposal {t_first:.3f} s, screen {time.perf_counter() - t:.3f} s", flush=True)
        steps = []
        while s.state.remaining:
            d = s.choice(s.proposal())
            i = s.directions.index(d)
            parts["log"] = parts["update"] = 0.0
            t = time.perf_counter()
            s.accept(Entry("measure", d, float(round(forces[i], 1))))
            t1 = time.perf_counter()
            if s.state.remaining:
                s.proposal()
            t2 = time.perf_counter()
            s.render()
            t3 = time.perf_counter()
            st = {"direction": d, "log": parts["log"], "update": parts["update"],
                  "accept_other": t1 - t - parts["log"] - parts["update"], "proposal": t2 - t1, "screen": t3 - t2,
                  "total": t3 - t, "load": os.getloadavg()[0]}
            steps.append(st)
            print(f"step {len(steps):2d} {d:>14}: log {st['log']:.3f} s, update {st['update']:.3f} s, proposal "
                  f"{st['proposal']:.3f} s, screen {st['screen']:.3f} s, total {st['total']:.3f} s "
                  f"(load {st['load']:.2f})", flush=True)
        tot = [x["total"] for x in steps]
        return {"model": model, "criterion": s.criterion, "n_candidates": s.settings.n_candidates,
                "threads": s.threads if s.joint else 1, "K": len(U), "m": s.model.m, "n_sim": s.settings.n_sim,
                "start_s": round(t_start, 2), "start_cpu_s": round(c_start, 2), "first_proposal_s": round(t_first, 3),
                "step_s_median": round(float(np.median(tot)), 3), "step_s_max": round(float(np.max(tot)), 3),
                "max_s": {k: round(max(x[k] for x in steps), 3) for k in ("log", "update", "proposal", "screen")},
                "n_steps": len(steps)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", nargs="+", default=["s3m24"])
    ap.add_argument("--n-candidates", nargs="*", default=None, metavar="MODEL=N_F",
                    help="default: p2m7=500000 s3m24=500000 for the thesis's scheme; the session's own N for the joint")
    ap.add_argument("--cache", default=None, help="candidate-set cache folder (default: a fresh temporary one)")
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--json", default=None, help="also write the results here")
    ap.add_argument("--criterion", default="thesis", choices=["thesis", "joint_eig", "marginal_entropy"],
                    help="thesis (default): Algorithms 7-9 with N_F of --n-candidates; joint_eig / "
                         "marginal_entropy: the joint posterior with N of --n-candidates, or config "
                         "clinician.session.<model> if not given")
    ap.add_argument("--threads", type=int, default=0, help="the joint posterior's solver threads (0 = every core)")
    a = ap.parse_args(argv)
    spec = a.n_candidates if a.n_candidates is not None else (
        ["p2m7=500000", "s3m24=500000"] if a.criterion == "thesis" else [])
    nf = {k: int(v) for k, v in (x.split("=") for x in spec)}
    print(f"# bench_session: {platform.machine()} {platform.system()} {platform.release()}, python "
          f"{platform.python_version()}, cpus {len(os.sched_getaffinity(0))}, load average "
          f"{os.getloadavg()[0]:.2f}, {time.strftime('%Y-%m-%d %H:%M')}", flush=True)
    res = []
    for m in a.models:
        with tempfile.TemporaryDirectory() as cache:
            r = bench(m, nf.get(m, 20000 if a.criterion == "thesis" else None), a.cache or cache, a.config,
                      criterion=a.criterion, threads=a.threads)
        print(json.dumps(r), flush=True)
        res.append(r)
    info = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
            "peak_memory_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024), "results": res}
    print(f"{'model':<7}{'N_F':>9}{'K':>4}{'start s':>9}{'step s (median/max)':>22}  max log/update/proposal/screen s")
    for r in res:
        mx = r["max_s"]
        print(f"{r['model']:<7}{r['n_candidates']:>9}{r['K']:>4}{r['start_s']:>9}{r['step_s_median']:>11} / "
              f"{r['step_s_max']:<8}  {mx['log']} / {mx['update']} / {mx['proposal']} / {mx['screen']}")
    print(f"peak memory (ru_maxrss): {info['peak_memory_mib']} MiB")
    if a.json:
        Path(a.json).write_text(json.dumps(info, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
