"""Model reduction (thesis Sec. 4.2.1): kinematic variants and muscle groupings.

:func:`reduce_model` keeps the chosen joints (planar or spatial task space) and groups
muscles (grouping matrix ``S_m``, group strength = 2-norm, grouped moment arm = torque
contribution / group strength); :class:`ReducedModel` is what every solver takes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.io import Column, DataValidationError, Schema, read_table
from neckstrength.model.full import (
    AXES,
    COORDINATES,
    KINEMATIC_VARIANTS,
    MUSCLE_VARIANTS,
    NAMED_MODELS,
    FullModel,
    _key,
)
from neckstrength.model.geometry import PLANAR_COMPONENTS, PLANAR_INDEX, WRENCH_COMPONENTS, jacobian_transpose


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
     Column("group", "str", allow_missing=True), Column("muscle", "str"),
     Column("basis", "str", choices=("printed", "anatomy", "fit")), Column("evidence", "str")))


def supplement_level(value: bool | str) -> str:
    """Config ``model.grouping_supplements``: 'anatomy' (rows justified by the printed tables or anatomy), 'all'
    (also rows that exist only to reproduce a printed value, basis 'fit'), 'none'; true = 'all', false = 'none'."""
    level = {True: "all", False: "none"}.get(value, value) if isinstance(value, bool) else str(value)
    if level not in ("all", "anatomy", "none"):
        raise ValueError(f"model.grouping_supplements: {value!r} (use anatomy, all or none)")
    return level


def read_grouping_supplements(path: str | Path, model: str, level: bool | str = "all") -> pd.DataFrame:
    df = read_table(path, SUPPLEMENT_SCHEMA)
    lv = supplement_level(level)
    keep = (df["model"] == model) & {"all": True, "anatomy": df["basis"] != "fit", "none": False}[lv]
    return df[keep].reset_index(drop=True)


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
                grouping_supplements: bool | str = True, signature_tol: float = 1e-3) -> ReducedModel:
    """One of the thesis's named models (p2m7, p3m12, s3m24) or '{kinematic}-{grouping}'.

    For named models, ``grouping_supplements`` applies ``grouping_supplements.csv``
    (the corrections that make the printed groupings reproduce Tables B.5/B.7): True / 'all' every row,
    'anatomy' the rows justified by the printed tables or by anatomy (not those that exist only to hit a printed
    value, basis 'fit'), False / 'none' none.
    """
    if model in NAMED_MODELS:
        k, g = NAMED_MODELS[model]
        sup = None
        if supplement_level(grouping_supplements) != "none" and thesis_dir is not None \
                and (Path(thesis_dir) / "grouping_supplements.csv").exists():
            sup = read_grouping_supplements(Path(thesis_dir) / "grouping_supplements.csv", model,
                                            grouping_supplements)
        return reduce_model(full, k, g, thesis_dir, name=model, signature_tol=signature_tol, supplements=sup)
    if "-" in model:
        k, g = model.split("-", 1)
        return reduce_model(full, k, g, thesis_dir, name=model, signature_tol=signature_tol)
    raise ValueError(f"unknown model {model!r}: use {list(NAMED_MODELS)} or '<kinematic>-<grouping>' with "
                     f"kinematic in {list(KINEMATIC_VARIANTS)} and grouping in {MUSCLE_VARIANTS}")
