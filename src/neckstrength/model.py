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
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from .geometry import PLANAR_INDEX, WRENCH_COMPONENTS, PLANAR_COMPONENTS, jacobian_transpose
from .io import Column, DataValidationError, Schema, read_table

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


@dataclass(frozen=True)
class ReducedModel:
    """A model variant ready for the max-wrench LP.

    ``moment_arms`` (n x m), ``strengths`` (m), ``JT`` (n x d) with d = 6
    (spatial, ``WRENCH_COMPONENTS``) or 3 (planar, ``PLANAR_COMPONENTS``).
    ``S`` is the (96 x m) grouping matrix used for the reduction.
    """

    name: str
    kinematic: str
    grouping: str
    coordinates: tuple[str, ...]
    muscle_names: tuple[str, ...]
    strengths: np.ndarray
    moment_arms: np.ndarray
    JT: np.ndarray
    S: np.ndarray
    task: tuple[str, ...]

    @property
    def planar(self) -> bool:
        return len(self.task) == 3

    @property
    def m(self) -> int:
        return len(self.strengths)

    @property
    def n(self) -> int:
        return len(self.coordinates)

    def task_direction(self, u6: np.ndarray) -> np.ndarray:
        """Project a 6-D unit wrench to this model's task space (and renormalise)."""
        u6 = np.asarray(u6, float)
        if not self.planar:
            return u6
        u = u6[..., PLANAR_INDEX]
        return u / np.linalg.norm(u, axis=-1, keepdims=True)

    def to_frame(self) -> pd.DataFrame:
        df = pd.DataFrame(self.moment_arms.T, columns=list(self.coordinates))
        df.insert(0, "strength_N", self.strengths)
        df.insert(0, "muscle", list(self.muscle_names))
        return df


# --------------------------------------------------------------------------- loading

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


# --------------------------------------------------------------------------- grouping

GROUP_SCHEMA = Schema("muscle grouping", (Column("group", "str"), Column("muscle", "str")))


def read_grouping(path: str | Path) -> pd.DataFrame:
    """A grouping table (``group, muscle[, name_normalized]``), base names without side."""
    df = read_table(path, GROUP_SCHEMA)
    if "name_normalized" not in df.columns:
        df["name_normalized"] = df["muscle"]
    return df


SUPPLEMENT_SCHEMA = Schema(
    "grouping supplements",
    (Column("model", "str"), Column("action", "str", choices=("add", "exclude")),
     Column("group", "str", allow_missing=True), Column("muscle", "str"), Column("evidence", "str")))


def read_grouping_supplements(path: str | Path, model: str) -> pd.DataFrame:
    df = read_table(path, SUPPLEMENT_SCHEMA)
    return df[df["model"] == model].reset_index(drop=True)


def apply_supplements(table: pd.DataFrame, supplements: pd.DataFrame | None) -> pd.DataFrame:
    """Add muscles to groups / exclude muscles (group '-') per ``grouping_supplements.csv``."""
    if supplements is None or len(supplements) == 0:
        return table
    t = table[["group", "muscle", "name_normalized"]].copy()
    keys = [_key(k) for k in t["name_normalized"]]
    for r in supplements.to_dict("records"):
        k = _key(r["muscle"])
        if k in keys:
            t = t[[kk != k for kk in keys]]
            keys = [kk for kk in keys if kk != k]
        g = r["group"] if r["action"] == "add" else "-"
        t = pd.concat([t, pd.DataFrame([{"group": g, "muscle": r["muscle"], "name_normalized": r["muscle"]}])],
                      ignore_index=True)
        keys.append(k)
    return t


def grouping_from_table(full: FullModel, table: pd.DataFrame, split_sides: bool,
                        source: str = "grouping table") -> tuple[np.ndarray, list[str]]:
    """Grouping matrix from a ``group, muscle`` table of base names.

    ``split_sides``: one group per side ('hyoids-R', 'hyoids-L'); otherwise left
    and right elements share a group (planar models). Every full-model muscle
    must be listed exactly once; group '-' means excluded (a zero row of S).
    """
    bases = [_key(b) for b in full.muscles["base"]]
    sides = list(full.muscles["side"])
    groups = [g for g in dict.fromkeys(table["group"]) if g != "-"]
    labels = [f"{g}-{s}" for g in groups for s in ("R", "L")] if split_sides else groups
    # spatial order: all right groups? The thesis lists R, L alternately (Table B.3).
    S = np.zeros((full.m, len(labels)))
    lookup = {}
    for k, r in enumerate(table.to_dict("records")):
        key = _key(r.get("name_normalized") or r["muscle"])
        if key in lookup:
            raise DataValidationError(source, f"muscle '{r['muscle']}' listed twice", k + 1, None, "muscle")
        lookup[key] = r["group"]
    unmatched = sorted(set(lookup) - set(bases))
    if unmatched:
        raise DataValidationError(source, f"muscles not in the full model: {unmatched}", field_name="muscle")
    for i, (b, s) in enumerate(zip(bases, sides)):
        if b not in lookup:
            raise DataValidationError(source, f"full-model muscle '{full.names[i]}' is in no group",
                                      field_name="muscle")
        g = lookup[b]
        if g == "-":
            continue
        col = labels.index(f"{g}-{s}") if split_sides else labels.index(g)
        S[i, col] = 1.0
    return S, labels


