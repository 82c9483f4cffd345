"""Command-line entry point: ``neckstrength <verb> ...``.

Verbs:
  derive-model   derive the full-model tables from an OpenSim .osim (needs the 'opensim' extra)
  directions     write the test-direction table for a config
  max-wrench     maximum wrench of a model in every test direction (baseline or given strengths)
  validate       check a measurement / activation / test-point file and report the first problem
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from .io import DataValidationError


def load_config(path: str | Path) -> dict:
    """Load a YAML config and validate it (defaults filled) against the workflow schema."""
    path = Path(path)
    with open(path) as fh:
        cfg = yaml.safe_load(fh)
    schema = path.resolve().parent.parent / "workflow" / "schemas" / "config.schema.yaml"
    if schema.exists():
        from snakemake.utils import validate

        validate(cfg, str(schema))
    return cfg


def _cmd_directions(args) -> int:
    from .stages import stage_directions

    stage_directions(load_config(args.config), args.out)
    print(f"wrote {args.out}")
    return 0


def _cmd_max_wrench(args) -> int:
    from .maxwrench import STATUS_CODES, max_wrench_batch
    from .stages import build_directions, full_model_from_config, model_directions, model_from_config

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
    d, U = model_directions(model, build_directions(cfg))
    if args.direction:
        keep = d["name"].isin(args.direction).to_numpy()
        if not keep.any():
            raise SystemExit(f"no direction named {args.direction}; known: {', '.join(d['name'])}")
        d, U = d[keep].reset_index(drop=True), U[keep]
    w, alpha, status = max_wrench_batch(model, f[None, :], U)
    out = pd.DataFrame({"direction": d["name"], "wrench": w[0], "force_N": w[0] / d["force_scale"].to_numpy(),
                        "status": [STATUS_CODES[s] for s in status[0]]})
    print(f"model {model.name}: {model.m} muscles, {model.n} coordinates")
    print(out.to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    return 0


def _cmd_validate(args) -> int:
    from .geometry import read_test_points
    from .io import read_activations, read_measurements

    reader = {"measurements": read_measurements, "activations": read_activations,
              "points": read_test_points}[args.kind]
    df = reader(args.file)
    print(f"{args.file}: OK ({len(df)} rows, columns: {', '.join(map(str, df.columns))})")
    return 0


def _cmd_derive(args) -> int:
    from . import derive_opensim

    argv = ["--osim", args.osim, "--out", args.out]
    if args.multifidus_osim:
        argv += ["--multifidus-osim", args.multifidus_osim]
    return derive_opensim.main(argv) or 0


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
