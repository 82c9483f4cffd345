"""Read and check the shipped posture tables (``data/model/postures/``, docs/postures.md); no OpenSim needed."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.io import Column, DataValidationError, Schema, read_table
from neckstrength.model.full import COORDINATES, FullModel
from neckstrength.model.geometry import WRENCH_COMPONENTS, jacobian_transpose

#: Postures of issue 20, in the order the derivation writes them (neutral first).
POSTURE_NAMES = ("neutral", "flex20", "ext20", "rotL30", "rotR30", "bendL15", "bendR15")

#: Sagittal postures: the only ones in which the sagittal plane of the skull stays the sagittal plane of the neck.
SAGITTAL_POSTURES = ("neutral", "flex20", "ext20")

#: Mirror partner of each posture (left <-> right).
MIRROR = {"neutral": "neutral", "flex20": "flex20", "ext20": "ext20", "rotL30": "rotR30", "rotR30": "rotL30",
          "bendL15": "bendR15", "bendR15": "bendL15"}

POSTURES_DIR = "postures"

FORCE_LENGTH_OPTIONS = ("relative", "absolute", "none")

_MA_SCHEMA = Schema("posture moment arms", (Column("index", "int", None, 1, 96), Column("name", "str"))
                    + tuple(Column(c, "float", "m", -0.25, 0.25) for c in COORDINATES), unique=("index",))

_CO_SCHEMA = Schema(
    "posture coordinates",
    (Column("coordinate", "str", choices=COORDINATES),)
    + tuple(Column(f"centre_{a}", "float", "m", -0.5, 0.5) for a in "xyz")
    + tuple(Column(f"axis_{a}", "float", "1", -1, 1) for a in "xyz")
    + tuple(Column(f"JT_{c}", "float", None, -1.5, 1.5) for c in WRENCH_COMPONENTS),
    unique=("coordinate",))

_FL_SCHEMA = Schema("posture force-length factors",
                    (Column("index", "int", None, 1, 96), Column("name", "str"),
                     Column("norm_fiber_length", "float", "1", 0.0, 3.0, min_exclusive=True),
                     Column("factor", "float", "1", 0.0, 1.0), Column("factor_rel", "float", "1", 0.0, 10.0)),
                    unique=("index",))


@dataclass(frozen=True)
class PostureTable:
    """One posture: ``moment_arms`` R (21 x 96), joint ``centres``/``axes`` (21 x 3), ``JT`` (21 x 6) and the
    active force-length factor of each element (absolute and relative to neutral)."""

    name: str
    moment_arms: np.ndarray
    centres: np.ndarray
    axes: np.ndarray
    JT: np.ndarray
    factor: np.ndarray
    factor_rel: np.ndarray
    names: tuple[str, ...]

    def strength_factor(self, force_length: str = "relative") -> np.ndarray:
        """Multiplier of each element's maximum force in this posture (config ``postures.force_length``)."""
        if force_length == "relative":
            return self.factor_rel
        if force_length == "absolute":
            return self.factor
        if force_length == "none":
            return np.ones_like(self.factor)
        raise ValueError(f"postures.force_length: {force_length!r} (use one of {FORCE_LENGTH_OPTIONS})")


