"""Derive the full 96-muscle, 21-DOF neck model tables from OpenSim model files.

This is a one-off *derivation* command, not part of the default pipeline.  It
needs the optional dependency ``opensim`` (``pip install neckstrength[opensim]``)
and two reference model files that are **not** part of the project (see
``docs/model_derivation.md``):

* ``Mortensen2014_rigidTorso.osim`` -- the generic Vasavada/Mortensen head-neck
  model with hyoid muscles (72 of the thesis' 96 muscles), and
* ``ModelOfNeckAndShoulder.osim`` -- a uniformly scaled copy of the same neck
  that additionally contains the cervical multifidus slips (``supmult-*``,
  ``deepmult-*``; thesis rows 73-96).

Usage::

    python -m neckstrength.derive_opensim \\
        --osim path/to/Mortensen2014_rigidTorso.osim \\
        --multifidus-osim path/to/ModelOfNeckAndShoulder.osim \\
        --out data/model [--seed path/to/thesis.txt]

What it does (details and rationale in ``docs/model_derivation.md``):

1. loads the generic model, disables all ``CoordinateCouplerConstraint`` s (the
   file drives the lower joints from ``pitch2/roll2/yaw2`` and C1-C2 from
   ``pitch1/roll1/yaw1``), replaces every non-identity rotation function of the
   intervertebral ``CustomJoint`` s by the identity, so that each of the 3
   coordinates of each joint is the physical rotation angle (rad) about the
   joint axis, and sets the neutral posture (all intervertebral coordinates 0);
2. copies the multifidus path points from the second file into the generic model,
   undoing that file's uniform per-body scaling (factors estimated from all
   path points and joint offsets that both files share);
3. computes the moment arm of every muscle about each of the 21 coordinates of
   the joints C0-C1 ... C6-C7 with OpenSim (``Muscle.computeMomentArm``), checks
   it against a central finite difference of the muscle length, and converts it
   to the thesis sign convention (pitch + extension, roll + right side-bend,
   yaw + left rotation);
4. records joint centres and rotation axes in the skull frame, the model's
   maximum isometric forces (both strength conventions), and compares the
   result with the moment arms printed in Table B.1 of the thesis.

The table row order (thesis Table B.1 order, 1..96) is :data:`THESIS_MUSCLES`.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import hashlib
import json
import math
import re
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import pandas as pd

# --------------------------------------------------------------------------- #
# Constants: thesis muscle order, joints, sign convention
# --------------------------------------------------------------------------- #

GENERIC = "generic"
MULTIFIDUS = "multifidus"

#: The 48 right-side muscles in thesis Table B.1 order (row 2k-1 is the right
#: muscle, row 2k its left partner with suffix " L").  Each entry:
#: (B.1 spelling, OpenSim name of the right muscle, which input file).
#: Rows 1-14, 31-46 and 63-96 are printed in the seed text; rows 15-30 and
#: 47-62 are missing there and are filled in the order of a public MATLAB
#: enumeration of the same 96 muscles (``classdef Muscles < uint8``), which
#: reproduces every printed row (see docs/model_derivation.md).
THESIS_MUSCLES: tuple[tuple[str, str, str], ...] = (
    ("digastric post", "digastric_post", GENERIC),  # 1
    ("digastric ant", "digastric_ant", GENERIC),  # 3
    ("mylohyoid ant", "Mylohyoid_Ant", GENERIC),  # 5
    ("stylohyoid lat", "Stylohyoid_Lat", GENERIC),  # 7
    ("stylohyoid med", "Stylohyoid_Med", GENERIC),  # 9
    ("sternohyoid", "Sterno_hyoid", GENERIC),  # 11
    ("geniohyoid", "Geniohyoid", GENERIC),  # 13
    ("mylohyoid post", "Mylohyoid_Post", GENERIC),  # 15  (not printed)
    ("sternothyroid", "SternoThyroid", GENERIC),  # 17  (not printed)
    ("omohyoid", "Omo_hyoid", GENERIC),  # 19  (not printed)
    ("stern mast", "stern_mast", GENERIC),  # 21  (not printed)
    ("cleid mast", "cleid_mast", GENERIC),  # 23  (not printed)
    ("cleid occ", "cleid_occ", GENERIC),  # 25  (not printed)
    ("scalenus ant", "scalenus_ant", GENERIC),  # 27  (not printed)
    ("scalenus med", "scalenus_med", GENERIC),  # 29  (not printed)
    ("scalenus post", "scalenus_post", GENERIC),  # 31
    ("long cap sklc4", "long_cap_sklc4", GENERIC),  # 33
    ("long col c1thx", "long_col_c1thx", GENERIC),  # 35
    ("long col c1c5", "long_col_c1c5", GENERIC),  # 37
    ("long col c5thx", "long_col_c5thx", GENERIC),  # 39
    ("trap cl", "trap_cl", GENERIC),  # 41
    ("trap acr", "trap_acr", GENERIC),  # 43
    ("splen cap sklc6", "splen_cap_sklc6", GENERIC),  # 45
    ("splen cap sklthx", "splen_cap_sklthx", GENERIC),  # 47  (not printed)
    ("semi cap sklc5", "semi_cap_sklc5", GENERIC),  # 49  (not printed)
    ("semi cap sklthx", "semi_cap_sklthx", GENERIC),  # 51  (not printed)
    ("splen cerv c3thx", "splen_cerv_c3thx", GENERIC),  # 53  (not printed)
    ("semi cerv c3thx", "semi_cerv_c3thx", GENERIC),  # 55  (not printed)
    ("levator scap", "levator_scap", GENERIC),  # 57  (not printed)
    ("longissi cap sklc6", "longissi_cap_sklc6", GENERIC),  # 59  (not printed)
    ("longissi cerv c4thx", "longissi_cerv_c4thx", GENERIC),  # 61  (not printed)
    ("iliocost cerv c5rib", "iliocost_cerv_c5rib", GENERIC),  # 63
    ("rectcap post maj", "rectcap_post_maj", GENERIC),  # 65
    ("rectcap post min", "rectcap_post_min", GENERIC),  # 67
    ("obl cap sup", "obl_cap_sup", GENERIC),  # 69
    ("obl cap inf", "obl_cap_inf", GENERIC),  # 71
    ("mult sup C45C2", "supmult-C4-5-C2", MULTIFIDUS),  # 73
    ("mult sup C56C2", "supmult-C5-6-C2", MULTIFIDUS),  # 75
    ("mult sup C67C2", "supmult-C6-7-C2", MULTIFIDUS),  # 77
    ("mult sup T1C4", "supmult-T1-C4", MULTIFIDUS),  # 79
    ("mult sup T1C5", "supmult-T1-C5", MULTIFIDUS),  # 81
    ("mult sup T2C6", "supmult-T2-C6", MULTIFIDUS),  # 83
    ("mult deep C45C2", "deepmult-C4-5-C2", MULTIFIDUS),  # 85
    ("mult deep C56C3", "deepmult-C5-6-C3", MULTIFIDUS),  # 87
    ("mult deep C67C4", "deepmult-C6-7-C4", MULTIFIDUS),  # 89
    ("mult deep T1C5", "deepmult-T1-C5", MULTIFIDUS),  # 91
    ("mult deep T1C6", "deepmult-T1-C6", MULTIFIDUS),  # 93
    ("mult deep T2C7", "deepmult-T2-C7", MULTIFIDUS),  # 95
)

#: B.1 rows that are not printed in the seed text (their order is inferred).
UNPRINTED_B1_ROWS: tuple[int, ...] = tuple(range(15, 31)) + tuple(range(47, 63))

#: Thesis joints, cranial to caudal; coordinate k of R is JOINTS[k // 3], AXES[k % 3].
JOINTS: tuple[str, ...] = ("C0-C1", "C1-C2", "C2-C3", "C3-C4", "C4-C5", "C5-C6", "C6-C7")
AXES: tuple[str, ...] = ("pitch", "roll", "yaw")
COORDINATES: tuple[str, ...] = tuple(f"{j}_{a}" for j in JOINTS for a in AXES)

#: Thesis sign convention as the positive rotation axis in the skull frame
#: (x anterior, y superior, z right; right-hand rule, rotation of the cranial
#: segment relative to the caudal one):
#: pitch about +z = extension, roll about +x = right side-bend,
#: yaw about +y = left axial rotation.
THESIS_AXIS_VECTORS: dict[str, tuple[float, float, float]] = {
    "pitch": (0.0, 0.0, 1.0),
    "roll": (1.0, 0.0, 0.0),
    "yaw": (0.0, 1.0, 0.0),
}
SIGN_CONVENTION = (
    "moment arm r = -dL/dq (m/rad) about each joint axis; pitch (+) extension, "
    "roll (+) right side-bend, yaw (+) left axial rotation (thesis Table B.1); "
    "skull frame: origin at the C0-C1 joint centre, x anterior, y superior, z right; "
    "pitch about +z, roll about +x, yaw about +y (right-hand rule, cranial segment "
    "relative to caudal segment); neutral posture (all intervertebral angles 0)"
)

#: Vertebral level of each body of the Vasavada/Mortensen neck models.
BODY_LEVELS: dict[str, str] = {
    "skull": "C0",
    **{f"cerv{i}": f"C{i}" for i in range(1, 8)},
    "spine": "T1",
}

#: Provenance of the reference files (from shared/models/README.md), by sha256.
KNOWN_SOURCES: dict[str, dict[str, str]] = {
    "23a8d694636235326495acda3b7c86bf4329d72da5cc49b0e15c3b13705d07fa": {
        "repository": "mjhmilla/kinematicPassengerModel",
        "commit": "5096f5537c26d1100a46b8d4362ad5a109c054e9",
        "path": "models/Mortensen2014_rigidTorso.osim",
        "licence": "MIT",
    },
    "3e821dde3aa91bc06446cf2748ea0e2e9e15d221d7117bcd3481ea19edd5819d": {
        "repository": "mariasoroka/Musculoskeletal_model_of_neck_and_shoulder",
        "commit": "4e2f893280998186648f500f8f1798ce03694f25",
        "path": "Models/ModelOfNeckAndShoulder.osim",
        "licence": "none stated (used only to derive multifidus geometry)",
    },
}

MUSCLES_CSV = "full_model_muscles.csv"
MOMENT_ARMS_CSV = "full_model_moment_arms.csv"
COORDINATES_CSV = "full_model_coordinates.csv"
PROVENANCE_JSON = "full_model_provenance.json"
COMPARISON_CSV = "momentarm_vs_B1.csv"

#: Central finite-difference step (rad) used to cross-check computeMomentArm.
FD_STEP = 1e-6
#: Moment arms with |r| below this (m) are written as exactly 0 (muscle does not
#: cross the joint; OpenSim returns ~1e-17 there).
ZERO_TOL = 1e-10


# --------------------------------------------------------------------------- #
# Small helpers
# --------------------------------------------------------------------------- #


def _import_opensim():
    """Import opensim lazily, with an actionable error if it is missing."""
    try:
        import opensim  # type: ignore[import-not-found]
    except ImportError as exc:  # pragma: no cover - depends on environment
        raise ImportError(
            "neckstrength.derive_opensim needs the OpenSim Python package. "
            "Install it with `pip install neckstrength[opensim]` "
            "(OpenSim 4.6, CPython 3.11, x86-64 Linux/Windows/macOS wheels)."
        ) from exc
    return opensim


def thesis_muscle_table() -> pd.DataFrame:
    """The 96 thesis muscles in B.1 order: index, name, osim_name, source, side."""
    rows = []
    for k, (name, osim_name, source) in enumerate(THESIS_MUSCLES):
        rows.append((2 * k + 1, name, osim_name, source, "R"))
        rows.append((2 * k + 2, f"{name} L", f"{osim_name}_L", source, "L"))
    return pd.DataFrame(rows, columns=["index", "name", "osim_name", "source", "side"])


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _source_info(path: Path, override: str | None = None) -> dict[str, str]:
    digest = sha256_file(path)
    info: dict[str, str] = {"file": path.name, "sha256": digest}
    if override:
        repo, _, commit = override.partition("@")
        info.update(repository=repo, commit=commit or "unknown")
    elif digest in KNOWN_SOURCES:
        info.update(KNOWN_SOURCES[digest])
    else:
        info.update(repository="unknown (pass --osim-source/--multifidus-source)", commit="unknown")
    return info


@dataclass
class _PathPoint:
    name: str
    body: str
    location: np.ndarray


def read_osim_muscles(path: Path) -> dict[str, dict[str, Any]]:
    """Parse muscles of an .osim file with ElementTree (no OpenSim needed).

    Returns ``{name: {"type", "points": [_PathPoint], "max_isometric_force",
    "optimal_fiber_length", "tendon_slack_length", "pennation_angle_at_optimal"}}``.
    Only plain ``PathPoint`` s are read; muscles with conditional/moving points
    list those in ``"unsupported_points"`` (none of the neck muscles has any).
    """
    root = ET.parse(path).getroot()
    out: dict[str, dict[str, Any]] = {}
    for el in root.iter():
        if not el.tag.endswith("Muscle") or el.get("name") is None:
            continue
        pts = []
        unsupported = sorted({pp.tag for pp in el.iter() if pp.tag in ("ConditionalPathPoint", "MovingPathPoint")})
        for pp in el.iter():
            if pp.tag != "PathPoint":
                continue
            sock = pp.find("socket_parent_frame")
            loc = pp.find("location")
            if sock is None or loc is None or sock.text is None or loc.text is None:
                raise ValueError(f"{path.name}: path point {pp.get('name')} lacks frame/location")
            pts.append(
                _PathPoint(pp.get("name", ""), sock.text.strip().split("/")[-1], np.array([float(v) for v in loc.text.split()]))
            )
        rec: dict[str, Any] = {"type": el.tag, "points": pts, "unsupported_points": unsupported}
        for prop in ("max_isometric_force", "optimal_fiber_length", "tendon_slack_length", "pennation_angle_at_optimal"):
            p = el.find(prop)
            rec[prop] = float(p.text) if p is not None and p.text else float("nan")
        out[el.get("name")] = rec
    return out


def read_osim_joint_offsets(path: Path) -> dict[tuple[str, str], tuple[str, np.ndarray]]:
    """Joint offset frames: {(joint, frame): (parent body, translation)}."""
    root = ET.parse(path).getroot()
    out = {}
    for j in root.iter():
        if not j.tag.endswith("Joint") or j.get("name") is None:
            continue
        frames = j.find("frames")
        if frames is None:
            continue
        for po in frames:
            sp, tr = po.find("socket_parent"), po.find("translation")
            if sp is None or tr is None or sp.text is None or tr.text is None:
                continue
            out[(j.get("name"), po.get("name"))] = (sp.text.strip().split("/")[-1], np.array([float(v) for v in tr.text.split()]))
    return out


def estimate_scale_factors(
    generic_path: Path, scaled_path: Path, min_abs: float = 1e-3
) -> dict[str, dict[str, float]]:
    """Per-body uniform scale factors of ``scaled_path`` relative to ``generic_path``.

    Uses every path point of every muscle present in both files with the same
    body and point count, and every joint offset frame present in both, taking
    coordinate ratios where the generic coordinate exceeds ``min_abs`` (m).
    Returns ``{body: {"factor": median, "n": count, "n_outliers": count of ratios
    more than 1e-4 (relative) away from the median, "max_rel_spread": ...}}``.
    Outliers come from points the second file moved (hyoid bone points), not
    from non-uniform scaling.
    """
    ga, sa = read_osim_muscles(generic_path), read_osim_muscles(scaled_path)
    ratios: dict[str, list[float]] = defaultdict(list)
    for name, rec in ga.items():
        other = sa.get(name)
        if other is None or len(other["points"]) != len(rec["points"]) or rec["unsupported_points"] or other["unsupported_points"]:
            continue
        for p, q in zip(rec["points"], other["points"]):
            if p.body != q.body:
                continue
            for a, b in zip(p.location, q.location):
                if abs(a) > min_abs:
                    ratios[p.body].append(b / a)
    fa, fb = read_osim_joint_offsets(generic_path), read_osim_joint_offsets(scaled_path)
    for key, (body, tr) in fa.items():
        if key not in fb or fb[key][0] != body:
            continue
        for a, b in zip(tr, fb[key][1]):
            if abs(a) > min_abs:
                ratios[body].append(b / a)
    out = {}
    for body, vals in sorted(ratios.items()):
        v = np.asarray(vals)
        med = float(np.median(v))
        rel = np.abs(v / med - 1.0)
        out[body] = {
            "factor": med,
            "n": int(v.size),
            "n_outliers": int(np.sum(rel > 1e-4)),
            "max_rel_spread_inliers": float(rel[rel <= 1e-4].max()) if np.any(rel <= 1e-4) else float("nan"),
        }
    return out


# --------------------------------------------------------------------------- #
# B.1 reference values
# --------------------------------------------------------------------------- #

B1_JOINT_COLUMNS = ("C6-C7", "C4-C5", "C0-C1")  # order of the printed column groups


def parse_b1_from_seed(seed_path: Path) -> pd.DataFrame:
    """Parse thesis Table B.1 from the seed text.

    Returns a long table ``index, name, strength_N, joint, axis, b1_m`` with one
    row per printed (nonblank) moment arm.  Rows are ``<index> <name>\\t<strength>``
    followed by 9 tab-separated moment-arm cells (C6-C7, C4-C5, C0-C1 x pitch,
    roll, yaw); blank cells are empty strings between tabs.
    """
    text = Path(seed_path).read_text(encoding="utf-8")
    start = text.find("Table B.1.")
    end = text.find("Table B.2.", start)
    if start < 0 or end < 0:
        raise ValueError(f"{seed_path}: cannot find Table B.1 in the seed text")
    rows = []
    for line in text[start:end].splitlines():
        m = re.match(r"^(\d+) ([^\t]+)\t(.*)$", line)
        if not m:
            continue
        idx, name, rest = int(m.group(1)), m.group(2).strip(), m.group(3).split("\t")
        strength = float(rest[0]) if rest and rest[0].strip() else float("nan")
        cells = rest[1:]
        if len(cells) == 9:
            for g, joint in enumerate(B1_JOINT_COLUMNS):
                for a, axis in enumerate(AXES):
                    c = cells[3 * g + a].strip()
                    if c:
                        rows.append((idx, name, strength, joint, axis, float(c)))
        elif any(c.strip() for c in cells):
            raise ValueError(f"{seed_path}: B.1 row {idx} has {len(cells)} moment-arm cells, expected 9")
    return pd.DataFrame(rows, columns=["index", "name", "strength_N", "joint", "axis", "b1_m"])


def read_b1_table(csv_path: Path) -> pd.DataFrame:
    """Read the project's B.1 table (``index,name,strength_N,<joint>_<axis>...``)
    into the same long format as :func:`parse_b1_from_seed`."""
    wide = pd.read_csv(csv_path, comment="#")
    rows = []
    for _, r in wide.iterrows():
        for col in wide.columns:
            if "_" not in col or col in ("strength_N",):
                continue
            joint, _, axis = col.rpartition("_")
            if joint in JOINTS and axis in AXES and pd.notna(r[col]):
                rows.append((int(r["index"]), str(r["name"]), float(r.get("strength_N", float("nan"))), joint, axis, float(r[col])))
    return pd.DataFrame(rows, columns=["index", "name", "strength_N", "joint", "axis", "b1_m"])


def compare_with_b1(moment_arms: pd.DataFrame, b1_long: pd.DataFrame) -> pd.DataFrame:
    """Compare derived moment arms (wide: index,name,<coords>) with B.1 (long)."""
    wide = moment_arms.set_index("index")
    out = []
    for _, r in b1_long.sort_values(["index", "joint", "axis"]).iterrows():
        derived = float(wide.loc[int(r["index"]), f"{r['joint']}_{r['axis']}"])
        diff = derived - float(r["b1_m"])
        rel = diff / abs(r["b1_m"]) if r["b1_m"] != 0 else float("nan")
        out.append((int(r["index"]), wide.loc[int(r["index"]), "name"], r["joint"], r["axis"], float(r["b1_m"]), derived, diff, rel))
    cmp_ = pd.DataFrame(out, columns=["index", "name", "joint", "axis", "b1_m", "derived_m", "diff_m", "rel_diff"])
    # B.1 column order: joint groups as printed, then pitch/roll/yaw
    cmp_["_j"] = cmp_["joint"].map({j: i for i, j in enumerate(B1_JOINT_COLUMNS)})
    cmp_["_a"] = cmp_["axis"].map({a: i for i, a in enumerate(AXES)})
    return cmp_.sort_values(["index", "_j", "_a"]).drop(columns=["_j", "_a"]).reset_index(drop=True)


# --------------------------------------------------------------------------- #
# OpenSim part
# --------------------------------------------------------------------------- #


def _vec3(osim, v: Iterable[float]):
    x, y, z = (float(t) for t in v)
    return osim.Vec3(x, y, z)


def _np3(v) -> np.ndarray:
    return np.array([v.get(0), v.get(1), v.get(2)], dtype=float)


def _function_value_slope(osim, f, q: float = 0.0) -> tuple[float, float]:
    x = osim.Vector(1, q)
    return float(f.calcValue(x)), float(f.calcDerivative(osim.StdVectorInt([0]), x))


def _find_joint_chain(model, osim, skull: str = "skull", n_joints: int = 7) -> list[dict[str, Any]]:
    """Walk from the skull caudally: the joint whose child is the current body.

    Returns n_joints dicts {label, joint, parent_body, child_body}, cranial first.
    """
    by_child: dict[str, Any] = {}
    js = model.getJointSet()
    for i in range(js.getSize()):
        j = js.get(i)
        child_body = j.getChildFrame().findBaseFrame().getName()
        by_child[child_body] = j
    chain = []
    body = skull
    for _ in range(n_joints):
        if body not in by_child:
            raise ValueError(f"no joint has body {body!r} as its child")
        j = by_child[body]
        parent_body = j.getParentFrame().findBaseFrame().getName()
        lc, lp = BODY_LEVELS.get(body), BODY_LEVELS.get(parent_body)
        if lc is None or lp is None:
            raise ValueError(f"joint {j.getName()}: bodies {body}/{parent_body} are not vertebral levels {sorted(BODY_LEVELS)}")
        chain.append({"label": f"{lc}-{lp}", "joint": j.getName(), "parent_body": parent_body, "child_body": body})
        body = parent_body
    return chain


def _prepare_generic_model(osim, osim_path: Path, log: list[str]) -> tuple[Any, dict[str, Any]]:
    """Load the generic model, disable couplers, identity joint functions."""
    model = osim.Model(str(osim_path))
    info: dict[str, Any] = {"constraints_disabled": [], "functions_replaced": [], "coordinate_defaults": {}}
    cs = model.getConstraintSet()
    for i in range(cs.getSize()):
        c = cs.get(i)
        c.set_isEnforced(False)
        desc = c.getName()
        cc = osim.CoordinateCouplerConstraint.safeDownCast(c)
        if cc is not None:
            indep = cc.getIndependentCoordinateNames()
            ind = [indep.get(k) for k in range(indep.getSize())]
            f = cc.getFunction()
            x = osim.Vector(1, 0.0)
            slope = float(f.calcDerivative(osim.StdVectorInt([0]), x))
            desc = {"name": c.getName(), "dependent": cc.getDependentCoordinateName(), "independent": ind, "slope": slope}
        info["constraints_disabled"].append(desc)
    log.append(f"disabled {cs.getSize()} constraints")
    return model, info


def _identity_rotation_functions(osim, model, chain_joints: Sequence[str], info: dict[str, Any]) -> None:
    """Replace the rotation functions of the chain's CustomJoints by q -> q."""
    for jn in chain_joints:
        cj = osim.CustomJoint.safeDownCast(model.getJointSet().get(jn))
        if cj is None:
            raise ValueError(f"joint {jn} is not a CustomJoint; not supported")
        st = cj.getSpatialTransform()
        for k in range(3):
            ta = st.updTransformAxis(k)
            f = ta.get_function()
            val, slope = _function_value_slope(osim, f, 0.0)
            lin = osim.LinearFunction.safeDownCast(f)
            is_identity = lin is not None and abs(slope - 1.0) < 1e-12 and abs(val) < 1e-12
            if abs(val) > 1e-9:
                raise ValueError(f"{jn} rotation{k + 1}: function value at q=0 is {val}, expected 0")
            # also check linearity over a small range (SimmSpline through 2 points is linear)
            _, s2 = _function_value_slope(osim, f, 0.2)
            if not is_identity:
                coord = ta.get_coordinates(0)
                info["functions_replaced"].append(
                    {"joint": jn, "axis": f"rotation{k + 1}", "coordinate": coord, "type": f.getConcreteClassName(),
                     "slope_at_0": slope, "slope_at_0.2": s2}
                )
                ta.set_function(osim.LinearFunction(1.0, 0.0))


