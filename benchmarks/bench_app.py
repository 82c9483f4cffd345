#!/usr/bin/env python
"""Benchmark: a step of the clinician's session in the app (issue 34: tell -> next proposal on screen within 1 s).

For each participant, three sessions with the same options (default: s3m24 at the session's default candidate
count, config ``clinician.session.s3m24``; the joint posterior and the deficit decision) are driven through the
same tests with the participant's forces, step by step and interleaved, so all three see the same machine load:

- ``app``: ``POST /api/sessions/{name}/tell`` to the real app (uvicorn on 127.0.0.1, an HTTP client in this process)
  until its JSON answer, which carries the next proposal and everything the page shows, is parsed;
- ``engine``: the engine called directly as the terminal does: ``Session.tell`` then ``Session.propose`` (what the
  screen needs to show the next test);
- ``reference``: the same engine with its speed switches off (``Session.one_blas_thread`` and
  ``Session.concurrent_decision`` False: numpy's BLAS multi-threaded and the deficit decision updated after the
  joint posterior in the same process, as before 2026-11-28; ``JointPosterior.dual_bound_reject`` False in its
  samplers: every Metropolis-Hastings rejection decided by LPs), ``tell`` then ``propose``.

Participants (``--participants``): the thesis's 'norm' and 'weak' data sets (Table 5.3 f_a, forces = the model's
maximum force of f_a), and simulated ones made here: ``sim-deficit-<i>`` (every muscle f'_base x log-normal sd
0.15, the deficit group x U(0.25, 0.5)) and ``sim-normal-<i>`` (every muscle f'_base x log-normal sd 0.15); all
forces with 5% log-normal noise, streams ``bench_app/<participant>`` of the config seed.

Printed per step and summarised per session kind over every step of every participant: median, p95 and max step
time and the count within 1 s; the ratios engine / reference (the speed-up, same run, same load) and app / engine
(the web layer's cost). The proposals, estimates and decisions of the three sessions are checked equal at every
step (app and engine exactly, the reference to the solver's rounding, 1e-9 relative).

Run from the repository root::

    .venv/bin/python benchmarks/bench_app.py                       # s3m24, default candidates, 6 participants x 25
    .venv/bin/python benchmarks/bench_app.py --participants norm,weak --steps 10
    .venv/bin/python benchmarks/bench_app.py --model p2m7 --n-candidates 20000 --participants sim-normal-1 --steps 5
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

from neckstrength.testing import assert_close

DEFAULT_PARTICIPANTS = "norm,weak,sim-deficit-1,sim-deficit-2,sim-normal-1,sim-normal-2"


def participant_forces(name: str, model, U, force_scale, cfg, group_idx) -> np.ndarray:
    """The forces (N) of participant ``name`` in every test direction (see the module's doc)."""
    from neckstrength.estimation.datasets import thesis_f_actual
    from neckstrength.seeds import derive_rng
    from neckstrength.wrench import solve

    rng = derive_rng(int(cfg["seed"]), f"bench_app/{name}")
    if name in ("norm", "weak"):
        fa = thesis_f_actual(model, cfg["data"]["thesis_dir"], name)
    elif name.startswith(("sim-deficit-", "sim-normal-")):
        fa = model.strengths * np.exp(0.15 * rng.standard_normal(model.m))
        if name.startswith("sim-deficit-"):
            fa[group_idx] *= rng.uniform(0.25, 0.5, len(group_idx))
    else:
        raise SystemExit(f"unknown participant {name!r}: norm, weak, sim-deficit-<i>, sim-normal-<i>")
    w, _, _ = solve(model, fa[None], np.asarray(U))
    return w[0] / np.asarray(force_scale) * np.exp(0.05 * rng.standard_normal(len(force_scale)))


def _cpu_of(pid: int) -> float:
    """CPU seconds (user + system) of process ``pid`` so far (Linux; NaN elsewhere)."""
    try:
        f = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
        return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return float("nan")


def _stats(x: np.ndarray) -> str:
    return (f"median {np.median(x):.3f} s, p95 {np.percentile(x, 95):.3f} s, max {x.max():.3f} s, "
            f"within 1 s {int((x <= 1.0).sum())} of {len(x)}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="s3m24", choices=["p2m7", "p3m12", "s3m24"])
    ap.add_argument("--n-candidates", type=int, default=None, help="default: the session's (config)")
    ap.add_argument("--participants", default=DEFAULT_PARTICIPANTS,
                    help=f"comma-separated (default {DEFAULT_PARTICIPANTS})")
    ap.add_argument("--steps", type=int, default=25, help="tests measured per participant (default 25, all)")
    ap.add_argument("--threads", type=int, default=2, help="the joint posterior's solver threads (default 2)")
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--seed", type=int, default=None, help="session seed (default: the config's)")
    ap.add_argument("--no-reference", action="store_true", help="skip the reference sessions (quicker)")
    a = ap.parse_args(argv)

    import httpx
    import uvicorn

    from neckstrength.app import create_app
    from neckstrength.app.serve import free_port
    from neckstrength.config import load_config
    from neckstrength.session import Entry, Session, SessionOptions

    class Reference(Session):
        one_blas_thread = False
        concurrent_decision = False

    cfg = load_config(a.config)
    print(f"# bench_app: {platform.machine()} {platform.system()} {platform.release()}, python "
          f"{platform.python_version()}, cpus {len(os.sched_getaffinity(0))}, load average "
          f"{os.getloadavg()[0]:.2f}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}", flush=True)
    times: dict[str, list[float]] = {"app": [], "engine": [], "reference": [], "cpu_main": [], "cpu_worker": [],
                                   "cpu_reference": []}
    loads = []
    with tempfile.TemporaryDirectory() as tmp:
        cache = str(Path(tmp) / "cache")
        token = secrets.token_hex(16)
        app = create_app(Path(tmp) / "app", token, config=a.config, cache=cache, threads=a.threads)
        port = free_port()
        # keep-alive longer than a step of the other two sessions (else a reused connection can meet its close)
        server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning",
                                               timeout_keep_alive=3600))
        th = threading.Thread(target=server.run, daemon=True)
        th.start()
        while not server.started:
            time.sleep(0.05)
        client = httpx.Client(base_url=f"http://127.0.0.1:{port}", headers={"X-Neckstrength-Token": token},
                              timeout=600)
        for pi, who in enumerate(x.strip() for x in a.participants.split(",") if x.strip()):
            opts = SessionOptions(model=a.model, participant=who, config=a.config, n_candidates=a.n_candidates,
                                  cache=cache, seed=a.seed)
            t0 = time.perf_counter()
            eng = Session.create(Path(tmp) / f"engine-{pi}", opts, threads=a.threads)
            t_eng = time.perf_counter() - t0
            ref = None if a.no_reference else Reference.create(Path(tmp) / f"ref-{pi}", opts, threads=a.threads)
            if ref is not None:
                posts = [getattr(ref.state, "post", None)] + list(ref.decision.posts.values() if ref.decision else [])
                for post in filter(None, posts):
                    post.dual_bound_reject = False
            body = {"name": f"p{pi}", "model": a.model, "participant": who}
            body.update({k: v for k, v in (("n_candidates", a.n_candidates), ("seed", a.seed)) if v is not None})
            t0 = time.perf_counter()
            r = client.post("/api/sessions", json=body)
            r.raise_for_status()
            t_app = time.perf_counter() - t0
            st = r.json()
            gi = eng.decision.settings.group_indices(eng.muscles) if eng.decision is not None else np.array([], int)
            forces = participant_forces(who, eng.model, eng.U, eng.force_scale, cfg, gi)
            print(f"{who}: start engine {t_eng:.1f} s, app {t_app:.1f} s ({eng.criterion}, N "
                  f"{eng.settings.n_candidates}, {len(eng.directions)} tests, threads {a.threads})", flush=True)
            prop = eng.propose()
            assert prop["test"] == st["snapshot"]["proposal"]["test"]
            for k in range(min(a.steps, len(eng.directions))):
                test = prop["test"]
                f = float(round(forces[eng.directions.index(test)], 1))
                wpid = getattr(getattr(eng.decision, "_proc", None), "pid", None)
                c0, w0 = time.process_time(), (_cpu_of(wpid) if wpid else 0.0)
                t0 = time.perf_counter()
                eng.tell(Entry("measure", test, f))
                prop = eng.propose()
                t_e = time.perf_counter() - t0
                c_e, c_w = time.process_time() - c0, (_cpu_of(wpid) if wpid else 0.0) - w0
                t_r = np.nan
                c_r = np.nan
                if ref is not None:
                    c0 = time.process_time()
                    t0 = time.perf_counter()
                    ref.tell(Entry("measure", test, f))
                    rprop = ref.propose()
                    t_r = time.perf_counter() - t0
                    c_r = time.process_time() - c0
                    assert_close(rprop, prop, f"{who} step {k + 1}: proposal")
                t0 = time.perf_counter()
                r = client.post(f"/api/sessions/p{pi}/tell", json={"test": test, "force_N": f})
                r.raise_for_status()
                ans = r.json()
                t_a = time.perf_counter() - t0
                snap = ans["state"]["snapshot"]
                got, want = (snap["proposal"] or {}).get("test"), (prop or {}).get("test")
                assert got == want, (got, want)
                assert snap["estimate"] == eng.snapshot()["estimate"]
                if ref is not None:
                    rs = ref.snapshot()
                    assert_close(rs["estimate"], snap["estimate"], f"{who} step {k + 1}: estimate")
                    assert_close(rs["decision"], snap["decision"], f"{who} step {k + 1}: decision")
                load = os.getloadavg()[0]
                loads.append(load)
                times["app"].append(t_a)
                times["engine"].append(t_e)
                times["reference"].append(t_r)
                times["cpu_main"].append(c_e)
                times["cpu_worker"].append(c_w)
                times["cpu_reference"].append(c_r)
                print(f"{who} step {k + 1:2d}: {test:>14} {f:7.1f} N  app {t_a:.3f} s  engine {t_e:.3f} s (CPU "
                      f"{c_e:.2f} s + decision worker {c_w:.2f} s)  reference {t_r:.3f} s (CPU {c_r:.2f} s)  (load "
                      f"{load:.1f})",
                      flush=True)
                if prop is None or prop["test"] is None:
                    break
            _summary(a, who, times, loads, eng.settings.n_candidates)
        server.should_exit = True
        th.join(10)
        app.state.registry.close_all()
    _summary(a, "all", times, loads, eng.settings.n_candidates)
    return 0


def _summary(a, upto: str, times: dict, loads: list, n: int) -> None:
    """The summary of every step so far (after each participant, and at the end)."""
    ld = np.array(loads)
    e, ap_, rf = (np.array(times[x]) for x in ("engine", "app", "reference"))
    print(f"summary up to {upto} ({a.model}, N {n}, {a.participants}, {len(e)} steps, threads "
          f"{a.threads}; load {ld.min():.1f}-{ld.max():.1f}):", flush=True)
    print(f"  app:       {_stats(ap_)}")
    print(f"  engine:    {_stats(e)}")
    if not a.no_reference:
        print(f"  reference: {_stats(rf)}")
        print(f"  engine / reference: ratio of medians {np.median(e) / np.median(rf):.2f}, of maxima "
              f"{e.max() / rf.max():.2f}, of totals {e.sum() / rf.sum():.2f}")
    print(f"  app / engine: ratio of medians {np.median(ap_) / np.median(e):.2f}", flush=True)
    cm, cw = np.array(times["cpu_main"]), np.array(times["cpu_worker"])
    if len(cm):
        # CPU seconds per step: the session's process (all its threads) and the decision's worker process. Each
        # process's Python holds its interpreter lock most of the time, so on a quiet two-core machine a step takes
        # about the larger of the two (and at least half their sum): an estimate that the load here inflates less
        # than the wall-clock times (CPU time grows with the load too: shared caches)
        est = np.maximum(np.maximum(cm, cw), 0.5 * (cm + cw))
        print(f"  engine CPU per step: session process median {np.median(cm):.3f} s, max {cm.max():.3f} s; decision "
              f"worker median {np.median(cw):.3f} s, max {cw.max():.3f} s; quiet two-core estimate (the larger, at "
              f"least half the sum): {_stats(est)}", flush=True)
        cr = np.array(times["cpu_reference"])
        if not a.no_reference:
            print(f"  reference CPU per step (one process, the decision after the joint posterior): "
                  f"{_stats(cr)}; estimate / reference CPU: ratio of maxima {est.max() / cr.max():.2f}, of totals "
                  f"{est.sum() / cr.sum():.2f}", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
