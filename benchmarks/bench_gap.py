#!/usr/bin/env python
"""Benchmark: how long the gap diagnosis of one participant takes (issue 17, item 6), and where the time goes.

Times, for one data set of the measurement table with the config's diagnosis settings (default: s3m24, all nine
effects): the diagnosis without calibration (the fits of the ranking, pairs, refinement, bootstrap, reach
envelope) with the exact Jacobian and, as the reference measured in the same run, with forward differences
(``--reference``); then the calibrated diagnosis (noise-only and power replicates, ``gap.calibration``).
Every run uses the compiled all-direction solver pass of ``neckstrength.wrench.fused`` (the default,
``neckstrength.gap.fit.FUSED_SOLVER = True``). With ``--fused`` every run is repeated with the per-direction batched
solver (``FUSED_SOLVER = False``), the reference timed in the same run, and the two runs' summaries are compared
(decision, p-values, gaps: 1e-6). ``--only-calibrated`` times the calibrated diagnosis alone (with ``--fused``: it
against its reference).
Prints wall and CPU seconds per stage (CPU of the main process and of the worker processes) and the machine load
(``os.getloadavg``), and writes them as JSON. Timings on a shared machine are only comparable as ratios within one
run.

Run from the repository root::

    .venv/bin/python benchmarks/bench_gap.py                                  # s3m24, S003, full config
    .venv/bin/python benchmarks/bench_gap.py --dataset S005 --reference --out bench_gap.json
    .venv/bin/python benchmarks/bench_gap.py --workers 2 --fused     # the fused pass against the per-direction solver
    .venv/bin/python benchmarks/bench_gap.py --fused --only-calibrated --out bench_gap_cal.json
    .venv/bin/python benchmarks/bench_gap.py --staged --only-calibrated --workers 2   # against the one-stage screen
    .venv/bin/python benchmarks/bench_gap.py --only-calibrated --workers 2 --against-src ../ref/src   # older code

``--against-src DIR`` times the same command twice in fresh processes, first with the package imported from ``DIR``
(e.g. the ``src`` of a ``git worktree`` of an older commit: the reference), then with this checkout's, and prints
the ratios of CPU (main and worker processes), wall and peak resident memory, and whether the summaries agree.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import replace


def run(cfg_path: str, model: str, dataset: str, reference: bool, calibrate: bool, effects=None,
        workers: int = 1, fused: bool = False, only_calibrated: bool = False, staged: bool = False) -> dict:
    import neckstrength.gap.calibrate as calmod
    import neckstrength.gap.fit as fitmod
    from neckstrength.config import build_directions, diagnosis_settings, gap_blind_dataset, gap_context, load_config
    from neckstrength.gap.diagnose import diagnose

    cfg = load_config(cfg_path)
    if effects:
        cfg["gap"]["effects"] = list(effects)
    directions = build_directions(cfg)
    ctx = gap_context(cfg, model, directions)
    data = gap_blind_dataset(cfg, ctx, directions, dataset)
    s = diagnosis_settings(cfg)
    out: dict = {"model": model, "dataset": dataset, "effects": list(s.effects), "platform": platform.platform(),
                 "cpu_count": os.cpu_count(), "workers": workers}
    runs = [] if only_calibrated else [("exact_gradient", replace(s, calibration=replace(s.calibration,
                                                                                         replicates=0)))]
    if reference and not only_calibrated:
        runs.append(("finite_differences", replace(s, calibration=replace(s.calibration, replicates=0),
                                                   fit=replace(s.fit, exact_gradient=False))))
    if calibrate and s.calibration.replicates > 0:
        runs.append(("calibrated", s))
    if fused:      # the reference (per-direction solver) first: its caches and compilation cannot favour the pass
        runs = [(tag + "_per_direction", st) for tag, st in runs] + runs
    if staged:     # the reference first: power with the null in one screen, sensitivity with `replicates` each
        runs = [(tag + "_one_stage", replace(st, calibration=replace(st.calibration, sensitivity_replicates=None)))
                for tag, st in runs if tag == "calibrated"] + runs
    default = fitmod.FUSED_SOLVER
    _warm_up(ctx)
    for tag, st in runs:
        fitmod.FUSED_SOLVER = not tag.endswith("_per_direction")
        calmod.POWER_IN_TWO_STAGES = not tag.endswith("_one_stage")
        t0, c0, l0 = time.perf_counter(), time.process_time(), os.getloadavg()[0]
        k0 = os.times().children_user + os.times().children_system
        stages = []

        def say(msg, t0=t0, stages=stages):
            stages.append((round(time.perf_counter() - t0, 1), msg))
            print(f"[{tag} {time.perf_counter() - t0:.0f} s] {msg}", flush=True)

        d = diagnose(ctx, [data], st, progress=say, workers=workers)[0]
        out[tag] = {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
                    "cpu_workers_s": os.times().children_user + os.times().children_system - k0,
                    "load_before": l0, "load_after": os.getloadavg()[0], "decision": d.summary.get("decision"),
                    "gap_before": d.summary["gap_before"], "gap_after": d.summary["gap_after"], "stages": stages,
                    "summary": {k: v for k, v in d.summary.items() if isinstance(v, (str, int, float, bool))},
                    "ranking": d.effects[["candidate", "gap_cv"]].to_dict("list"),
                    "power": d.power.to_dict("list") if len(d.power) else {},
                    "sensitivity": d.summary.get("sensitivity", []),
                    # peak resident memory so far (this process; the largest worker process waited for)
                    "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                    "maxrss_workers_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}
        print(f"{tag}: {out[tag]['wall_s']:.0f} s wall, {out[tag]['cpu_s']:.0f} s CPU (+ "
              f"{out[tag]['cpu_workers_s']:.0f} s in worker processes), load "
              f"{l0:.1f} -> {out[tag]['load_after']:.1f}: {d.summary.get('decision')}", flush=True)
    fitmod.FUSED_SOLVER = default
    calmod.POWER_IN_TWO_STAGES = True
    if staged and "calibrated_one_stage" in out:
        a, b = out["calibrated"], out["calibrated_one_stage"]
        cpu_a, cpu_b = a["cpu_s"] + a["cpu_workers_s"], b["cpu_s"] + b["cpu_workers_s"]
        import pandas as pd

        same_power = pd.DataFrame(a["power"]).equals(pd.DataFrame(b["power"]))      # NaN where no replicate
        diffs = _differences(a, b) + ([] if same_power else ["power table"])
        out["staged_ratio_cpu"], out["staged_differences"] = cpu_b / cpu_a, diffs
        print(f"calibrated: power in two stages, sensitivity {a['sensitivity'][0].get('replicates')} replicates "
              f"per end: {cpu_a:.1f} s CPU ({a['wall_s']:.0f} s wall) vs one screen, sensitivity as the null: "
              f"{cpu_b:.1f} s CPU ({b['wall_s']:.0f} s wall): {cpu_b / cpu_a:.2f}x less CPU, "
              f"{b['wall_s'] / a['wall_s']:.2f}x less wall; "
              f"{'decision, summary, ranking and power table equal to 1e-6' if not diffs else 'DIFFERENT: ' + '; '.join(diffs[:5])}"
              "; sensitivity rows: " + "; ".join(f"{r['noise']}: {r['named']} p {r['p_value']:.3g}"
                                                  for r in a["sensitivity"]) + " (vs "
              + "; ".join(f"{r['noise']}: {r['named']} p {r['p_value']:.3g}" for r in b["sensitivity"]) + ")",
              flush=True)
    if fused:
        for tag, _ in runs:
            if tag.endswith("_per_direction"):
                continue
            a, b = out[tag], out[tag + "_per_direction"]
            cpu_a, cpu_b = a["cpu_s"] + a["cpu_workers_s"], b["cpu_s"] + b["cpu_workers_s"]
            diffs = _differences(a, b)
            out[tag + "_solver_ratio_cpu"] = cpu_b / cpu_a
            out[tag + "_solver_differences"] = diffs
            print(f"{tag}: fused pass {cpu_a:.1f} s CPU ({a['wall_s']:.0f} s wall) vs per-direction solver "
                  f"{cpu_b:.1f} s CPU ({b['wall_s']:.0f} s wall): {cpu_b / cpu_a:.2f}x less CPU; "
                  f"{'results equal to 1e-6' if not diffs else 'DIFFERENT: ' + '; '.join(diffs[:5])}", flush=True)
    if reference and not only_calibrated:
        out["speedup_cpu"] = out["finite_differences"]["cpu_s"] / out["exact_gradient"]["cpu_s"]
        print(f"exact Jacobian vs finite differences: {out['speedup_cpu']:.2f}x less CPU")
    return out


def against(src: str, argv: list[str]) -> dict:
    """The benchmark with ``argv`` in two fresh processes, the package first from ``src`` (the reference), then
    from this checkout; returns both results and prints the ratios (reference / this) and the differences."""
    here = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "src")
    res = {}
    for tag, path in (("reference", os.path.abspath(src)), ("this", here)):
        with tempfile.TemporaryDirectory() as tmp:
            out = os.path.join(tmp, "out.json")
            env = {**os.environ, "PYTHONPATH": path + os.pathsep + os.environ.get("PYTHONPATH", "")}
            print(f"--- {tag}: package from {path}", flush=True)
            subprocess.run([sys.executable, os.path.abspath(__file__), *argv, "--out", out], env=env, check=True)
            with open(out) as fh:
                res[tag] = json.load(fh)
    for k, v in res["this"].items():
        if not isinstance(v, dict) or "wall_s" not in v or k not in res["reference"]:
            continue
        a, b = v, res["reference"][k]
        cpu_a, cpu_b = a["cpu_s"] + a["cpu_workers_s"], b["cpu_s"] + b["cpu_workers_s"]
        rss_a = max(a["maxrss_mb"], a["maxrss_workers_mb"])
        rss_b = max(b["maxrss_mb"], b["maxrss_workers_mb"])
        diffs = _differences(a, b)
        import pandas as pd

        if not pd.DataFrame(a["power"]).equals(pd.DataFrame(b["power"])):
            diffs.append("power table")
        if not _close(a["sensitivity"], b["sensitivity"]):
            diffs.append("sensitivity")
        res[k + "_against"] = {"ratio_cpu": cpu_b / cpu_a, "ratio_wall": b["wall_s"] / a["wall_s"],
                               "rss_mb": [rss_b, rss_a], "differences": diffs}
        print(f"{k}: this {cpu_a:.1f} s CPU ({a['cpu_workers_s']:.1f} s of it in workers), {a['wall_s']:.1f} s wall, "
              f"peak RSS {rss_a:.0f} MB; reference {cpu_b:.1f} s CPU ({b['cpu_workers_s']:.1f}), {b['wall_s']:.1f} s "
              f"wall, {rss_b:.0f} MB: {cpu_b / cpu_a:.2f}x less CPU, {b['wall_s'] / a['wall_s']:.2f}x less wall, "
              f"{rss_b / rss_a:.2f}x less memory; load {b['load_before']:.1f} -> {a['load_after']:.1f}; "
              + ("decision, summary, ranking, power table and sensitivity equal to 1e-6" if not diffs
                 else "DIFFERENT: " + "; ".join(diffs[:5])), flush=True)
    return res


def _warm_up(ctx) -> None:
    """Load both solver paths' compiled code (numba's cache) before anything is timed."""
    import numpy as np

    from neckstrength.gap.effects import base_instance
    from neckstrength.wrench import solve
    from neckstrength.wrench.batched import BasisCache

    inst = base_instance(ctx)
    model = inst.reduced(ctx.model)
    U = inst.task_directions(ctx.model)
    lb, ub = np.repeat(inst.lb, inst.J, axis=0), np.repeat(inst.ub, inst.J, axis=0)
    F = inst.strengths(ctx.model.strengths[None] * np.array([[1.0], [0.9], [1.1]]))
    for fused in (False, True):
        solve(model, F, U, lb, ub, cache=BasisCache(fused=fused))


def _close(x, y, tol: float = 1e-6) -> bool:
    """Two JSON values equal, numbers to ``tol`` relative (NaN equal to NaN)."""
    if isinstance(x, dict) and isinstance(y, dict):
        return x.keys() == y.keys() and all(_close(x[k], y[k], tol) for k in x)
    if isinstance(x, list) and isinstance(y, list):
        return len(x) == len(y) and all(_close(u, v, tol) for u, v in zip(x, y))
    if isinstance(x, float) and isinstance(y, (int, float)) and not isinstance(y, bool):
        return x == y or abs(x - y) <= tol * max(1.0, abs(y)) or (x != x and y != y)
    return x == y


def _differences(a: dict, b: dict, tol: float = 1e-6) -> list[str]:
    """Where two runs' summaries and rankings differ (numbers beyond ``tol`` relative, anything else unequal)."""
    out = []
    for k in sorted(set(a["summary"]) | set(b["summary"])):
        x, y = a["summary"].get(k), b["summary"].get(k)
        if isinstance(x, float) and isinstance(y, float):
            if not (x == y or abs(x - y) <= tol * max(1.0, abs(y)) or (x != x and y != y)):
                out.append(f"{k}: {x} vs {y}")
        elif x != y:
            out.append(f"{k}: {x} vs {y}")
    ra, rb = a["ranking"], b["ranking"]
    if ra["candidate"] != rb["candidate"]:
        out.append("ranking order")
    elif any(abs(x - y) > tol * max(1.0, abs(y)) for x, y in zip(ra["gap_cv"], rb["gap_cv"])):
        out.append("ranking gap_cv")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--model", default="s3m24")
    ap.add_argument("--dataset", default="S003")
    ap.add_argument("--reference", action="store_true", help="also time finite-difference Jacobians")
    ap.add_argument("--no-calibration", action="store_true")
    ap.add_argument("--effects", default=None, help="comma-separated effects (default: config gap.effects)")
    ap.add_argument("--out", default=None, help="JSON file for the timings")
    ap.add_argument("--workers", type=int, default=1, help="processes for the calibration's screen")
    ap.add_argument("--fused", action="store_true",
                    help="also time every run with the per-direction solver (gap.fit.FUSED_SOLVER = False), the "
                         "reference")
    ap.add_argument("--only-calibrated", action="store_true", help="time the calibrated diagnosis only")
    ap.add_argument("--staged", action="store_true",
                    help="also time the calibrated diagnosis as before 2026-11-28 (the reference: power replicates "
                         "in the null's screen, gap.calibration.POWER_IN_TWO_STAGES = False; sensitivity with "
                         "`replicates` per end)")
    ap.add_argument("--against-src", default=None, metavar="DIR",
                    help="time the same command with the package from DIR first (the reference, e.g. an older "
                         "commit's src), then with this checkout's, each in a fresh process")
    a = ap.parse_args()
    if a.against_src:
        argv = [x for x in sys.argv[1:]]
        i = argv.index("--against-src")
        del argv[i:i + 2]
        if "--out" in argv:
            i = argv.index("--out")
            del argv[i:i + 2]
        res = against(a.against_src, argv)
        if a.out:
            with open(a.out, "w") as fh:
                json.dump(res, fh, indent=2)
        return
    res = run(a.config, a.model, a.dataset, a.reference, not a.no_calibration,
              a.effects.split(",") if a.effects else None, a.workers, a.fused, a.only_calibrated, a.staged)
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(res, fh, indent=2)


if __name__ == "__main__":
    main()
