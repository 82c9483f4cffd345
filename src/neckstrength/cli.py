"""Command-line entry point: ``neckstrength <verb> ...``.

Verbs:
  derive-model   derive the full-model tables from an OpenSim .osim (needs the 'opensim' extra)
  directions     write the test-direction table for a config
  max-wrench     maximum wrench of a model in every test direction (baseline or given strengths)
  validate       check a measurement / activation / test-point file and report the first problem
  session        clinician-in-the-loop session: start, resume, replay (docs/session.md)
  diagnose       sim-to-real gap diagnosis of a data set: where, which effect, how far (docs/gap_diagnosis.md)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.config import load_config
from neckstrength.io import DataValidationError


def _cmd_directions(args) -> int:
    from neckstrength.config import build_directions
    from neckstrength.io import atomic_write_csv
    from neckstrength.model.geometry import DIRECTIONS_HEADER

    atomic_write_csv(build_directions(load_config(args.config)), args.out, DIRECTIONS_HEADER, float_format="%.6f")
    print(f"wrote {args.out}")
    return 0


def _cmd_max_wrench(args) -> int:
    from neckstrength.config import build_directions, full_model_from_config, model_from_config
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.wrench import solve
    from neckstrength.wrench.problem import STATUS_CODES

    cfg = load_config(args.config)
    full = full_model_from_config(cfg)
    model = model_from_config(full, cfg, args.model)
    f = model.strengths.copy()
    if args.strengths:
        s = pd.read_csv(args.strengths, comment="#")
        if not {"muscle", "strength_N"} <= set(s.columns):
            raise DataValidationError(args.strengths, "needs columns muscle, strength_N")
        lookup = dict(zip(s["muscle"], s["strength_N"]))
        unknown = set(lookup) - set(model.muscle_names)
        if unknown:
            raise DataValidationError(args.strengths, f"unknown muscles {sorted(unknown)}", field_name="muscle")
        f = np.array([lookup.get(m, fm) for m, fm in zip(model.muscle_names, f)])
    d, U = model_directions_table(model, build_directions(cfg))
    if args.direction:
        keep = d["name"].isin(args.direction).to_numpy()
        if not keep.any():
            raise SystemExit(f"no direction named {args.direction}; known: {', '.join(d['name'])}")
        d, U = d[keep].reset_index(drop=True), U[keep]
    w, alpha, status = solve(model, f[None, :], U, method="highs")
    out = pd.DataFrame({"direction": d["name"], "wrench": w[0], "force_N": w[0] / d["force_scale"].to_numpy(),
                        "status": [STATUS_CODES[s] for s in status[0]]})
    print(f"model {model.name}: {model.m} muscles, {model.n} coordinates")
    print(out.to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    return 0


def _cmd_validate(args) -> int:
    from neckstrength.io import read_activations, read_measurements
    from neckstrength.model.geometry import read_test_points

    reader = {"measurements": read_measurements, "activations": read_activations,
              "points": read_test_points}[args.kind]
    df = reader(args.file)
    print(f"{args.file}: OK ({len(df)} rows, columns: {', '.join(map(str, df.columns))})")
    return 0


def _cmd_derive(args) -> int:
    from neckstrength.model.opensim import derive as derive_opensim

    argv = ["--osim", args.osim, "--out", args.out]
    if args.multifidus_osim:
        argv += ["--multifidus-osim", args.multifidus_osim]
    return derive_opensim.main(argv) or 0


def _cmd_session(args) -> int:
    from neckstrength.session import InputError, Session, SessionOptions, parse_priorities, replay_csv, run_interactive

    try:
        if args.action == "resume":
            s = Session.resume(args.out)
            return run_interactive(s)
        opts = SessionOptions(model=args.model, participant=args.participant,
                              priorities=parse_priorities(args.priority), config=args.config,
                              n_candidates=args.n_candidates, prior_scale=args.prior_scale,
                              gain_frac=args.stop_frac, cache=args.cache, seed=args.seed)
        s = Session.start(args.out, opts)
        return run_interactive(s) if args.action == "start" else replay_csv(s, args.csv)
    except (InputError, ValueError, FileExistsError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def _cmd_diagnose(args) -> int:
    from neckstrength.config import (
        build_directions,
        derive_rng,
        diagnosis_settings,
        gap_blind_dataset,
        gap_context,
        gap_settings_text,
        gap_withheld_activations,
    )
    from neckstrength.gap.run import DATASET_FILES, FIGURES, run_diagnosis

    cfg = load_config(args.config)
    if args.measurements:
        cfg["gap"]["measurements"] = args.measurements
    if args.effects:
        cfg["gap"]["effects"] = [e.strip() for e in args.effects.split(",") if e.strip()]
    model = args.model or cfg["gap"]["models"][0]
    out = Path(args.out or f"results/gap/{model}/{args.dataset}")
    outputs = {k: out / f"{k}.csv" for k in DATASET_FILES}
    outputs.update({f"fig_{k}": out / f"fig_{k}.png" for k in FIGURES})
    outputs.update({"summary": out / "summary.json", "report": out / "report.md"})
    try:
        directions = build_directions(cfg)
        ctx = gap_context(cfg, model, directions)
        data = gap_blind_dataset(cfg, ctx, directions, args.dataset)
        settings = diagnosis_settings(cfg)
        s = run_diagnosis(ctx, data, settings, derive_rng(cfg["seed"], f"gap/{model}/{args.dataset}"), directions,
                          gap_withheld_activations(cfg, ctx, args.dataset), outputs,
                          gap_settings_text(cfg, settings), model)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out}/report.md: where {s['worst_plane']} / {s['worst_component']}; which {s['chosen']}; "
          f"held-out gap {s['gap_before']:.3f} -> {s['gap_after']:.3f}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="neckstrength", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="verb", required=True)

    d = sub.add_parser("derive-model", help="derive full-model tables from an OpenSim model (needs opensim)")
    d.add_argument("--osim", required=True)
    d.add_argument("--multifidus-osim", default=None)
    d.add_argument("--out", default="data/model")
    d.set_defaults(func=_cmd_derive)

    d = sub.add_parser("directions", help="write the test-direction table")
    d.add_argument("--config", default="config/config.yaml")
    d.add_argument("--out", default="results/geometry/directions.csv")
    d.set_defaults(func=_cmd_directions)

    d = sub.add_parser("max-wrench", help="max wrench of a model in the test directions")
    d.add_argument("--config", default="config/config.yaml")
    d.add_argument("--model", default="s3m24", help="p2m7, p3m12, s3m24 or <kinematic>-<grouping>")
    d.add_argument("--strengths", default=None, help="CSV with columns muscle,strength_N (others: baseline)")
    d.add_argument("--direction", action="append", help="restrict to this direction (repeatable)")
    d.set_defaults(func=_cmd_max_wrench)

    d = sub.add_parser("validate", help="validate an input file")
    d.add_argument("kind", choices=["measurements", "activations", "points"])
    d.add_argument("file")
    d.set_defaults(func=_cmd_validate)

    d = sub.add_parser("session", help="clinician-in-the-loop session (propose, measure, update, stop)")
    ss = d.add_subparsers(dest="action", required=True)
    for action in ("start", "replay"):
        a = ss.add_parser(action, help="start an interactive session" if action == "start" else
                          "run a session from a CSV of measurements (direction,force_N[,activations])")
        if action == "replay":
            a.add_argument("--csv", required=True)
        a.add_argument("--out", required=True, help="session folder (log, summary)")
        a.add_argument("--model", default="p2m7", choices=["p2m7", "p3m12", "s3m24"])
        a.add_argument("--participant", default="anonymous")
        a.add_argument("--priority", action="append", metavar="MUSCLE=WEIGHT",
                       help="Eq. 6.8 muscle priority (repeatable; unlisted muscles weigh 0)")
        a.add_argument("--config", default="config/config.yaml")
        a.add_argument("--n-candidates", type=int, default=None, help="N_F (default: config chapter6)")
        a.add_argument("--prior-scale", type=float, default=1.0, help="a in the prior f_0 = a f'_base")
        a.add_argument("--stop-frac", type=float, default=None,
                       help="stop when the best expected reduction < this share of the first step's "
                            "(default: config chapter6.stop.gain_frac)")
        a.add_argument("--cache", default=None, help="candidate-set cache folder (default results/session_cache)")
        a.add_argument("--seed", type=int, default=None, help="default: config seed")
    a = ss.add_parser("resume", help="resume a session from its log")
    a.add_argument("--out", required=True)
    d.set_defaults(func=_cmd_session)

    d = sub.add_parser("diagnose", help="sim-to-real gap diagnosis of one data set (forces only)")
    d.add_argument("--config", default="config/config.yaml")
    d.add_argument("--model", default=None, help="p2m7, p3m12, s3m24 or <kinematic>-<grouping> (default: "
                                                 "first of config gap.models)")
    d.add_argument("--dataset", required=True, help="participant column of the measurement table, or norm/weak")
    d.add_argument("--measurements", default=None, help="a measurement table in the Table A.2 layout "
                                                        "(default: config gap.measurements / data.measurements)")
    d.add_argument("--effects", default=None, help="comma-separated effects (default: config gap.effects)")
    d.add_argument("--out", default=None, help="output folder (default results/gap/<model>/<dataset>)")
    d.set_defaults(func=_cmd_diagnose)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except DataValidationError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