def _add_multifidus(osim, model, multifidus_path: Path, names: Sequence[str], factors: dict[str, float], log: list[str]) -> dict[str, dict[str, Any]]:
    """Add the multifidus slips to ``model`` with un-scaled path points."""
    recs = read_osim_muscles(multifidus_path)
    added = {}
    bodies = {model.getBodySet().get(i).getName() for i in range(model.getBodySet().getSize())}
    for name in names:
        if name not in recs:
            raise KeyError(f"{multifidus_path.name}: muscle {name!r} not found")
        rec = recs[name]
        if rec["unsupported_points"]:
            raise ValueError(f"{multifidus_path.name}: muscle {name} uses {rec['unsupported_points']}; only PathPoints are supported")
        m = osim.Millard2012EquilibriumMuscle(
            name, rec["max_isometric_force"], rec["optimal_fiber_length"], rec["tendon_slack_length"],
            0.0 if math.isnan(rec["pennation_angle_at_optimal"]) else rec["pennation_angle_at_optimal"],
        )
        m.set_ignore_tendon_compliance(True)
        pts = []
        for p in rec["points"]:
            if p.body not in bodies:
                raise KeyError(f"{name}: body {p.body!r} not in the generic model")
            if p.body not in factors:
                raise KeyError(f"{name}: no scale factor for body {p.body!r}")
            loc = p.location / factors[p.body]
            m.addNewPathPoint(p.name, model.getBodySet().get(p.body), _vec3(osim, loc))
            pts.append({"name": p.name, "body": p.body, "scaled_location": p.location.tolist(), "generic_location": loc.tolist()})
        model.addForce(m)
        added[name] = {"points": pts, "max_isometric_force": rec["max_isometric_force"],
                       "optimal_fiber_length_scaled": rec["optimal_fiber_length"],
                       "tendon_slack_length_scaled": rec["tendon_slack_length"]}
    log.append(f"added {len(added)} multifidus muscles from {multifidus_path.name}")
    return added