def _signature_grouping(full: FullModel, joints: Sequence[str], use_yaw: bool, split_sides: bool,
                        tol: float) -> tuple[np.ndarray, list[str]]:
    """Group muscles by the signs of their actions at ``joints`` (Sec. 4.2.1.2).

    Sagittal action: sign of the pitch moment arm (E/F/0) at each joint.
    Sagittal+axial: additionally the sign of the yaw moment arm relative to the
    muscle's side (ipsilateral 'i' / contralateral 'c' / 0). Muscles with the
    same signature (i.e. same joints crossed, same actions) form one group, so
    single- and multi-joint muscles fall into different groups. ``tol`` (m):
    moment arms below it count as zero.
    """
    sig_of = []
    for i, name in enumerate(full.names):
        side = full.muscles["side"].iat[i]
        parts = []
        for j in joints:
            p = full.moment_arms[COORDINATES.index(f"{j}_pitch"), i]
            s = "E" if p > tol else ("F" if p < -tol else "0")
            if use_yaw:
                y = full.moment_arms[COORDINATES.index(f"{j}_yaw"), i]
                # yaw + = left rotation; ipsilateral for a right muscle is right rotation (yaw < 0)
                ipsi = -y if side == "R" else y
                s += "i" if ipsi > tol else ("c" if ipsi < -tol else "0")
            parts.append(f"{j}:{s}")
        sig_of.append("|".join(parts))
    keys = [(sig, full.muscles["side"].iat[i]) if split_sides else (sig, "") for i, sig in enumerate(sig_of)]
    uniq_sigs = list(dict.fromkeys(sig_of))
    labels = []
    for k, sig in enumerate(uniq_sigs):
        if split_sides:
            labels += [f"g{k + 1:02d}[{sig}]-R", f"g{k + 1:02d}[{sig}]-L"]
        else:
            labels.append(f"g{k + 1:02d}[{sig}]")
    S = np.zeros((full.m, len(labels)))
    for i, (sig, side) in enumerate(keys):
        k = uniq_sigs.index(sig)
        lab = f"g{k + 1:02d}[{sig}]" + (f"-{side}" if split_sides else "")
        S[i, labels.index(lab)] = 1.0
    keep = S.sum(axis=0) > 0
    return S[:, keep], [l for l, kp in zip(labels, keep) if kp]


def grouping_matrix(full: FullModel, variant: str, planar: bool, thesis_dir: str | Path | None = None,
                    signature_joints: Sequence[str] = ("C0-C1", "C4-C5", "C6-C7"),
                    signature_tol: float = 1e-3,
                    supplements: pd.DataFrame | None = None) -> tuple[np.ndarray, list[str]]:
    """Grouping matrix ``S_m`` (96 x g) and group labels for a muscle variant."""
    split = not planar
    if variant == "independent":
        if split:
            return np.eye(full.m), full.names
        bases = list(dict.fromkeys(full.muscles["base"]))
        S = np.zeros((full.m, len(bases)))
        for i, b in enumerate(full.muscles["base"]):
            S[i, bases.index(b)] = 1.0
        return S, bases
    if variant in ("sagittal", "sagittal_axial"):
        return _signature_grouping(full, signature_joints, variant == "sagittal_axial", split, signature_tol)
    if thesis_dir is None:
        raise ValueError(f"grouping '{variant}' needs the thesis tables directory")
    thesis_dir = Path(thesis_dir)
    if variant == "anatomical":
        path = thesis_dir / ("table_B4_groups_p3m12.csv" if planar else "table_B2_groups_s3m24.csv")
    elif variant == "p2m7":
        path = thesis_dir / "table_B6_groups_p2m7.csv"
    else:
        raise ValueError(f"unknown muscle variant {variant!r}; choose from {MUSCLE_VARIANTS}")
    return grouping_from_table(full, apply_supplements(read_grouping(path), supplements), split, str(path))


