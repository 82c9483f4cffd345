"""Data sets whose tests name a posture (issue 20): simulated and measured, in the Table A.2 layout plus an
optional ``posture`` column (default ``neutral``: a table without it is read exactly as before)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.estimation.datasets import WRENCH, Dataset
from neckstrength.io import MEASUREMENT_SCHEMA, Column, DataValidationError, Schema, read_table
from neckstrength.postures.model import PostureSet, pair_label, split_label
from neckstrength.wrench.problem import STATUS_CODES


def posture_measurement_schema(postures: Sequence[str]) -> Schema:
    return Schema(MEASUREMENT_SCHEMA.name + " with a posture column",
                  (Column("direction", "str"), Column("posture", "str", choices=tuple(postures))),
                  unique=(),
                  pattern_columns=MEASUREMENT_SCHEMA.pattern_columns)


def read_posture_measurements(path: str | Path, directions: Sequence[str], postures: Sequence[str]) -> pd.DataFrame:
    """Max forces (N) per (direction, posture) row and participant column; rows without a posture column are
    neutral. Unknown directions / postures are errors naming the row and field. Index: test label."""
    head = pd.read_csv(path, comment="#", nrows=0)
    if "posture" in head.columns:
        df = read_table(path, posture_measurement_schema(postures))
    else:
        df = read_table(path, MEASUREMENT_SCHEMA)
        df.insert(1, "posture", "neutral")
    seen: dict = {}
    for i, key in enumerate(zip(df["direction"], df["posture"])):
        if key in seen:
            raise DataValidationError(path, f"duplicate test {key[0]} in posture {key[1]} (first at row {seen[key]})",
                                      i + 1, None, "posture")
        seen[key] = i + 1
    known = set(directions)
    for i, d in enumerate(df["direction"]):
        if d not in known:
            raise DataValidationError(path, f"unknown test direction '{d}' (known: {', '.join(directions)})",
                                      i + 1, None, "direction")
    cols = [c for c in df.columns if c not in ("direction", "posture", "avg", "sd")]
    if not cols:
        raise DataValidationError(path, "no participant columns (expected e.g. S003, S004, ...)")
    df.index = [pair_label(p, d) for p, d in zip(df["posture"], df["direction"])]
    return df[["direction", "posture", *cols]]


def posture_grid(pset: PostureSet, directions: pd.DataFrame, postures: Sequence[str] | None = None) -> pd.DataFrame:
    """Every (posture, direction) test of the model: label, posture, direction, task-space U, force scale."""
    d = directions[directions["sagittal"]] if pset.planar else directions
    d = d.reset_index(drop=True)
    U = pset.task_direction(d[[f"u_{c}" for c in WRENCH]].to_numpy(float))
    rows = []
    for p in (pset.postures if postures is None else postures):
        for k, r in d.iterrows():
            rows.append({"label": pair_label(p, r["name"]), "posture": p, "direction": r["name"],
                         "force_scale": float(r["force_scale"]), **{f"u{j}": U[k, j] for j in range(U.shape[1])}})
    return pd.DataFrame(rows)


def _U(grid: pd.DataFrame) -> np.ndarray:
    return grid[[c for c in grid.columns if c.startswith("u") and c[1:].isdigit()]].to_numpy(float)


def posture_dataset(pset: PostureSet, grid: pd.DataFrame, name: str, f_actual: np.ndarray,
                    labels: Sequence[str] | None = None) -> Dataset:
    """Simulated measurements of neutral group strengths ``f_actual`` in the tests ``labels`` (default: all)."""
    g = grid if labels is None else grid.set_index("label").loc[list(labels)].reset_index()
    U = _U(g)
    w, _, st = pset.wrenches(np.asarray(f_actual, float)[None], U, list(g["posture"]))
    bad = [g["label"][k] for k in range(len(g)) if STATUS_CODES[int(st[0, k])] != "optimal"]
    if bad:
        raise ValueError(f"{pset.name} with f_a cannot produce tests {bad}")
    return Dataset(name, list(g["label"]), U, w[0], g["force_scale"].to_numpy(float), None, None,
                   np.asarray(f_actual, float), postures=list(g["posture"]))


def participant_posture_dataset(pset: PostureSet, grid: pd.DataFrame, participant: str,
                                measurements: str | Path) -> Dataset:
    """A participant's measured forces in every (posture, direction) test the table has."""
    meas = read_posture_measurements(measurements, sorted(set(grid["direction"])), pset.postures)
    if participant not in meas.columns:
        raise ValueError(f"{measurements}: no column for participant {participant!r}")
    col = meas[participant].dropna()
    g = grid.set_index("label")
    missing = [lab for lab in col.index if lab not in g.index]
    if missing:
        raise ValueError(f"{measurements}: tests {missing} are not tests of model {pset.name}")
    g = g.loc[list(col.index)].reset_index()
    scale = g["force_scale"].to_numpy(float)
    return Dataset(participant, list(g["label"]), _U(g), col.to_numpy(float) * scale, scale, None, None, None,
                   postures=list(g["posture"]))


__all__ = [
    "participant_posture_dataset",
    "posture_dataset",
    "posture_grid",
    "read_posture_measurements",
    "split_label",
]