@dataclass
class Derivation:
    muscles: pd.DataFrame
    moment_arms: pd.DataFrame
    coordinates: pd.DataFrame
    provenance: dict[str, Any]
    comparison: pd.DataFrame | None


def derive_tables(
    osim_path: Path | str,
    multifidus_osim_path: Path | str,
    *,
    b1: pd.DataFrame | None = None,
    osim_source: str | None = None,
    multifidus_source: str | None = None,
    save_osim: Path | str | None = None,
) -> Derivation:
    """Run the derivation and return the tables (nothing is written)."""
    osim = _import_opensim()
    osim_path, multifidus_osim_path = Path(osim_path), Path(multifidus_osim_path)
    log: list[str] = []
    table = thesis_muscle_table()

    # --- scale factors of the multifidus file, verified on shared geometry ---
    scale = estimate_scale_factors(osim_path, multifidus_osim_path)
    factors = {b: v["factor"] for b, v in scale.items()}

    model, info = _prepare_generic_model(osim, osim_path, log)
    model.finalizeConnections()
    chain = _find_joint_chain(model, osim)
    labels = [c["label"] for c in chain]
    if tuple(labels) != JOINTS:
        raise ValueError(f"joint chain {labels} != thesis joints {JOINTS}")
    _identity_rotation_functions(osim, model, [c["joint"] for c in chain] + _caudal_joint(model, osim, chain), info)

    mult_names = [n for n in table.loc[table.source == MULTIFIDUS, "osim_name"]]
    added = _add_multifidus(osim, model, multifidus_osim_path, mult_names, factors, log)
    model.finalizeConnections()

    state = model.initSystem()
    # neutral posture: every intervertebral coordinate (all coordinates of the
    # chain joints and of the C7-T1 joint) is 0; the ground-to-thorax joint
    # keeps its default (it only orients the whole model in ground).
    cset = model.getCoordinateSet()
    neck_joints = {c["joint"] for c in chain} | set(_caudal_joint(model, osim, chain))
    for i in range(cset.getSize()):
        c = cset.get(i)
        info["coordinate_defaults"][c.getName()] = {"joint": c.getJoint().getName(), "default": c.getDefaultValue()}
        if c.getJoint().getName() in neck_joints:
            c.setValue(state, 0.0, False)
    model.assemble(state)
    model.realizePosition(state)

    # multifidus: keep the file's lopt:lts ratio but fit it to the generic path length
    mus_set = model.getMuscles()
    for name in mult_names:
        m = mus_set.get(name)
        rec = added[name]
        L = m.getLength(state)
        tot = rec["optimal_fiber_length_scaled"] + rec["tendon_slack_length_scaled"]
        m.setOptimalFiberLength(L * rec["optimal_fiber_length_scaled"] / tot)
        m.setTendonSlackLength(L * rec["tendon_slack_length_scaled"] / tot)
        rec["generic_neutral_length"] = L
    state = model.initSystem()
    for i in range(cset.getSize()):
        c = cset.get(i)
        if c.getJoint().getName() in neck_joints:
            c.setValue(state, 0.0, False)
    model.assemble(state)
    model.realizePosition(state)

    skull = model.getBodySet().get("skull")

    # --- coordinates: axes, signs, centres ---
    coord_rows = []
    coord_objs = {}
    for c in chain:
        j = model.getJointSet().get(c["joint"])
        cj = osim.CustomJoint.safeDownCast(j)
        st = cj.getSpatialTransform()
        child_origin = _np3(j.getChildFrame().findStationLocationInAnotherFrame(state, osim.Vec3(0, 0, 0), skull))
        parent_origin = _np3(j.getParentFrame().findStationLocationInAnotherFrame(state, osim.Vec3(0, 0, 0), skull))
        if np.max(np.abs(child_origin - parent_origin)) > 1e-9:
            raise ValueError(f"{c['joint']}: parent/child frame origins differ at neutral: {parent_origin} vs {child_origin}")
        seen = set()
        for k in range(3):
            ta = st.getTransformAxis(k)
            axis_parent = _np3(ta.getAxis())
            axis_skull = _np3(j.getParentFrame().expressVectorInAnotherFrame(state, _vec3(osim, axis_parent), skull))
            axis_skull /= np.linalg.norm(axis_skull)
            dots = {a: float(np.dot(axis_skull, THESIS_AXIS_VECTORS[a])) for a in AXES}
            axis_name = max(dots, key=lambda a: abs(dots[a]))
            if abs(dots[axis_name]) < 0.999:
                raise ValueError(f"{c['joint']} rotation{k + 1}: axis {axis_skull} not aligned with a skull-frame axis")
            if axis_name in seen:
                raise ValueError(f"{c['joint']}: two rotations about the {axis_name} axis")
            seen.add(axis_name)
            _, slope = _function_value_slope(osim, ta.get_function(), 0.0)
            sign = int(np.sign(dots[axis_name]) * np.sign(slope))
            coord_name = ta.get_coordinates(0)
            key = f"{c['label']}_{axis_name}"
            coord_objs[key] = (cset.get(coord_name), sign)
            coord_rows.append({
                "coordinate": key, "joint": c["label"], "axis": axis_name, "osim_coordinate": coord_name,
                "sign": sign, "centre_x": child_origin[0], "centre_y": child_origin[1], "centre_z": child_origin[2],
                "axis_x": sign * axis_skull[0], "axis_y": sign * axis_skull[1], "axis_z": sign * axis_skull[2],
                "osim_joint": c["joint"],
            })
    coordinates = pd.DataFrame(coord_rows).set_index("coordinate").loc[list(COORDINATES)].reset_index()

    # --- skull frame sanity: all neck bodies parallel to the skull at neutral ---
    orient = {}
    for b in ["skull", *(f"cerv{i}" for i in range(1, 8)), "spine"]:
        R = model.getBodySet().get(b).findTransformBetween(state, skull).R()
        M = np.array([[R.get(r, cc) for cc in range(3)] for r in range(3)])
        orient[b] = float(np.max(np.abs(M - np.eye(3))))
    ground_R = skull.getTransformInGround(state).R()
    skull_in_ground = np.array([[ground_R.get(r, cc) for cc in range(3)] for r in range(3)])
    markers = {}
    ms = model.getMarkerSet()
    for i in range(ms.getSize()):
        mk = ms.get(i)
        if mk.getName() in ("GLA", "RZF", "RZP", "LZP"):
            markers[mk.getName()] = _np3(mk.getParentFrame().findStationLocationInAnotherFrame(state, mk.get_location(), skull)).round(6).tolist()

    # caudal joint (C7-T1) centre for the record
    extra_centres = {}
    for jn in _caudal_joint(model, osim, chain):
        j = model.getJointSet().get(jn)
        extra_centres[jn] = _np3(j.getChildFrame().findStationLocationInAnotherFrame(state, osim.Vec3(0, 0, 0), skull)).tolist()

    # --- moment arms ---
    R = np.zeros((len(table), len(COORDINATES)))
    fd_err = np.zeros_like(R)
    for i, osim_name in enumerate(table["osim_name"]):
        m = mus_set.get(osim_name)
        for k, key in enumerate(COORDINATES):
            coord, sign = coord_objs[key]
            r = float(m.computeMomentArm(state, coord))
            # finite-difference check of r = -dL/dq
            q0 = coord.getValue(state)
            coord.setValue(state, q0 + FD_STEP, False)
            model.realizePosition(state)
            lp = m.getLength(state)
            coord.setValue(state, q0 - FD_STEP, False)
            model.realizePosition(state)
            lm = m.getLength(state)
            coord.setValue(state, q0, False)
            model.realizePosition(state)
            r_fd = -(lp - lm) / (2 * FD_STEP)
            fd_err[i, k] = r - r_fd
            r = 0.0 if abs(r) < ZERO_TOL else r
            R[i, k] = sign * r
    moment_arms = pd.concat([table[["index", "name"]], pd.DataFrame(R, columns=list(COORDINATES))], axis=1)

    # --- strengths ---
    generic_recs = read_osim_muscles(osim_path)
    mult_recs = read_osim_muscles(multifidus_osim_path)
    musc = table.copy()
    musc["source_file"] = np.where(musc.source == MULTIFIDUS, multifidus_osim_path.name, osim_path.name)
    f_src, f_gen, f_mult = [], [], []
    for _, r in musc.iterrows():
        g = generic_recs.get(r.osim_name)
        mm = mult_recs.get(r.osim_name)
        f_gen.append(g["max_isometric_force"] if g else float("nan"))
        f_mult.append(mm["max_isometric_force"] if mm else float("nan"))
        f_src.append(f_mult[-1] if r.source == MULTIFIDUS else f_gen[-1])
    musc["osim_max_isometric_force_N"] = f_src
    musc["mortensen2014_max_isometric_force_N"] = f_gen
    musc["neckshoulder_max_isometric_force_N"] = f_mult
    with np.errstate(invalid="ignore", divide="ignore"):
        musc["mortensen_over_neckshoulder"] = np.round(np.asarray(f_gen) / np.asarray(f_mult), 4)
    musc = musc[["index", "name", "osim_name", "source_file", "side", "osim_max_isometric_force_N",
                 "mortensen2014_max_isometric_force_N", "neckshoulder_max_isometric_force_N",
                 "mortensen_over_neckshoulder"]]

    # --- checks ---
    symmetry = _symmetry_error(moment_arms)
    comparison = compare_with_b1(moment_arms, b1) if b1 is not None and len(b1) else None

    if save_osim:
        model.printToXML(str(save_osim))
        log.append(f"wrote derived model to {save_osim}")

    provenance: dict[str, Any] = {
        "inputs": {
            "osim": {**_source_info(osim_path, osim_source), "role": "generic neck model (muscles 1-72, joints)"},
            "multifidus_osim": {**_source_info(multifidus_osim_path, multifidus_source),
                                "role": "multifidus path points (muscles 73-96), un-scaled"},
        },
        "opensim_version": str(osim.__version__),
        "python_version": sys.version.split()[0],
        "date_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "sign_convention": SIGN_CONVENTION,
        "coordinate_order": list(COORDINATES),
        "joint_chain": chain,
        "caudal_joint_centres_skull_frame_m": extra_centres,
        "neutral_posture": "all coordinates of the 7 thesis joints and of the C7-T1 joint set to 0 "
                            "(file defaults are within 2e-6 rad of 0); ground-to-thorax joint at file default",
        "constraints_disabled": info["constraints_disabled"],
        "functions_replaced_by_identity": info["functions_replaced"],
        "coordinate_defaults_in_file": info["coordinate_defaults"],
        "multifidus_scale_factors": {b: scale[b] for b in sorted(scale)},
        "multifidus_scale_factors_used": {b: factors[b] for b in sorted({p["body"] for a in added.values() for p in a["points"]})},
        "multifidus_added": added,
        "checks": {
            "max_abs_computeMomentArm_minus_finite_difference_m": float(np.max(np.abs(fd_err))),
            "finite_difference_step_rad": FD_STEP,
            "max_abs_left_right_mirror_error_m": symmetry,
            "max_body_orientation_deviation_from_skull_at_neutral": orient,
            "skull_rotation_in_ground_at_neutral": skull_in_ground.round(6).tolist(),
            "skull_markers_skull_frame_m": markers,
        },
        "log": log,
    }
    return Derivation(musc, moment_arms, coordinates, provenance, comparison)


