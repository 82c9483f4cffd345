#!/usr/bin/env python
"""The user-facing gap benchmark (issue 32, item 5): truths made apart from the diagnosis, scored model-free.

Cases come from :mod:`neckstrength.gap.truths` (direction errors within a cone, asymmetry, origin offset,
direction-dependent submaximal effort, posture drift, head/neck size; noise-only controls of the base model and of
the 96-element truth), three trials per test, the largest kept, the trials' pooled log SD given to the diagnosis as
the participant's measured noise (``noise: auto`` -> repeats, as for a lab that imports its trials). The diagnosis
sees the forces and that noise only. Its settings are the config's ``gap`` with the benchmark's reductions
(``gap.benchmark``: folds, bootstrap, starts; no pairs, no refinement, no reach envelope), the calibrated decision
with ``--null-replicates`` noise-only replicates (19: p resolution 0.05), no sensitivity table and no power tables
(neither changes the decision). Candidates: ``gap.effects`` plus ``submaximal_effort``, ``posture_drift`` and
``anthropometric_scaling`` where the registry has them (otherwise those truths are scored "not a candidate"), and
the decision's aiming-scatter step (``direction_scatter``, :mod:`neckstrength.gap.scatter`), the target of the
direction-error truth since 2026-11-28.

Scoring (:mod:`neckstrength.gap.scoring`): model-free detectability (held-out gap under the base model above the
95th percentile of the base-model controls'), named correctly among detectable cases and false alarms on the
controls with Wilson 95% intervals, and "consistent with noise" verdicts where the held-out residual exceeds three
times the measured noise.

Resumable and chunked: cases are generated in a stratified order (every prefix samples each truth in proportion),
diagnosed in batches of ``--chunk``; after each batch one line per case is appended to ``OUT/rows.jsonl`` (with
the commit it ran on) and every table is rescored, so a run stopped by ``--max-seconds`` or killed leaves usable
partial results; a rerun with the same design skips the cases in ``rows.jsonl``.

    nice -n 10 .venv/bin/python benchmarks/bench_gap_users.py --out results/gap/s3m24/users --jobs 2
    .venv/bin/python benchmarks/bench_gap_users.py --out OUT --score-only    # rescore what is there
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

NEW_EFFECTS = ("submaximal_effort", "posture_drift", "anthropometric_scaling")


def settings_for(cfg, model, n_null: int, repeats, null_truth: str | None = None, element_spread: float | None = None):
    """Context, diagnosis settings and candidate list of the benchmark (see the module docstring); ``null_truth``:
    the noise-only replicates' truths and ``element_spread`` their element spread (None: the config's
    ``gap.calibration.null_truth`` / ``element_spread``)."""
    from neckstrength.config import build_directions, calibration_settings, diagnosis_settings, gap_context
    from neckstrength.gap.effects import EFFECTS

    ctx = gap_context(cfg, model, build_directions(cfg))
    effects = list(cfg["gap"]["effects"]) + [e for e in NEW_EFFECTS if e in EFFECTS and e not in cfg["gap"]["effects"]]
    ds = diagnosis_settings(cfg, effects)
    b = cfg["gap"]["benchmark"]
    cal = calibration_settings(cfg)
    cal = replace(cal, replicates=int(n_null), noise="auto", repeats=tuple(repeats), sensitivity=False,
                  power_replicates=0, null_truth=null_truth or cal.null_truth,
                  element_spread=cal.element_spread if element_spread is None else float(element_spread))
    ds = replace(ds, folds=b.get("folds", ds.folds), bootstrap=b.get("bootstrap", ds.bootstrap),
                 starts=b.get("starts", ds.starts), pairs_top=0, refine_iter=0, reach_samples=0, reach_iter=0,
                 calibration=cal)
    return ctx, ds, effects


def add_design_args(ap) -> None:
    """The arguments that name a design of this benchmark (for scripts that look at its cases again)."""
    ap.add_argument("--config", default="config/config.yaml", help="its seed makes the design")
    ap.add_argument("--model", default="s3m24")
    ap.add_argument("--controls", type=int, default=30)
    ap.add_argument("--rich-controls", type=int, default=10)
    ap.add_argument("--replicates", type=int, default=15, help="cases per effect truth")


def design_from_args(a):
    """``(cfg, cases, ctx, ds)`` of the design :func:`add_design_args`' arguments name."""
    from neckstrength.config import load_config
    from neckstrength.gap.truths import CaseSettings

    cfg = load_config(a.config)
    cs = CaseSettings(replicates=a.replicates, controls=a.controls, rich_controls=a.rich_controls)
    return (cfg, *design_cases(cfg, a.model, cs))