def reduce_strengths_and_arms(R: np.ndarray, f: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sec. 4.2.1.3: ``F_g(i) = ||F . S(:, i)||``, ``R_g(:, i) = (R diag(F) S)(:, i) / F_g(i)``."""
    tau_g = R @ (f[:, None] * S)
    f_g = np.sqrt(((f[:, None] * S) ** 2).sum(axis=0))
    if np.any(S.sum(axis=0) == 0):
        raise ValueError("a muscle group has no members")
    # a group whose members all have zero strength (e.g. deep extensors scaled by 0) produces no torque;
    # its grouped moment arm is then undefined and set to 0
    with np.errstate(divide="ignore", invalid="ignore"):
        R_g = np.where(f_g[None, :] > 0, tau_g / np.where(f_g > 0, f_g, 1.0)[None, :], 0.0)
    return f_g, R_g


def reduce_model(full: FullModel, kinematic: str, grouping: str, thesis_dir: str | Path | None = None,
                 name: str | None = None, signature_tol: float = 1e-3,
                 supplements: pd.DataFrame | None = None) -> ReducedModel:
    """Kinematic and muscle reduction of the full model (Sec. 4.2.1.3)."""
    if kinematic not in KINEMATIC_VARIANTS:
        raise ValueError(f"unknown kinematic variant {kinematic!r}; choose from {list(KINEMATIC_VARIANTS)}")
    space, joints = KINEMATIC_VARIANTS[kinematic]
    planar = space == "planar"
    axes_kept = ("pitch",) if planar else AXES
    coords = tuple(f"{j}_{a}" for j in joints for a in axes_kept)
    rows = [COORDINATES.index(c) for c in coords]
    sig_joints = joints if len(joints) <= 3 else ("C0-C1", "C4-C5", "C6-C7")
    S, labels = grouping_matrix(full, grouping, planar, thesis_dir, sig_joints, signature_tol, supplements)
    f_g, R_g = reduce_strengths_and_arms(full.moment_arms[rows], full.strengths, S)
    JT = jacobian_transpose(full.centres[rows], full.axes[rows])
    task = WRENCH_COMPONENTS
    if planar:
        JT = JT[:, PLANAR_INDEX]
        task = PLANAR_COMPONENTS
    return ReducedModel(name or f"{kinematic}-{grouping}", kinematic, grouping, coords, tuple(labels),
                        f_g, R_g, JT, S, task)


def scale_strengths(full: FullModel, mask: np.ndarray, factor: float) -> FullModel:
    """A copy of ``full`` with the strengths of the muscles in ``mask`` multiplied by ``factor``.

    Scaling a group "by scaling all elements in that group individually" (Sec. 4.2.1.3), before reduction,
    so that it works for every grouping, including groups that mix scaled and unscaled muscles.
    """
    if factor < 0:
        raise ValueError("strength factor must be >= 0")
    f = full.strengths.copy()
    f[np.asarray(mask, bool)] *= factor
    muscles = full.muscles.copy()
    muscles["strength_N"] = f
    return FullModel(muscles, f, full.moment_arms, full.centres, full.axes, full.provenance)


def named_model(full: FullModel, model: str, thesis_dir: str | Path | None = None,
                grouping_supplements: bool = True, signature_tol: float = 1e-3) -> ReducedModel:
    """One of the thesis's named models (p2m7, p3m12, s3m24) or '{kinematic}-{grouping}'.

    For named models, ``grouping_supplements`` applies ``grouping_supplements.csv``
    (the corrections that make the printed groupings reproduce Tables B.5/B.7).
    """
    if model in NAMED_MODELS:
        k, g = NAMED_MODELS[model]
        sup = None
        if grouping_supplements and thesis_dir is not None \
                and (Path(thesis_dir) / "grouping_supplements.csv").exists():
            sup = read_grouping_supplements(Path(thesis_dir) / "grouping_supplements.csv", model)
        return reduce_model(full, k, g, thesis_dir, name=model, signature_tol=signature_tol, supplements=sup)
    if "-" in model:
        k, g = model.split("-", 1)
        return reduce_model(full, k, g, thesis_dir, name=model, signature_tol=signature_tol)
    raise ValueError(f"unknown model {model!r}: use {list(NAMED_MODELS)} or '<kinematic>-<grouping>' with "
                     f"kinematic in {list(KINEMATIC_VARIANTS)} and grouping in {MUSCLE_VARIANTS}")
