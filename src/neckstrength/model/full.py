"""The musculoskeletal neck model and its reduction (thesis Sec. 4.2.1).

- :class:`FullModel`: 96 muscles x 7 joints x (pitch, roll, yaw) at the neutral
  posture: moment arms ``R`` (21 x 96), strengths ``f`` (96), joint centres and
  axes in the skull frame. Built by :func:`load_full_model` from the derived
  tables in ``data/model`` (OpenSim derivation, see ``docs/model_derivation.md``)
  and the thesis's Table B.1 (``data/thesis``), which wins where it has a value.
- :func:`reduce_model`: kinematic variant (joint selection, planar task space)
  and muscle grouping (grouping matrix ``S_m``, group strength = 2-norm, grouped
  moment arm = torque contribution / group strength).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from neckstrength.io import Column, DataValidationError, Schema, read_table

JOINTS = ("C0-C1", "C1-C2", "C2-C3", "C3-C4", "C4-C5", "C5-C6", "C6-C7")


AXES = ("pitch", "roll", "yaw")


COORDINATES = tuple(f"{j}_{a}" for j in JOINTS for a in AXES)


B1_JOINTS = ("C6-C7", "C4-C5", "C0-C1")


#: Kinematic variants (Sec. 4.2.1.1): task space and joints kept.
KINEMATIC_VARIANTS: dict[str, tuple[str, tuple[str, ...]]] = {
    "s7": ("spatial", JOINTS),
    "s3": ("spatial", ("C0-C1", "C4-C5", "C6-C7")),
    "s2": ("spatial", ("C0-C1", "C6-C7")),
    "p7": ("planar", JOINTS),
    "p3": ("planar", ("C0-C1", "C4-C5", "C6-C7")),
    "p2": ("planar", ("C0-C1", "C6-C7")),
}


#: Muscle variants (Sec. 4.2.1.2) plus the p2m7 grouping of Table B.6.
MUSCLE_VARIANTS = ("independent", "sagittal_axial", "sagittal", "anatomical", "p2m7")


#: The named models of Chapters 5 and 6.
NAMED_MODELS: dict[str, tuple[str, str]] = {
    "p2m7": ("p2", "p2m7"),
    "p3m12": ("p3", "anatomical"),
    "s3m24": ("s3", "anatomical"),
}


def base_name(name: str) -> str:
    """Muscle name without the left-side suffix (' L')."""
    return name[:-2] if name.endswith(" L") else name


def side_of(name: str) -> str:
    return "L" if name.endswith(" L") else "R"


def _key(s: str) -> str:
    return " ".join(str(s).lower().split())


@dataclass(frozen=True)
class FullModel:
    """Full model: ``moment_arms`` is R (21 x 96), rows in :data:`COORDINATES` order."""

    muscles: pd.DataFrame
    strengths: np.ndarray
    moment_arms: np.ndarray
    centres: np.ndarray
    axes: np.ndarray
    provenance: Mapping[str, str] = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return list(self.muscles["name"])

    @property
    def m(self) -> int:
        return len(self.strengths)


_MA_COLS = tuple(Column(c, "float", "m", -0.25, 0.25) for c in COORDINATES)


DERIVED_MUSCLES_SCHEMA = Schema(
    "derived muscles",
    (Column("index", "int", None, 1, 96), Column("name", "str"),
     Column("osim_max_isometric_force_N", "float", "N", 0.0, 5000.0, min_exclusive=True)),
    unique=("index", "name"))


DERIVED_MA_SCHEMA = Schema("derived moment arms", (Column("index", "int", None, 1, 96), Column("name", "str"))
                           + _MA_COLS, unique=("index",))


COORD_SCHEMA = Schema(
    "joint coordinates",
    (Column("coordinate", "str", choices=COORDINATES),
     Column("centre_x", "float", "m", -0.5, 0.5), Column("centre_y", "float", "m", -0.5, 0.5),
     Column("centre_z", "float", "m", -0.5, 0.5),
     Column("axis_x", "float", "1", -1, 1), Column("axis_y", "float", "1", -1, 1),
     Column("axis_z", "float", "1", -1, 1)),
    unique=("coordinate",))


B1_SCHEMA = Schema(
    "Table B.1",
    (Column("index", "int", None, 1, 96), Column("name", "str"),
     Column("strength_N", "float", "N", 0.0, 5000.0, min_exclusive=True))
    + tuple(Column(f"{j}_{a}", "float", "m", -0.25, 0.25, allow_missing=True) for j in B1_JOINTS for a in AXES),
    unique=("index",))


IMPLIED_SCHEMA = Schema(
    "strengths implied by Table B.3",
    (Column("index", "int", None, 1, 96), Column("name", "str"),
     Column("implied_strength_N", "float", "N", 0.0, 5000.0, min_exclusive=True)), unique=("index",))


ERRATA_SCHEMA = Schema(
    "Table B.1 errata",
    (Column("index", "int", None, 1, 96), Column("name", "str"), Column("field", "str"),
     Column("printed", "float", "m", allow_missing=True), Column("corrected", "float", "m", allow_missing=True),
     Column("evidence", "str")))


def load_full_model(model_dir: str | Path, thesis_dir: str | Path | None = None,
                    moment_arm_source: str = "derived", apply_errata: bool = True,
                    unprinted_strengths: str = "b3_implied") -> FullModel:
    """Assemble the full model from the derived tables and Table B.1.

    ``moment_arm_source``: 'derived' uses the OpenSim-derived moment arms for
    every joint; 'b1_where_available' (default) uses Table B.1's printed values
    (blank = 0) at its three joints for the rows it prints, and derived values
    elsewhere, so that reduced 2- and 3-joint models use the thesis's own
    numbers. Strengths: B.1 wins where it has a value; for the 32 rows B.1 does
    not print, ``unprinted_strengths`` = 'b3_implied' takes the thesis's own
    values recovered from Table B.3 (``data/model/b3_implied_strengths.csv``),
    'osim' the OpenSim model's unscaled maximum isometric force.
    """
    model_dir = Path(model_dir)
    mus = read_table(model_dir / "full_model_muscles.csv", DERIVED_MUSCLES_SCHEMA).sort_values("index")
    ma = read_table(model_dir / "full_model_moment_arms.csv", DERIVED_MA_SCHEMA).sort_values("index")
    coords = read_table(model_dir / "full_model_coordinates.csv", COORD_SCHEMA).set_index("coordinate")
    if len(mus) != 96 or list(mus["index"]) != list(range(1, 97)):
        raise DataValidationError(model_dir / "full_model_muscles.csv", "expected indices 1..96")
    if list(ma["index"]) != list(mus["index"]):
        raise DataValidationError(model_dir / "full_model_moment_arms.csv", "indices differ from muscles table")
    missing = [c for c in COORDINATES if c not in coords.index]
    if missing:
        raise DataValidationError(model_dir / "full_model_coordinates.csv", f"missing coordinates {missing}")
    names = list(mus["name"])
    R = ma[list(COORDINATES)].to_numpy(float).T.copy()
    f = mus["osim_max_isometric_force_N"].to_numpy(float).copy()
    f_src = ["osim" for _ in names]
    ma_src = ["derived" for _ in names]
    if unprinted_strengths not in ("b3_implied", "osim"):
        raise ValueError(f"unknown unprinted_strengths {unprinted_strengths!r}")
    if thesis_dir is not None and unprinted_strengths == "b3_implied":
        imp = read_table(model_dir / "b3_implied_strengths.csv", IMPLIED_SCHEMA)
        for r in imp.to_dict("records"):
            i = int(r["index"]) - 1
            if _key(r["name"]) != _key(names[i]):
                raise DataValidationError(imp.attrs["source"], f"name '{r['name']}' does not match '{names[i]}'",
                                          None, None, "name")
            f[i] = r["implied_strength_N"]
            f_src[i] = "table_B3_implied"

    if thesis_dir is not None:
        b1 = load_table_b1(thesis_dir, apply_errata=apply_errata)
        for r in b1.to_dict("records"):
            i = int(r["index"]) - 1
            if _key(r["name"]) != _key(names[i]):
                raise DataValidationError(b1.attrs.get("source", "table_B1"),
                                          f"B.1 name '{r['name']}' does not match derived name '{names[i]}'",
                                          int(r["index"]), None, "name")
            f[i] = r["strength_N"]
            f_src[i] = "table_B1"
            if moment_arm_source == "b1_where_available":
                for j in B1_JOINTS:
                    for a in AXES:
                        v = r[f"{j}_{a}"]
                        R[COORDINATES.index(f"{j}_{a}"), i] = 0.0 if (v is None or np.isnan(v)) else v
                ma_src[i] = "table_B1 at C0-C1/C4-C5/C6-C7, derived elsewhere"
    elif moment_arm_source != "derived":
        raise ValueError("moment_arm_source='b1_where_available' needs thesis_dir")
    if moment_arm_source not in ("derived", "b1_where_available"):
        raise ValueError(f"unknown moment_arm_source {moment_arm_source!r}")

    muscles = pd.DataFrame({"index": np.arange(1, 97), "name": names,
                            "base": [base_name(n) for n in names], "side": [side_of(n) for n in names],
                            "strength_N": f, "strength_source": f_src, "moment_arm_source": ma_src})
    centres = coords.loc[list(COORDINATES), ["centre_x", "centre_y", "centre_z"]].to_numpy(float)
    axes = coords.loc[list(COORDINATES), ["axis_x", "axis_y", "axis_z"]].to_numpy(float)
    axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    return FullModel(muscles, f, R, centres, axes,
                     {"model_dir": str(model_dir), "thesis_dir": str(thesis_dir),
                      "moment_arm_source": moment_arm_source, "errata": str(apply_errata),
                      "unprinted_strengths": unprinted_strengths})


def load_table_b1(thesis_dir: str | Path, apply_errata: bool = True) -> pd.DataFrame:
    """Table B.1 as transcribed, with the documented errata applied (``errata_B1.csv``)."""
    thesis_dir = Path(thesis_dir)
    b1 = read_table(thesis_dir / "table_B1_muscles.csv", B1_SCHEMA)
    if apply_errata and (thesis_dir / "errata_B1.csv").exists():
        err = read_table(thesis_dir / "errata_B1.csv", ERRATA_SCHEMA)
        for k, e in enumerate(err.to_dict("records")):
            hit = b1.index[b1["index"] == e["index"]]
            if len(hit) != 1 or e["field"] not in b1.columns:
                raise DataValidationError(err.attrs["source"], "errata row does not match Table B.1",
                                          k + 1, None, "index")
            b1.loc[hit[0], e["field"]] = np.nan if e["corrected"] is None else e["corrected"]
    return b1