def _caudal_joint(model, osim, chain) -> list[str]:
    """The joint below the last chain joint (C7-T1), if it is a vertebral joint."""
    last_parent = chain[-1]["parent_body"]
    js = model.getJointSet()
    for i in range(js.getSize()):
        j = js.get(i)
        if j.getChildFrame().findBaseFrame().getName() == last_parent:
            return [j.getName()]
    return []


def _symmetry_error(moment_arms: pd.DataFrame) -> float:
    """Max |mirror error| over R/L pairs: pitch equal, roll and yaw opposite."""
    vals = moment_arms[list(COORDINATES)].to_numpy()
    sgn = np.array([1.0 if c.endswith("pitch") else -1.0 for c in COORDINATES])
    return float(np.max(np.abs(vals[0::2] - sgn * vals[1::2])))


# --------------------------------------------------------------------------- #
# Writing
# --------------------------------------------------------------------------- #


def _header(prov: dict[str, Any], what: str, extra: Sequence[str] = ()) -> str:
    gi, mi = prov["inputs"]["osim"], prov["inputs"]["multifidus_osim"]
    lines = [
        f"{what}",
        "derived by: python -m neckstrength.derive_opensim (see docs/model_derivation.md)",
        f"source: {gi['file']} from {gi.get('repository')} commit {gi.get('commit')} ({gi.get('path', '')}), sha256 {gi['sha256']}",
        f"multifidus source: {mi['file']} from {mi.get('repository')} commit {mi.get('commit')} ({mi.get('path', '')}), sha256 {mi['sha256']}",
        f"opensim {prov['opensim_version']}; date {prov['date_utc']}",
        f"sign convention: {prov['sign_convention']}",
        *extra,
    ]
    return "".join(f"# {ln}\n" for ln in lines)


