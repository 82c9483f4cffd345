#!/usr/bin/env python
"""Benchmark: a step of the clinician's session in the app (issue 34: tell -> next proposal on screen within 1 s).

Two sessions with the same options (default: s3m24 at the session's default candidate count, config
``clinician.session.s3m24``; the joint posterior and the deficit decision) are driven through the same tests with
simulated forces ``M(0.9 f'_base, u_i)``, step by step and interleaved, so both see the same machine load:

- ``app``: ``POST /api/sessions/{name}/tell`` to the real app (uvicorn on 127.0.0.1, an HTTP client in this process)
  until its JSON answer, which carries the next proposal and everything the page shows, is parsed;
- ``engine``: the reference, the engine called directly as the terminal does: ``Session.tell`` then
  ``Session.propose`` (what the screen needs to show the next test).

Printed per step and summarised: the median and max of each, and the ratio app / engine (the web layer's cost:
the snapshot with the predicted forces, JSON, HTTP). The proposals and estimates of both sessions are checked equal.

Run from the repository root::

    .venv/bin/python benchmarks/bench_app.py                         # s3m24, default candidates, 6 steps
    .venv/bin/python benchmarks/bench_app.py --model p2m7 --n-candidates 20000 --steps 5
"""

from __future__ import annotations

import argparse
import os
import platform
import secrets
import tempfile
import threading
import time
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="s3m24", choices=["p2m7", "p3m12", "s3m24"])
    ap.add_argument("--n-candidates", type=int, default=None, help="default: the session's (config)")
    ap.add_argument("--steps", type=int, default=6, help="tests measured (default 6)")
    ap.add_argument("--threads", type=int, default=2, help="the joint posterior's solver threads (default 2)")
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--seed", type=int, default=None, help="session seed (default: the config's)")
    a = ap.parse_args(argv)

    import httpx
    import uvicorn

    from neckstrength.app import create_app
    from neckstrength.app.serve import free_port
    from neckstrength.session import Entry, Session, SessionOptions
    from neckstrength.wrench import solve

    print(f"# bench_app: {platform.machine()} {platform.system()} {platform.release()}, python "
          f"{platform.python_version()}, cpus {len(os.sched_getaffinity(0))}, load average "
          f"{os.getloadavg()[0]:.2f}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        cache = str(Path(tmp) / "cache")
        opts = SessionOptions(model=a.model, participant="bench", config=a.config, n_candidates=a.n_candidates,
                              cache=cache, seed=a.seed)
        t0 = time.perf_counter()
        eng = Session.create(Path(tmp) / "engine", opts, threads=a.threads)
        t_eng = time.perf_counter() - t0
        token = secrets.token_hex(16)
        app = create_app(Path(tmp) / "app", token, config=a.config, cache=cache, threads=a.threads)
        port = free_port()
        server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
        th = threading.Thread(target=server.run, daemon=True)
        th.start()
        while not server.started:
            time.sleep(0.05)
        client = httpx.Client(base_url=f"http://127.0.0.1:{port}", headers={"X-Neckstrength-Token": token},
                              timeout=600)
        body = {"name": "bench", "model": a.model, "participant": "bench"}
        body.update({k: v for k, v in (("n_candidates", a.n_candidates), ("seed", a.seed)) if v is not None})
        t0 = time.perf_counter()
        r = client.post("/api/sessions", json=body)
        r.raise_for_status()
        t_app = time.perf_counter() - t0
        st = r.json()
        print(f"start: engine {t_eng:.1f} s, app {t_app:.1f} s ({eng.criterion}, N {eng.settings.n_candidates}, "
              f"{len(eng.directions)} tests, threads {a.threads})", flush=True)
        w, _, _ = solve(eng.model, 0.9 * eng.model.strengths[None], np.asarray(eng.U))
        forces = w[0] / np.asarray(eng.force_scale)
        prop = eng.propose()
        assert prop["test"] == st["snapshot"]["proposal"]["test"]
        rows = []
        for k in range(min(a.steps, len(eng.directions))):
            test = prop["test"]
            f = float(round(forces[eng.directions.index(test)], 1))
            t0 = time.perf_counter()
            eng.tell(Entry("measure", test, f))
            prop = eng.propose()
            t_e = time.perf_counter() - t0
            t0 = time.perf_counter()
            r = client.post("/api/sessions/bench/tell", json={"test": test, "force_N": f})
            r.raise_for_status()
            ans = r.json()
            t_a = time.perf_counter() - t0
            snap = ans["state"]["snapshot"]
            assert snap["proposal"]["test"] == prop["test"], (snap["proposal"]["test"], prop["test"])
            assert snap["estimate"] == eng.snapshot()["estimate"]
            load = os.getloadavg()[0]
            rows.append((t_e, t_a, load))
            print(f"step {k + 1}: {test:>12} {f:7.1f} N  engine {t_e:.3f} s  app {t_a:.3f} s  "
                  f"ratio {t_a / t_e:.2f}  (load {load:.1f})", flush=True)
        server.should_exit = True
        th.join(10)
        app.state.registry.close_all()
    e, ap_, ld = (np.array(x) for x in zip(*rows))
    print(f"summary ({a.model}, N {eng.settings.n_candidates}, {len(rows)} steps): engine median {np.median(e):.3f} "
          f"s max {e.max():.3f} s; app median {np.median(ap_):.3f} s max {ap_.max():.3f} s; ratio of medians "
          f"{np.median(ap_) / np.median(e):.2f}, per step {np.min(ap_ / e):.2f}-{np.max(ap_ / e):.2f}; within 1 s: "
          f"{int((ap_ <= 1.0).sum())} of {len(rows)} steps; load {ld.min():.1f}-{ld.max():.1f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
