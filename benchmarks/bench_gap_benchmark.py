#!/usr/bin/env python
"""The withheld-effect benchmark of the gap diagnosis (issue 17, item 4) in stratified order, scored as it goes.

Generates exactly the cases of the rule ``gap_benchmark`` (same settings, same seed stream
``gap-benchmark/{model}``), but diagnoses them in a *stratified* order: every case gets the key
``(rank within its group + 0.5) / group size`` (group = injected effect and tier), so that any prefix of the
order is a proportional sample of the design (every effect, the mismatch tier; the controls twice as fast, so all
of them are in the first half). Each batch is stored in
the rule's resume folder (``results/gap/{model}/benchmark/resume``) as it finishes, so the rule later reuses it
(the diagnoses are made blind without power tables and the power of each case's injected effect is simulated
afterwards, as the rule does: ``neckstrength.gap.benchmark.benchmark_power``),
and after each batch the cases done so far are scored (``score_benchmark``: per case, accuracy by detectability
and size) into ``--out``. A run stopped by ``--max-seconds`` (or interrupted) leaves a valid stratified subset;
a rerun resumes.

Run from the repository root (the full design on 2 cores, as timed in the README: one batch of all cases, its
effects' fits shared out over 2 processes)::

    .venv/bin/python benchmarks/bench_gap_benchmark.py --jobs 2 --out results/gap/s3m24/benchmark_partial
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path


def stratified_order(cases, control_rate: float = 2.0) -> list[int]:
    """Indices of ``cases`` such that every prefix samples each (label, tier) group in proportion to its size,
    the controls (label 'none') ``control_rate`` times as fast (with 2: all controls within the first half), so
    that a partial run has the controls the false-alarm rate needs. Within a group the generator's (shuffled)
    order is kept."""
    groups: dict[tuple[str, str], list[int]] = {}
    for k, c in enumerate(cases):
        groups.setdefault((c.label, c.tier), []).append(k)
    keyed = [((r + 0.5) / len(ix) / (control_rate if g[0] == "none" else 1.0), g, r, k)
             for g, ix in groups.items() for r, k in enumerate(ix)]
    return [k for *_, k in sorted(keyed)]


def _score(ctx, cases, done, power, ds, out, cfg, model, t0, c0) -> dict:
    """Score the cases in ``done`` and write cases.csv, accuracy.csv, effect_size.csv, summary.json to ``out``."""
    from neckstrength.gap.benchmark import score_benchmark
    from neckstrength.io import atomic_write_csv, atomic_write_text

    sub = [c for c in cases if c.name in done]
    tabs = score_benchmark(ctx, sub, [done[c.name] for c in sub], ds.epsilon, power)
    pc = tabs["per_case"]
    ctrl = pc[pc["injected"] == "none"]
    det = pc[(pc["injected"] != "none") & pc["detectable"]]
    summ = {"model": model, "seed": cfg["seed"], "cases_done": len(sub), "cases_design": len(cases),
            "controls": len(ctrl), "false_alarms": int((ctrl["identified"] != "none").sum()),
            "detectable_cases": len(det), "detectable_correct": int(det["correct"].sum()),
            "effect_cases": int((pc["injected"] != "none").sum()),
            "effect_cases_correct": int(pc.loc[pc["injected"] != "none", "correct"].sum()),
            "wrong_effect_named": int(((pc["identified"] != "none") & ~pc["correct"]).sum()),
            "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}
    atomic_write_csv(tabs["per_case"], out / "cases.csv", float_format="%.4g")
    atomic_write_csv(tabs["accuracy"], out / "accuracy.csv", float_format="%.4g")
    atomic_write_csv(tabs["effect_size"], out / "effect_size.csv", float_format="%.4g")
    atomic_write_csv(tabs["confusion"], out / "confusion.csv")
    atomic_write_text(json.dumps(summ, indent=2), out / "summary.json")
    return summ


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--model", default=None, help="default: gap.benchmark.model")
    ap.add_argument("--chunk", type=int, default=None,
                    help="cases per stored batch (default: gap.benchmark.chunk; results do not depend on it)")
    ap.add_argument("--max-seconds", type=float, default=None, help="start no new batch after this long")
    ap.add_argument("--out", required=True, help="folder for the partial score tables")
    ap.add_argument("--score-only", action="store_true", help="diagnose nothing: score the cases already stored")
    ap.add_argument("--jobs", type=int, default=1, help="processes: several batches, one batch at a time each; one "
                    "batch, its effects' fits shared out over them")
    a = ap.parse_args(argv)

    from neckstrength.config import build_directions, load_config
    from neckstrength.gap.benchmark import benchmark_power, blind, decision_settings, generate_cases
    from neckstrength.gap.diagnose import BlindData, diagnose
    from neckstrength.gap.store import ResultStore
    from neckstrength.pipeline.gap import benchmark_setup

    t0, c0 = time.perf_counter(), time.process_time()
    cfg = load_config(a.config)
    model = a.model or cfg["gap"]["benchmark"]["model"]
    ctx, bs, ds, rng = benchmark_setup(cfg, model, build_directions(cfg))
    cases = generate_cases(ctx, bs, rng)
    order = stratified_order(cases)
    a.chunk = a.chunk or cfg["gap"]["benchmark"].get("chunk") or len(cases)
    store = ResultStore(Path("results/gap") / model / "benchmark" / "resume", ctx, decision_settings(ds))
    power_store = ResultStore(Path("results/gap") / model / "benchmark" / "resume", ctx, ds)
    power: dict = {}
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)

    def say(msg):
        print(f"[{time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU, load "
              f"{os.getloadavg()[0]:.1f}] {msg}", flush=True)

    say(f"{model}: {len(cases)} cases; seed {cfg['seed']} stream gap-benchmark/{model}; stratified order")
    done: dict[str, object] = {}
    summ: dict = {}
    if a.score_only:                       # the stored cases (diagnosis and, for effect cases, power) in order
        keep = []
        for k in order:
            c = cases[k]
            d = store.get(blind([c])[0])
            p = power_store.get(BlindData(f"{c.name}/power/{c.label}", c.forces)) if len(c.injected) == 1 else None
            if d is not None and (len(c.injected) != 1 or p is not None):
                done[c.name] = d
                if p is not None:
                    power[c.name] = p
                keep.append(k)
        say(f"score only: {len(keep)} of {len(cases)} cases stored")
        order = []
        summ = _score(ctx, cases, done, power, ds, out, cfg, model, t0, c0)
    parts = [[cases[k] for k in order[a0:a0 + a.chunk]] for a0 in range(0, len(order), a.chunk)]

    def stop() -> bool:
        if a.max_seconds is not None and time.perf_counter() - t0 > a.max_seconds:
            say(f"stopping: --max-seconds {a.max_seconds:g} reached (no new batch is started)")
            return True
        return False

    def finish(i: int, tb: float | None = None) -> None:
        nonlocal summ
        part = parts[i]
        diags = diagnose(ctx, blind(part), decision_settings(ds), say, store=store, chunk=a.chunk, workers=a.jobs)
        power.update(benchmark_power(ctx, part, diags, ds, say, store=power_store, chunk=a.chunk, workers=a.jobs))
        for c, d in zip(part, diags):
            done[c.name] = d
        summ = _score(ctx, cases, done, power, ds, out, cfg, model, t0, c0)
        got = ", ".join(f"{c.name} {c.label}/{c.tier} -> " + done[c.name].summary["chosen"] for c in part)
        say(f"batch {i + 1}: {got} " + (f"({time.process_time() - tb:.0f} s CPU)" if tb is not None else "(in a worker)")
            + f"; so far {summ['cases_done']} cases: "
            f"false alarms {summ['false_alarms']}/{summ['controls']}, detectable correct {summ['detectable_correct']}/"
            f"{summ['detectable_cases']}, effect cases correct {summ['effect_cases_correct']}/{summ['effect_cases']}")

    if a.jobs > 1 and len(parts) > 1:        # batches in worker processes; one batch: its effects shared out
        from neckstrength.gap.benchmark import diagnose_in_workers

        diagnose_in_workers(ctx, parts, ds, store, power_store, a.jobs, say, on_done=finish, stop=stop)
    else:
        for i in range(len(parts)):
            if stop():
                break
            finish(i, time.process_time())
    say(f"done: {time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU in this process"
        + (f" (plus the workers'; {a.jobs} worker processes)" if a.jobs > 1 else ""))
    return summ


if __name__ == "__main__":
    main()