def write_tables(d: Derivation, out_dir: Path | str, command_line: str) -> list[Path]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    prov = dict(d.provenance)
    prov["command_line"] = command_line
    written = []

    def _write(df: pd.DataFrame, name: str, what: str, extra: Sequence[str] = (), fmt: str = "%.6f") -> None:
        p = out / name
        with open(p, "w", encoding="utf-8", newline="") as fh:
            fh.write(_header(prov, what, extra))
            df.to_csv(fh, index=False, float_format=fmt, lineterminator="\n")
        written.append(p)

    _write(d.muscles, MUSCLES_CSV, "Full neck model: the 96 muscle elements in thesis Table B.1 order.", (
        "osim_max_isometric_force_N: max_isometric_force in source_file (rows 1-72: Mortensen2014 file, rows 73-96: ModelOfNeckAndShoulder)",
        "mortensen2014_max_isometric_force_N: Mortensen et al. 2018 convention (generic x1.4 for extensors, x2.7 for flexors/hyoids)",
        "neckshoulder_max_isometric_force_N: unscaled convention (ModelOfNeckAndShoulder); thesis Table B.1 strengths win where printed",
        "side: R for names without suffix, L for names ending in ' L' / '_L'",
    ), fmt="%.4f")
    _write(d.moment_arms, MOMENT_ARMS_CSV, "Full neck model: moment arms (m) of the 96 muscles about the 21 joint coordinates, neutral posture.", (
        "rows: thesis muscle index 1..96; columns: joint-major, C0-C1 pitch = row 1 of R, C6-C7 pitch = row 19",
        "0 means the muscle does not span the joint",
    ), fmt="%.6f")
    _write(d.coordinates, COORDINATES_CSV, "Full neck model: joint centres and rotation axes in the skull frame (m), neutral posture.", (
        "sign: factor applied to the OpenSim moment arm about osim_coordinate; axis_*: positive thesis rotation axis (unit vector)",
    ), fmt="%.6f")
    if d.comparison is not None:
        _write(d.comparison, COMPARISON_CSV, "Derived moment arms vs. every nonblank moment arm printed in thesis Table B.1.", (
            f"B.1 source: {prov.get('b1_source', 'unknown')}",
            "diff_m = derived_m - b1_m; rel_diff = diff_m / |b1_m|",
        ), fmt="%.6f")
    p = out / PROVENANCE_JSON
    p.write_text(json.dumps(prov, indent=2, sort_keys=False, default=_json_default) + "\n", encoding="utf-8")
    written.append(p)
    return written


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(type(o))