def load_posture_tables(model_dir: str | Path, postures: Sequence[str] | None = None) -> dict[str, PostureTable]:
    """The posture tables under ``<model_dir>/postures`` (all shipped postures, or ``postures``)."""
    d = Path(model_dir) / POSTURES_DIR
    if not (d / "postures_provenance.json").exists():
        raise FileNotFoundError(f"{d}: no posture tables (derive them: python -m neckstrength.model.opensim.postures)")
    post = pd.read_csv(d / "postures.csv", comment="#")
    known = list(post["posture"])
    postures = known if postures is None else list(postures)
    bad = [p for p in postures if p not in known]
    if bad:
        raise ValueError(f"unknown postures {bad}; {d / 'postures.csv'} has {known}")
    out = {}
    for p in postures:
        ma = read_table(d / f"moment_arms_{p}.csv", _MA_SCHEMA).sort_values("index")
        co = read_table(d / f"coordinates_{p}.csv", _CO_SCHEMA).set_index("coordinate").loc[list(COORDINATES)]
        fl = read_table(d / f"force_length_{p}.csv", _FL_SCHEMA).sort_values("index")
        if list(ma["index"]) != list(range(1, 97)) or list(fl["index"]) != list(range(1, 97)):
            raise DataValidationError(d / f"moment_arms_{p}.csv", "expected the 96 thesis muscles in index order")
        out[p] = PostureTable(
            p, ma[list(COORDINATES)].to_numpy(float).T.copy(),
            co[["centre_x", "centre_y", "centre_z"]].to_numpy(float), co[["axis_x", "axis_y", "axis_z"]].to_numpy(float),
            co[[f"JT_{c}" for c in WRENCH_COMPONENTS]].to_numpy(float),
            fl["factor"].to_numpy(float), fl["factor_rel"].to_numpy(float), tuple(ma["name"]))
    return out


def provenance(model_dir: str | Path) -> dict:
    return json.loads((Path(model_dir) / POSTURES_DIR / "postures_provenance.json").read_text())


def check_posture_tables(tables: dict[str, PostureTable], full: FullModel | None = None,
                         atol_m: float = 2e-6, atol_jt: float = 2e-6) -> dict[str, float]:
    """Consistency checks that need no OpenSim; raises ``ValueError`` on the first failure, returns the errors.

    - every ``JT`` row is ``[a, c x a]`` of its axis and centre, with unit axes (the tables are written to 6-8
      decimals: ``atol_jt``);
    - left/right mirror: the mirror posture's moment arms equal this posture's with left and right muscles swapped,
      pitch equal and roll/yaw negated (exact in the generic geometry; ``atol_m`` = CSV rounding);
    - neutral: equal to the full model's derived moment arms and joint centres/axes (if ``full`` is given and was
      built with derived moment arms), with every relative force-length factor 1.
    """
    errs: dict[str, float] = {}
    sgn = np.array([1.0 if c.endswith("pitch") else -1.0 for c in COORDINATES])
    for p, t in tables.items():
        e = float(np.max(np.abs(jacobian_transpose(t.centres, t.axes) - t.JT)))
        errs[f"{p}: JT vs [a, c x a]"] = e
        if e > atol_jt:
            raise ValueError(f"posture {p}: J^T rows differ from [a, c x a] by {e:.2e}")
        q = MIRROR.get(p)
        if q in tables:
            swap = np.arange(96).reshape(48, 2)[:, ::-1].ravel()
            e = float(np.max(np.abs(tables[q].moment_arms[:, swap] - sgn[:, None] * t.moment_arms)))
            errs[f"{p}: mirror of {q}"] = e
            if e > atol_m:
                raise ValueError(f"posture {p}: moment arms are not the mirror image of {q} (max error {e:.2e} m)")
    if "neutral" in tables:
        t = tables["neutral"]
        e = float(np.max(np.abs(t.factor_rel - 1.0)))
        errs["neutral: factor_rel - 1"] = e
        if e > 1e-6:
            raise ValueError("neutral posture: relative force-length factors are not 1")
        if full is not None and full.provenance.get("moment_arm_source", "derived") == "derived":
            e = float(np.max(np.abs(t.moment_arms - full.moment_arms)))
            errs["neutral: moment arms vs full model"] = e
            if e > atol_m:
                raise ValueError(f"neutral posture: moment arms differ from the full model by {e:.2e} m")
            e = max(float(np.max(np.abs(t.centres - full.centres))), float(np.max(np.abs(t.axes - full.axes))))
            errs["neutral: centres/axes vs full model"] = e
            if e > atol_m:
                raise ValueError(f"neutral posture: joint centres/axes differ from the full model by {e:.2e}")
    return errs