def finish(tab, out, t0: float, c0: float):
    """Print the wall and CPU time since ``t0`` / ``c0`` and the load, write ``tab`` to ``out`` (when given)."""
    print(f"\n{time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU, "
          f"load {os.getloadavg()[0]:.1f}")
    if out:
        tab.to_csv(out, index=False)
    return tab


def design_cases(cfg, model: str, cs, n_null: int = 19):
    """A design's cases as this benchmark draws them (``cfg``'s seed, stream ``gap-users/{model}``, case settings
    ``cs``) and the context and diagnosis settings that see their repeats: ``(cases, ctx, ds)``."""
    from neckstrength.gap.truths import TruthSetup, generate_truth_cases
    from neckstrength.seeds import derive_rng

    ctx0, _, _ = settings_for(cfg, model, n_null, ())
    cases = generate_truth_cases(TruthSetup.of(ctx0), cs, derive_rng(cfg["seed"], f"gap-users/{model}"))
    ctx, ds, _ = settings_for(cfg, model, n_null, [c.repeats_row() for c in cases])
    return cases, ctx, ds


def power_of_targets(ctx, part, diags, ds, effects, jobs, cfg) -> dict:
    """Per case whose target is a candidate: whether the diagnosis's own power analysis (the config's power sizes
    and replicates at the case's measured noise, from its fitted base model) calls the target detectable at some
    simulated size up to the far bound (scoring side: the truth chooses which effect's power is simulated)."""
    from neckstrength.gap.calibrate import power_for, power_summary
    from neckstrength.gap.diagnose import BlindData
    from neckstrength.config import calibration_settings

    c0 = calibration_settings(cfg)
    dsp = replace(ds, calibration=replace(ds.calibration, power_replicates=c0.power_replicates,
                                          power_sizes=c0.power_sizes, power_target=c0.power_target))
    todo = [(c, d) for c, d in zip(part, diags) if c.target in effects and d.calibration is not None]
    if not todo:
        return {}
    tabs = power_for(ctx, [BlindData(c.name, c.forces.copy()) for c, _ in todo],
                     [d.calibration for _, d in todo], [[c.target] for c, _ in todo], dsp, None, jobs)
    out = {}
    for (c, _), t in zip(todo, tabs):
        sm = power_summary(t, dsp.calibration.power_target).set_index("effect")
        out[c.name] = bool(c.target in sm.index and np.isfinite(float(sm.loc[c.target, "min_detectable_share"])))
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--model", default=None, help="default: gap.benchmark.model")
    ap.add_argument("--out", required=True, help="folder for rows.jsonl and the score tables (created)")
    ap.add_argument("--replicates", type=int, default=12, help="cases per effect truth")
    ap.add_argument("--controls", type=int, default=24, help="noise-only controls of the base model")
    ap.add_argument("--rich-controls", type=int, default=12, help="controls from the 96-element truth")
    ap.add_argument("--limit", type=int, default=None, help="only the first cases of the stratified order")
    ap.add_argument("--only", default=None, help="comma-separated case names (u001, ...): diagnose only these "
                    "cases of the design (its draws unchanged), e.g. to look at single cases again")
    ap.add_argument("--null-replicates", type=int, default=19, help="noise-only replicates of the decision")
    ap.add_argument("--null-truth", choices=("base", "elements"), default=None,
                    help="truths of the noise-only replicates (default: the config's gap.calibration.null_truth)")
    ap.add_argument("--element-spread", type=float, default=None,
                    help="with --null-truth elements: log SD of the element strengths (default: the config's)")
    ap.add_argument("--chunk", type=int, default=8, help="cases per batch (results do not depend on it)")
    ap.add_argument("--jobs", type=int, default=1, help="processes sharing out a batch's effects")
    ap.add_argument("--max-seconds", type=float, default=None, help="start no new batch after this long")
    ap.add_argument("--score-only", action="store_true", help="diagnose nothing: rescore rows.jsonl")
    ap.add_argument("--force", action="store_true", help="replace an OUT whose rows.jsonl is of another design")
    ap.add_argument("--power", action="store_true", help="also the diagnosis's own power for each case's target "
                    "effect (the secondary column; about a third more time)")
    a = ap.parse_args(argv)

    from neckstrength.config import load_config
    from neckstrength.gap.diagnose import AIM_SCATTER, BlindData, diagnose
    from neckstrength.gap.scoring import case_row, confusion, score_cases
    from neckstrength.gap.truths import CaseSettings, TruthSetup, describe, generate_truth_cases
    from neckstrength.io import atomic_write_csv, atomic_write_text
    from neckstrength.seeds import derive_rng

    t0, c0 = time.perf_counter(), time.process_time()
    cfg = load_config(a.config)
    model = a.model or cfg["gap"]["benchmark"]["model"]
    out = Path(a.out)

    def say(msg):
        print(f"[{time.strftime('%H:%M:%S')} UTC, {time.perf_counter() - t0:.0f} s wall, "
              f"{time.process_time() - c0:.0f} s CPU, load {os.getloadavg()[0]:.1f}] {msg}", flush=True)

    cs = CaseSettings(replicates=a.replicates, controls=a.controls, rich_controls=a.rich_controls)
    ctx0, _, _ = settings_for(cfg, model, a.null_replicates, ())
    setup = TruthSetup.of(ctx0)
    stream = f"gap-users/{model}"
    cases = generate_truth_cases(setup, cs, derive_rng(cfg["seed"], stream), limit=a.limit)
    ctx, ds, effects = settings_for(cfg, model, a.null_replicates, [c.repeats_row() for c in cases], a.null_truth,
                                    a.element_spread)
    design = {"model": model, "seed": cfg["seed"], "stream": stream, "cases": asdict(cs), "limit": a.limit,
              "null_replicates": a.null_replicates, "effects": effects,
              "decision": "aim scatter (gap.scatter) after the calibrated choice, 2026-11-28"}
    if ds.calibration.null_truth != "base":      # (a base null keeps the designs of the runs before the option)
        design.update(null_truth=ds.calibration.null_truth, element_spread=ds.calibration.element_spread)
    if ds.calibration.selection != "max_z":      # (likewise the selection of the runs before 2026-11-28)
        design.update(selection=ds.calibration.selection)
    dhash = hashlib.sha256(json.dumps(design, sort_keys=True).encode()).hexdigest()[:16]
    out.mkdir(parents=True, exist_ok=True)
    rows_path = out / "rows.jsonl"
    rows = []
    if rows_path.exists():
        rows = [json.loads(x) for x in rows_path.read_text().splitlines() if x.strip()]
        other = {r["design"] for r in rows} - {dhash}
        if other and not a.force:
            raise SystemExit(f"{rows_path}: rows of another design ({', '.join(sorted(other))}); use another --out "
                             "or --force to replace them")
        if other:
            rows = []
            rows_path.unlink()
    done = {r["case"] for r in rows}
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                check=False).stdout.strip() or "unknown"
    except OSError:
        commit = "unknown"
    say(f"{model}: {len(cases)} cases ({len(done)} done before), design {dhash}, seed {cfg['seed']} stream {stream}; "
        f"candidates {', '.join(effects)}; {a.null_replicates} noise-only replicates, null truths "
        f"{ds.calibration.null_truth}")
    atomic_write_text(json.dumps(design, indent=2), out / "design.json")

    def rescore() -> dict:
        if not rows:
            return {}
        pc, tab, thr = score_cases(rows)
        atomic_write_csv(pc, out / "cases.csv", float_format="%.4g")
        atomic_write_csv(tab, out / "scores.csv", float_format="%.4g")
        atomic_write_csv(confusion(pc), out / "confusion.csv")
        head = tab.set_index("group")
        summ = {"cases_done": len(pc), "cases_design": len(cases), "threshold_gap": thr,
                "wall_s_this_run": time.perf_counter() - t0, "cpu_s_this_run": time.process_time() - c0,
                "scores": tab.to_dict(orient="records")}
        atomic_write_text(json.dumps(summ, indent=2, default=float), out / "summary.json")
        say("so far: " + "; ".join(f"{g[:60]}: {int(r['count'])}/{int(r['cases'])}" for g, r in head.iloc[:6].iterrows()))
        return summ

    summ = rescore()
    todo = [c for c in cases if c.name not in done]
    if a.only:
        only = [x.strip() for x in a.only.split(",") if x.strip()]
        unknown = sorted(set(only) - {c.name for c in cases})
        if unknown:
            raise SystemExit(f"--only: no case {', '.join(unknown)} in this design ({len(cases)} cases)")
        todo = [c for c in todo if c.name in only]
    if a.score_only:
        todo = []
    for b0 in range(0, len(todo), max(1, a.chunk)):
        if a.max_seconds is not None and time.perf_counter() - t0 > a.max_seconds:
            say(f"stopping: --max-seconds {a.max_seconds:g} reached")
            break
        part = todo[b0:b0 + a.chunk]
        tb, cb = time.perf_counter(), time.process_time()
        diags = diagnose(ctx, [BlindData(c.name, c.forces.copy()) for c in part], ds, None, workers=a.jobs)
        pw = power_of_targets(ctx, part, diags, ds, effects, a.jobs, cfg) if a.power else {}
        wall = time.perf_counter() - tb
        with rows_path.open("a") as fh:
            for c, d in zip(part, diags):
                r = case_row(c.name, c.truth, c.target, effects + [AIM_SCATTER], d.summary, d.effects)
                r.update({"design": dhash, "commit": commit, "noise_true": c.noise, "noise_measured": c.noise_sd,
                          "truth_params": describe(c.truth, c.params), "batch_wall_s": wall,
                          "null_truth": d.summary.get("null_truth", ""),
                          "batch_cases": len(part)})
                if c.name in pw:
                    r["power_detectable"] = pw[c.name]
                cal = d.calibration
                if cal is not None:       # the decision's inputs: other selection rules can be scored offline
                    r["decision_inputs"] = {"effects": list(cal.effects), "gap_obs": list(map(float, cal.gap_obs)),
                                            "mu": list(map(float, cal.mu)), "sd": list(map(float, cal.sd)),
                                            "t_null": list(map(float, cal.t_null)),
                                            "delta_null": np.round(np.asarray(cal.delta_null, float), 6).tolist(),
                                            "gap_null_none": list(map(float, np.asarray(cal.gap_null)[:, 0])),
                                            "rms_obs": None if cal.rms_obs is None else list(map(float, cal.rms_obs))}
                rows.append(r)
                fh.write(json.dumps(r, default=float) + "\n")
        say(f"batch of {len(part)} ({part[0].name}-{part[-1].name}): {wall:.0f} s wall, "
            f"{time.process_time() - cb:.0f} s CPU in this process; "
            + ", ".join(f"{c.name} {c.truth} -> {r['named']}" for c, r in zip(part, rows[-len(part):])))
        summ = rescore()
    say("done")
    return summ


if __name__ == "__main__":
    main()