def summarize_comparison(cmp_: pd.DataFrame, min_abs_b1: float = 0.005) -> dict[str, Any]:
    """Summary statistics of a B.1 comparison table."""
    big = cmp_[cmp_["b1_m"].abs() >= min_abs_b1]
    return {
        "n": int(len(cmp_)),
        "median_abs_diff_m": float(cmp_["diff_m"].abs().median()),
        "max_abs_diff_m": float(cmp_["diff_m"].abs().max()),
        f"n_with_abs_b1_ge_{min_abs_b1}": int(len(big)),
        "median_abs_rel_diff": float(big["rel_diff"].abs().median()),
        "max_abs_rel_diff": float(big["rel_diff"].abs().max()),
        "median_abs_rel_diff_all": float(cmp_["rel_diff"].abs().median()),
        "sign_disagreements": int(np.sum(np.sign(cmp_["b1_m"]) != np.sign(cmp_["derived_m"]))),
    }


def derive_full_model(
    osim_path: Path | str,
    multifidus_osim_path: Path | str,
    out_dir: Path | str,
    *,
    b1_table: Path | str | None = None,
    seed: Path | str | None = None,
    osim_source: str | None = None,
    multifidus_source: str | None = None,
    save_osim: Path | str | None = None,
    command_line: str | None = None,
) -> Derivation:
    """Derive the full-model tables and write them to ``out_dir``.

    ``b1_table`` (project CSV, preferred) or ``seed`` (thesis text) provide the
    Table B.1 moment arms for ``momentarm_vs_B1.csv``; without either, the
    comparison is skipped.
    """
    b1 = None
    b1_source = "none"
    if b1_table is not None and Path(b1_table).exists():
        b1 = read_b1_table(Path(b1_table))
        b1_source = f"{b1_table} (sha256 {sha256_file(Path(b1_table))})"
    elif seed is not None:
        b1 = parse_b1_from_seed(Path(seed))
        b1_source = f"parsed from seed text {Path(seed).name} (sha256 {sha256_file(Path(seed))}), Table B.1"
    d = derive_tables(osim_path, multifidus_osim_path, b1=b1, osim_source=osim_source,
                      multifidus_source=multifidus_source, save_osim=save_osim)
    d.provenance["b1_source"] = b1_source
    if d.comparison is not None:
        d.provenance["b1_comparison_summary"] = summarize_comparison(d.comparison)
    if command_line is None:
        command_line = "derive_full_model(" + ", ".join(map(str, (osim_path, multifidus_osim_path, out_dir))) + ")"
    write_tables(d, out_dir, command_line)
    return d


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m neckstrength.derive_opensim", description=__doc__.split("\n\n")[0])
    ap.add_argument("--osim", required=True, type=Path, help="generic model, e.g. Mortensen2014_rigidTorso.osim")
    ap.add_argument("--multifidus-osim", required=True, type=Path, help="model with the multifidus slips, e.g. ModelOfNeckAndShoulder.osim")
    ap.add_argument("--out", required=True, type=Path, help="output directory, e.g. data/model")
    ap.add_argument("--b1-table", type=Path, default=Path("data/thesis/table_B1_muscles.csv"),
                    help="project copy of thesis Table B.1 (used if it exists; default: %(default)s)")
    ap.add_argument("--seed", type=Path, default=None, help="thesis text to parse Table B.1 from if --b1-table is absent")
    ap.add_argument("--osim-source", default=None, help="'owner/repo@commit' provenance for --osim if its sha256 is not known")
    ap.add_argument("--multifidus-source", default=None, help="'owner/repo@commit' provenance for --multifidus-osim")
    ap.add_argument("--save-osim", type=Path, default=None, help="also write the derived OpenSim model (keep it outside the project)")
    args = ap.parse_args(argv)
    argv_list = list(sys.argv[1:] if argv is None else argv)
    cmd = "python -m neckstrength.derive_opensim " + " ".join(argv_list)
    d = derive_full_model(args.osim, args.multifidus_osim, args.out, b1_table=args.b1_table, seed=args.seed,
                          osim_source=args.osim_source, multifidus_source=args.multifidus_source,
                          save_osim=args.save_osim, command_line=cmd)
    chk = d.provenance["checks"]
    print(f"wrote {MUSCLES_CSV}, {MOMENT_ARMS_CSV}, {COORDINATES_CSV}, {PROVENANCE_JSON}"
          + (f", {COMPARISON_CSV}" if d.comparison is not None else "") + f" to {args.out}")
    print(f"max |computeMomentArm - finite difference| = {chk['max_abs_computeMomentArm_minus_finite_difference_m']:.2e} m; "
          f"max L/R mirror error = {chk['max_abs_left_right_mirror_error_m']:.2e} m")
    if d.comparison is not None:
        print("B.1 comparison:", json.dumps(d.provenance["b1_comparison_summary"]))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
