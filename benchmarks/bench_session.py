#!/usr/bin/env python
"""Benchmark: how long a clinician waits per step of `neckstrength session` (src/neckstrength/session.py).

For each model a session is started in a temporary folder (the candidate set is built once, or loaded from
``--cache``), then driven through every direction with simulated forces ``M(0.9 f'_base, u_i)``. Timed per step:
``proposal`` (Eq. 6.6 for every remaining direction, Algorithm 9, the part the issue's targets are about: < 1 s
for p2m7, a few seconds for s3m24), and ``step`` = log + update (Algorithm 8) + next proposal + rendering the
screen. Targets: p2m7 < 1 s, s3m24 a few seconds.

Run from the repository root::

    .venv/bin/python benchmarks/bench_session.py                          # p2m7 N_F 500,000; s3m24 N_F 20,000
    .venv/bin/python benchmarks/bench_session.py --models p2m7 --n-candidates p2m7=20000
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np


def bench(model: str, n_candidates: int, cache: str, config: str) -> dict:
    from neckstrength.session import Entry, Session, SessionOptions
    from neckstrength.wrench import solve

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        s = Session.start(Path(tmp) / "s", SessionOptions(model=model, participant="bench", config=config,
                                                          n_candidates=n_candidates, cache=cache,
                                                          criterion="thesis"),   # the thesis's scheme
                          progress=lambda x: print(x, flush=True))
        t_start = time.perf_counter() - t0
        w, _, _ = solve(s.model, 0.9 * s.model.strengths[None], s.sim.U)
        forces = w[0] / s.state.force_scale
        t_prop, t_step = [], []
        t = time.perf_counter()
        s.proposal()
        t_prop.append(time.perf_counter() - t)
        s.render()
        while s.state.remaining:
            d = s.choice(s.proposal())
            i = s.directions.index(d)
            t = time.perf_counter()
            s.accept(Entry("measure", d, float(round(forces[i], 1))))
            t1 = time.perf_counter()
            if s.state.remaining:
                s.proposal()
            t2 = time.perf_counter()
            s.render()
            t_step.append(time.perf_counter() - t)
            if s.state.remaining:
                t_prop.append(t2 - t1)
        return {"model": model, "n_candidates": n_candidates, "K": s.sim.K, "m": s.sim.m, "n_sim": s.settings.n_sim,
                "start_s": round(t_start, 2), "proposal_s_median": round(float(np.median(t_prop)), 3),
                "proposal_s_max": round(float(np.max(t_prop)), 3), "step_s_median": round(float(np.median(t_step)), 3),
                "step_s_max": round(float(np.max(t_step)), 3), "n_steps": len(t_step)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", nargs="+", default=["p2m7", "s3m24"])
    ap.add_argument("--n-candidates", nargs="*", default=["p2m7=500000", "s3m24=20000"], metavar="MODEL=N_F")
    ap.add_argument("--cache", default="results/session_cache")
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--json", default=None, help="also write the results here")
    a = ap.parse_args(argv)
    nf = {k: int(v) for k, v in (x.split("=") for x in a.n_candidates)}
    res = []
    for m in a.models:
        r = bench(m, nf.get(m, 20000), a.cache, a.config)
        print(json.dumps(r), flush=True)
        res.append(r)
    info = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(), "results": res}
    print(f"{'model':<7}{'N_F':>9}{'K':>4}{'start s':>9}{'proposal s (median/max)':>26}{'step s (median/max)':>22}")
    for r in res:
        print(f"{r['model']:<7}{r['n_candidates']:>9}{r['K']:>4}{r['start_s']:>9}"
              f"{r['proposal_s_median']:>15} / {r['proposal_s_max']:<8}{r['step_s_median']:>11} / {r['step_s_max']}")
    if a.json:
        Path(a.json).write_text(json.dumps(info, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
