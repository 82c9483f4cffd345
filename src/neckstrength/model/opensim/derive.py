"""Derive the full 96-muscle, 21-DOF neck model tables from OpenSim model files.

This is a one-off *derivation* command, not part of the default pipeline.  It
needs the optional dependency ``opensim`` (``pip install neckstrength[opensim]``)
and two reference model files that are **not** part of the project (see
``docs/model_derivation.md``):

* ``Mortensen2014_rigidTorso.osim`` -- the Vasavada/Mortensen head-neck model
  with hyoid muscles (bodies, joints, shoulder girdle and 72 of the 96 muscles);
* ``ModelOfNeckAndShoulder.osim`` -- a uniformly scaled copy of the same neck
  that also contains the cervical multifidus slips (``supmult-*``,
  ``deepmult-*``; thesis rows 73-96).

Usage::

    python -m neckstrength.model.opensim.derive \\
        --osim path/to/Mortensen2014_rigidTorso.osim \\
        --multifidus-osim path/to/ModelOfNeckAndShoulder.osim \\
        --out data/model [--thesis-dir data/thesis] [--seed path/to/thesis.txt]

Two geometries are derived (details and evidence in ``docs/model_derivation.md``):

``generic`` (primary, ``full_model_*.csv``)
    the *unscaled* generic neck geometry that thesis Table B.1 was computed on.
    Both files are scaled copies of it: each body's scale follows from the ratio
    of the two files' shared path points and joint offsets and the files' own
    mesh ``scale_factors`` (ModelOfNeckAndShoulder: 0.865351 for every neck
    body).  The Mortensen model is rescaled body by body with
    ``Model.scale``; the suprahyoid points that the two files disagree on and
    the multifidus slips are taken from ModelOfNeckAndShoulder divided by its
    mesh scale.  This reproduces every nonblank Table B.1 moment arm within
    its print rounding.
``mortensen2014`` (``full_model_mortensen2014_*.csv``)
    ``Mortensen2014_rigidTorso.osim`` as it is, with the multifidus slips
    brought to its (cervical x0.792, skull x0.914, thorax x0.971) scale.

In both, the coordinate coupler constraints are disabled, the rotation
functions of the intervertebral ``CustomJoint`` s are replaced by the identity
(so that each joint coordinate is the physical rotation angle about its
axis), the posture is neutral (all intervertebral angles 0), and moment arms are
``Muscle.computeMomentArm`` (checked against a finite difference of the
muscle length) converted to the thesis sign convention (pitch + extension,
roll + right side-bend, yaw + left rotation).

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import pandas as pd

GENERIC = "generic"


MULTIFIDUS = "multifidus"


GEOMETRY_GENERIC = "generic"


GEOMETRY_MORTENSEN = "mortensen2014"


#: The 48 right-side muscles in thesis Table B.1 order (row 2k-1 is the right
#: muscle, row 2k its left partner with suffix " L").  Each entry:
#: (B.1 spelling, OpenSim name of the right muscle, which input file).
#: Rows 1-14, 31-46 and 63-96 are printed in the seed text; rows 15-30 and
#: 47-62 are missing there and follow a public MATLAB enumeration of the same
#: 96 muscles (``classdef Muscles < uint8``, "96 muscles; multif: 73-96") that
#: reproduces every printed row, including the hyoid order that differs from the
#: model file (see docs/model_derivation.md).
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
    "moment arm r = -dL/dq (m per rad) about each joint axis; pitch (+) extension, "
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
        "licence": "none stated (used only to derive geometry)",
    },
}


MUSCLES_CSV = "full_model_muscles.csv"


MOMENT_ARMS_CSV = "full_model_moment_arms.csv"


COORDINATES_CSV = "full_model_coordinates.csv"


PROVENANCE_JSON = "full_model_provenance.json"


COMPARISON_CSV = "momentarm_vs_B1.csv"


MORTENSEN_MOMENT_ARMS_CSV = "full_model_mortensen2014_moment_arms.csv"


MORTENSEN_COORDINATES_CSV = "full_model_mortensen2014_coordinates.csv"


B3_STRENGTHS_CSV = "b3_implied_strengths.csv"


#: Central finite-difference step (rad) used to cross-check computeMomentArm.
FD_STEP = 1e-6


#: Moment arms with |r| below this (m) are written as exactly 0 (the muscle does
#: not span the joint; OpenSim returns ~1e-17 there).
ZERO_TOL = 1e-10


#: Two path-point sets are "the same" if every point agrees within this (m).
SAME_POINT_TOL = 1e-5


#: Relative tolerance for a per-body scale ratio to count as uniform.
UNIFORM_TOL = 1e-4


def _import_opensim():
    """Import opensim lazily, with an actionable error if it is missing."""
    try:
        import opensim  # type: ignore[import-not-found]
    except ImportError as exc:  # pragma: no cover - depends on environment
        raise ImportError(
            "neckstrength.model.opensim.derive needs the OpenSim Python package. "
            "Install it with `pip install neckstrength[opensim]` "
            "(OpenSim 4.6 wheel, CPython 3.11, x86-64)."
        ) from exc
    try:
        opensim.Logger.setLevelString("error")  # silence missing-.vtp warnings
    except Exception:  # pragma: no cover
        pass
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
    """Parse the muscles of an .osim file with ElementTree (no OpenSim needed).

    Returns ``{name: {"type", "points": [_PathPoint], "unsupported_points",
    "max_isometric_force", "optimal_fiber_length", "tendon_slack_length",
    "pennation_angle_at_optimal"}}``.  Only plain ``PathPoint`` s are read;
    muscles with conditional/moving points list those tags in
    ``"unsupported_points"`` (none of the neck muscles has any).
    """
    root = ET.parse(path).getroot()
    out: dict[str, dict[str, Any]] = {}
    for el in root.iter():
        if not el.tag.endswith("Muscle") or el.get("name") is None:
            continue
        unsupported = sorted({pp.tag for pp in el.iter() if pp.tag in ("ConditionalPathPoint", "MovingPathPoint")})
        pts = []
        for pp in el.iter():
            if pp.tag != "PathPoint":
                continue
            sock, loc = pp.find("socket_parent_frame"), pp.find("location")
            if sock is None or loc is None or sock.text is None or loc.text is None:
                raise ValueError(f"{path.name}: path point {pp.get('name')} lacks frame/location")
            pts.append(_PathPoint(pp.get("name", ""), sock.text.strip().split("/")[-1],
                                  np.array([float(v) for v in loc.text.split()])))
        rec: dict[str, Any] = {"type": el.tag, "points": pts, "unsupported_points": unsupported}
        for prop in ("max_isometric_force", "optimal_fiber_length", "tendon_slack_length", "pennation_angle_at_optimal"):
            p = el.find(prop)
            rec[prop] = float(p.text) if p is not None and p.text else float("nan")
        out[el.get("name")] = rec
    return out


def read_osim_joint_offsets(path: Path) -> dict[tuple[str, str], tuple[str, np.ndarray]]:
    """Joint offset frames: ``{(joint, frame): (parent body, translation)}``."""
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
            out[(j.get("name"), po.get("name"))] = (sp.text.strip().split("/")[-1],
                                                    np.array([float(v) for v in tr.text.split()]))
    return out


def read_mesh_scale_factors(path: Path) -> dict[str, float]:
    """Uniform mesh ``scale_factors`` of each body (the scale the file was made at).

    Bodies without a mesh or with non-uniform/inconsistent mesh scales are omitted.
    """
    root = ET.parse(path).getroot()
    out = {}
    for body in root.iter("Body"):
        vals = set()
        for mesh in body.iter("Mesh"):
            sf = mesh.find("scale_factors")
            if sf is not None and sf.text:
                v = [float(t) for t in sf.text.split()]
                vals.add(tuple(round(x, 12) for x in v))
        if len(vals) == 1:
            v = next(iter(vals))
            if max(v) - min(v) < 1e-12:
                out[body.get("name")] = v[0]
    return out


def estimate_scale_factors(generic_path: Path, scaled_path: Path, min_abs: float = 1e-3) -> dict[str, dict[str, float]]:
    """Per-body uniform scale factors of ``scaled_path`` relative to ``generic_path``.

    Uses every path point of every muscle present in both files with the same
    body and point count, and every joint offset frame present in both, taking
    coordinate ratios where the first file's coordinate exceeds ``min_abs`` (m).
    Returns ``{body: {"factor": median, "n": count, "n_outliers": ratios more
    than UNIFORM_TOL (relative) from the median, "max_rel_spread_inliers"}}``.
    The outliers are points that the second file moved (suprahyoid points on
    cerv1), not non-uniform scaling.
    """
    ga, sa = read_osim_muscles(generic_path), read_osim_muscles(scaled_path)
    ratios: dict[str, list[float]] = defaultdict(list)
    for name, rec in ga.items():
        other = sa.get(name)
        if (other is None or len(other["points"]) != len(rec["points"])
                or rec["unsupported_points"] or other["unsupported_points"]):
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
            "n_outliers": int(np.sum(rel > UNIFORM_TOL)),
            "max_rel_spread_inliers": float(rel[rel <= UNIFORM_TOL].max()),
        }
    return out


def generic_body_factors(osim_path: Path, multifidus_path: Path) -> dict[str, dict[str, Any]]:
    """Scale factor of each body of ``osim_path`` that gives the unscaled generic geometry.

    Rule: where the second file has the body, ``factor = (second/first point
    ratio) / (second file's mesh scale)``, i.e. the second file divided by the
    scale it was made at; other bodies (ribcage and the right shoulder girdle,
    which the second file replaces by a shoulder model) use ``1 / (first file's
    mesh scale)``.  Both rules are reported where both apply: they agree for
    the skull, the thorax and the left shoulder girdle but not for the cervical
    vertebrae (documented in docs/model_derivation.md).
    """
    ratio = estimate_scale_factors(osim_path, multifidus_path)
    mesh_a, mesh_b = read_mesh_scale_factors(osim_path), read_mesh_scale_factors(multifidus_path)
    out = {}
    for body, m_a in sorted(mesh_a.items()):
        rec: dict[str, Any] = {"mesh_scale_first": m_a, "inverse_mesh_scale_first": 1.0 / m_a}
        if body in ratio and body in mesh_b:
            rec.update(point_ratio_second_over_first=ratio[body]["factor"], mesh_scale_second=mesh_b[body],
                       n_ratios=ratio[body]["n"], n_outlier_ratios=ratio[body]["n_outliers"])
            rec["factor"] = ratio[body]["factor"] / mesh_b[body]
            rec["rule"] = "second-file point ratio / second-file mesh scale"
            rec["rules_agree"] = bool(abs(rec["factor"] * m_a - 1.0) < 1e-4)
        else:
            rec["factor"] = 1.0 / m_a
            rec["rule"] = "1 / first-file mesh scale"
        out[body] = rec
    return out


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
    """Read the project's B.1 table (``index,name,strength_N,<joint>_<axis>...``,
    ``#`` comments) into the long format of :func:`parse_b1_from_seed`."""
    wide = pd.read_csv(csv_path, comment="#")
    rows = []
    for _, r in wide.iterrows():
        for col in wide.columns:
            joint, _, axis = str(col).rpartition("_")
            if joint in JOINTS and axis in AXES and pd.notna(r[col]):
                strength = float(r["strength_N"]) if "strength_N" in wide.columns and pd.notna(r["strength_N"]) else float("nan")
                rows.append((int(r["index"]), str(r["name"]), strength, joint, axis, float(r[col])))
    return pd.DataFrame(rows, columns=["index", "name", "strength_N", "joint", "axis", "b1_m"])


def parse_b1_strengths_from_seed(seed_path: Path) -> pd.DataFrame:
    """Strength column of Table B.1 (every printed row, also rows without moment arms)."""
    text = Path(seed_path).read_text(encoding="utf-8")
    block = text[text.find("Table B.1."):text.find("Table B.2.")]
    rows = []
    for line in block.splitlines():
        m = re.match(r"^(\d+) ([^\t]+)\t([^\t]*)", line)
        if m and m.group(3).strip():
            rows.append((int(m.group(1)), m.group(2).strip(), float(m.group(3))))
    return pd.DataFrame(rows, columns=["index", "name", "strength_N"])


def _norm_name(name: str) -> str:
    """Normalise thesis muscle spellings across Tables B.1/B.2/B.4 ('skl6' = 'sklc6')."""
    n = re.sub(r"\s+", " ", name.strip().lower())
    return re.sub(r"skl(\d)", r"sklc\1", n)


def parse_b2_groups(seed_path: Path) -> dict[str, list[str]]:
    """Muscle groups of the s3m24 model (Table B.2): ``{group: [right-side names]}``."""
    text = Path(seed_path).read_text(encoding="utf-8")
    block = text[text.find("Table B.2."):text.find("Table B.3.")]
    groups: dict[str, list[str]] = {}
    header: list[str] | None = None
    for line in block.splitlines()[1:]:
        if not line.strip():
            continue
        cells = line.split("\t")
        if all(c.strip() and " " not in c.strip() for c in cells) and len(cells) >= 3:
            header = [c.strip() for c in cells]
            for g in header:
                groups.setdefault(g, [])
            continue
        if header is None:
            continue
        for g, c in zip(header, cells):
            if c.strip():
                groups[g].append(c.strip())
    return groups


def parse_b3_groups(seed_path: Path) -> dict[str, dict[str, Any]]:
    """Right-side group rows of Table B.3: ``{group: {"strength_N", <joint>_<axis>: value}}``.

    B.3's lowest joint column ("T1-C7") is the joint B.1 calls C6-C7."""
    text = Path(seed_path).read_text(encoding="utf-8")
    block = text[text.find("Table B.3."):text.find("Table B.4.")]
    out: dict[str, dict[str, Any]] = {}
    for line in block.splitlines():
        m = re.match(r"^(\d+)[ \t]([^\t]+)-R\t(.*)$", line)
        if not m:
            continue
        cells = m.group(3).split("\t")
        rec: dict[str, Any] = {"strength_N": float(cells[0])}
        rest = cells[1:]
        if any(len(c.split()) == 3 for c in rest):  # grouped format: one cell per joint
            groups = (rest + ["", "", ""])[:3]
            values = [v for c in groups for v in (c.split() if c.strip() else ["", "", ""])]
        else:
            values = (rest + [""] * 9)[:9]
        for g, joint in enumerate(B1_JOINT_COLUMNS):
            for a, axis in enumerate(AXES):
                v = values[3 * g + a].strip()
                if v:
                    rec[f"{joint}_{axis}"] = float(v)
        out[m.group(2).strip()] = rec
    return out


def read_b2_table(csv_path: Path) -> dict[str, list[str]]:
    """Groups from the project's ``table_B2_groups_s3m24.csv`` (``group,muscle[,name_normalized]``)."""
    df = pd.read_csv(csv_path, comment="#")
    col = "name_normalized" if "name_normalized" in df.columns else "muscle"
    groups: dict[str, list[str]] = {}
    for g, n in zip(df["group"], df[col]):
        groups.setdefault(str(g), []).append(str(n))
    return groups


def read_b3_table(csv_path: Path) -> dict[str, dict[str, Any]]:
    """Right-side rows of the project's ``table_B3_params_s3m24.csv``, as :func:`parse_b3_groups`."""
    df = pd.read_csv(csv_path, comment="#")
    out: dict[str, dict[str, Any]] = {}
    for _, r in df.iterrows():
        g = str(r["group"])
        if not g.endswith("-R"):
            continue
        rec: dict[str, Any] = {"strength_N": float(r["strength_N"])}
        for c in df.columns:
            joint, _, axis = str(c).rpartition("_")
            if joint in JOINTS and axis in AXES and pd.notna(r[c]):
                rec[c] = float(r[c])
        out[g[:-2]] = rec
    return out


def infer_strengths_from_b3(moment_arms: pd.DataFrame, b1_strengths: pd.DataFrame,
                            groups: dict[str, list[str]], b3: dict[str, dict[str, Any]],
                            model_strengths: pd.DataFrame | None = None) -> pd.DataFrame:
    """Strengths of the muscles without a printed B.1 strength, from Table B.3.

    B.3 gives, per s3m24 group g, the strength ``F_g = ||F_i||`` and the moment
    arms ``R_g = sum_i F_i r_i / F_g`` (thesis Sec. 4.2.1.3).  With the derived
    ``r_i`` and the printed B.1 strengths, the unknown ``F_i`` of each group
    (1-3 per group) are fitted by least squares to those 4-10 equations,
    each weighted by its print-rounding standard deviation (half a unit of the
    last printed digit / sqrt(3)).  Residuals are reported in those units: all
    within ~1.5 means the derived geometry and the inferred strengths reproduce
    B.3.  Right-side rows only (the left ones are mirror images).
    """
    from scipy.optimize import least_squares

    wide = moment_arms.set_index("name")
    known = {_norm_name(n): float(f) for n, f in zip(b1_strengths["name"], b1_strengths["strength_N"])}
    names_by_norm = {_norm_name(n): n for n in wide.index}
    sd_r, sd_f = 0.5e-4 / math.sqrt(3), 0.05 / math.sqrt(3)
    rows = []
    for g, members in groups.items():
        if g not in b3:
            continue
        full = [names_by_norm[_norm_name(m)] for m in members]
        unknown = [n for n in full if _norm_name(n) not in known]
        if not unknown:
            continue
        cols = [c for c in b3[g] if c != "strength_N"]
        r = wide.loc[full, cols].to_numpy(dtype=float)
        target = np.array([b3[g][c] for c in cols])
        fg = b3[g]["strength_N"]

        def resid(x, full=full, unknown=unknown, r=r, target=target, fg=fg):
            F = np.array([x[unknown.index(n)] if n in unknown else known[_norm_name(n)] for n in full])
            return np.concatenate([((F[:, None] * r).sum(0) / fg - target) / sd_r, [(np.linalg.norm(F) - fg) / sd_f]])

        x0 = np.full(len(unknown), fg / math.sqrt(len(full)))
        sol = least_squares(resid, x0, bounds=(0, np.inf))
        J = sol.jac
        cov = np.linalg.pinv(J.T @ J)
        for k, n in enumerate(unknown):
            idx = int(wide.loc[n, "index"])
            rows.append({
                "index": idx, "name": n, "b3_group": g, "implied_strength_N": float(sol.x[k]),
                "se_N": float(math.sqrt(max(cov[k, k], 0.0))), "n_equations": int(len(cols) + 1),
                "max_abs_residual_rounding_sd": float(np.max(np.abs(sol.fun))),
                "model_unscaled_N": float(model_strengths.set_index("name").loc[n, "osim_max_isometric_force_N"])
                if model_strengths is not None else float("nan"),
            })
    out = pd.DataFrame(rows)
    if len(out):
        left = out.copy()
        left["index"] = left["index"] + 1
        left["name"] = left["name"] + " L"
        out = pd.concat([out, left]).sort_values("index").reset_index(drop=True)
    return out


#: Table B.1 cells that the seed text prints in the wrong place, mapped to the
#: (row, joint) whose derived moment arms they equal: rows 11/12 (sternohyoid)
#: print the C4-C5 triple under C0-C1 (sternohyoid runs from the hyoid, carried
#: by C3, to the sternum and does not span C0-C1; its C6-C7 triple is missing);
#: rows 35/36 (long col c1thx, which ends at C1) carry the C0-C1 triple of rows
#: 33/34 (long cap sklc4, printed blank).
B1_MISPLACED: dict[tuple[int, str], tuple[int, str]] = {
    (11, "C0-C1"): (11, "C4-C5"),
    (12, "C0-C1"): (12, "C4-C5"),
    (35, "C0-C1"): (33, "C0-C1"),
    (36, "C0-C1"): (34, "C0-C1"),
}


def compare_with_b1(moment_arms: pd.DataFrame, b1_long: pd.DataFrame,
                    extra: dict[str, pd.DataFrame] | None = None) -> pd.DataFrame:
    """Compare derived moment arms (wide: index,name,<coords>) with B.1 (long).

    ``extra`` adds one column per named alternative table (its moment arm).
    Cells listed in :data:`B1_MISPLACED` get a ``note`` and, in
    ``reinterpreted_derived_m``, the derived value they actually equal.
    """
    wide = moment_arms.set_index("index")
    extra = extra or {}
    out = []
    for _, r in b1_long.iterrows():
        idx, col, b1v = int(r["index"]), f"{r['joint']}_{r['axis']}", float(r["b1_m"])
        derived = float(wide.loc[idx, col])
        diff = derived - b1v
        rel = diff / abs(b1v) if b1v != 0 else float("nan")
        row = [idx, wide.loc[idx, "name"], r["joint"], r["axis"], b1v, derived, diff, rel]
        row += [float(t.set_index("index").loc[idx, col]) for t in extra.values()]
        key = (idx, str(r["joint"]))
        if key in B1_MISPLACED:
            ridx, rjoint = B1_MISPLACED[key]
            row += [f"misplaced in seed text: equals derived {wide.loc[ridx, 'name']} {rjoint} {r['axis']}",
                    float(wide.loc[ridx, f"{rjoint}_{r['axis']}"])]
        else:
            row += ["", float("nan")]
        out.append(row)
    cmp_ = pd.DataFrame(out, columns=["index", "name", "joint", "axis", "b1_m", "derived_m", "diff_m", "rel_diff", *extra,
                                      "note", "reinterpreted_derived_m"])
    cmp_["_j"] = cmp_["joint"].map({j: i for i, j in enumerate(B1_JOINT_COLUMNS)})
    cmp_["_a"] = cmp_["axis"].map({a: i for i, a in enumerate(AXES)})
    return cmp_.sort_values(["index", "_j", "_a"]).drop(columns=["_j", "_a"]).reset_index(drop=True)


def summarize_comparison(cmp_: pd.DataFrame, column: str = "derived_m", min_abs_b1: float = 0.005) -> dict[str, Any]:
    """Summary statistics of a B.1 comparison (relative statistics over |B.1| >= ``min_abs_b1``)."""
    c = cmp_
    diff = c[column] - c["b1_m"]
    rel = diff / c["b1_m"].abs()
    big = c["b1_m"].abs() >= min_abs_b1
    return {
        "n": int(len(c)),
        "median_abs_diff_m": float(diff.abs().median()),
        "max_abs_diff_m": float(diff.abs().max()),
        f"n_with_abs_b1_ge_{min_abs_b1}": int(big.sum()),
        "median_abs_rel_diff": float(rel[big].abs().median()),
        "max_abs_rel_diff": float(rel[big].abs().max()),
        "sign_disagreements": int(np.sum(np.sign(c["b1_m"]) != np.sign(c[column]))),
    }


def _vec3(osim, v: Iterable[float]):
    x, y, z = (float(t) for t in v)
    return osim.Vec3(x, y, z)


def _np3(v) -> np.ndarray:
    return np.array([v.get(0), v.get(1), v.get(2)], dtype=float)


def _rot(R) -> np.ndarray:
    return np.array([[R.get(r, c) for c in range(3)] for r in range(3)])


def _function_value_slope(osim, f, q: float = 0.0) -> tuple[float, float]:
    x = osim.Vector(1, q)
    return float(f.calcValue(x)), float(f.calcDerivative(osim.StdVectorInt([0]), x))


def _joint_by_child(model) -> dict[str, Any]:
    js = model.getJointSet()
    return {js.get(i).getChildFrame().findBaseFrame().getName(): js.get(i) for i in range(js.getSize())}


def _find_joint_chain(model, skull: str = "skull", n_joints: int = 8) -> list[dict[str, Any]]:
    """Walk caudally from the skull: at each step the joint whose child is the
    current body.  Returns ``n_joints`` dicts {label, joint, parent_body,
    child_body}, cranial first (C0-C1, ..., C6-C7, C7-T1)."""
    by_child = _joint_by_child(model)
    chain = []
    body = skull
    for _ in range(n_joints):
        if body not in by_child:
            raise ValueError(f"no joint has body {body!r} as its child")
        j = by_child[body]
        parent_body = j.getParentFrame().findBaseFrame().getName()
        lc, lp = BODY_LEVELS.get(body), BODY_LEVELS.get(parent_body)
        if lc is None or lp is None:
            raise ValueError(f"joint {j.getName()}: bodies {body}/{parent_body} are not among {sorted(BODY_LEVELS)}")
        chain.append({"label": f"{lc}-{lp}", "joint": j.getName(), "parent_body": parent_body, "child_body": body})
        body = parent_body
    return chain


def _disable_constraints(osim, model) -> list[dict[str, Any]]:
    out = []
    cs = model.getConstraintSet()
    for i in range(cs.getSize()):
        c = cs.get(i)
        c.set_isEnforced(False)
        cc = osim.CoordinateCouplerConstraint.safeDownCast(c)
        if cc is None:
            out.append({"name": c.getName(), "type": c.getConcreteClassName()})
            continue
        indep = cc.getIndependentCoordinateNames()
        _, slope = _function_value_slope(osim, cc.getFunction(), 0.0)
        out.append({"name": c.getName(), "type": "CoordinateCouplerConstraint",
                    "dependent": cc.getDependentCoordinateName(),
                    "independent": [indep.get(k) for k in range(indep.getSize())], "slope": slope})
    return out


def _identity_rotation_functions(osim, model, joints: Sequence[str]) -> list[dict[str, Any]]:
    """Replace the rotation functions of the given CustomJoints by q -> q."""
    replaced = []
    for jn in joints:
        cj = osim.CustomJoint.safeDownCast(model.getJointSet().get(jn))
        if cj is None:
            raise ValueError(f"joint {jn} is not a CustomJoint; not supported")
        st = cj.getSpatialTransform()
        for k in range(3):
            ta = st.updTransformAxis(k)
            f = ta.get_function()
            val, slope = _function_value_slope(osim, f, 0.0)
            if abs(val) > 1e-9:
                raise ValueError(f"{jn} rotation{k + 1}: function value at q=0 is {val}, expected 0")
            lin = osim.LinearFunction.safeDownCast(f)
            if lin is not None and abs(slope - 1.0) < 1e-12:
                continue
            _, slope2 = _function_value_slope(osim, f, 0.2)
            replaced.append({"joint": jn, "axis": f"rotation{k + 1}", "coordinate": ta.get_coordinates(0),
                             "type": f.getConcreteClassName(), "slope_at_0": slope, "slope_at_0.2": slope2})
            ta.set_function(osim.LinearFunction(1.0, 0.0))
    return replaced


def _set_neutral(model, state, joints: set[str]) -> None:
    cset = model.getCoordinateSet()
    for i in range(cset.getSize()):
        c = cset.get(i)
        if c.getJoint().getName() in joints:
            c.setValue(state, 0.0, False)
    model.realizePosition(state)


def _point_in(model, state, body: str, loc: np.ndarray, frame) -> np.ndarray:
    osim = _import_opensim()
    return _np3(model.getBodySet().get(body).findStationLocationInAnotherFrame(state, _vec3(osim, loc), frame))


@dataclass
class _Built:
    geometry: str
    model: Any
    state: Any
    chain: list[dict[str, Any]]
    info: dict[str, Any] = field(default_factory=dict)


def _build_model(osim, osim_path: Path, multifidus_path: Path, geometry: str, table: pd.DataFrame) -> _Built:
    """Load, decouple, (rescale,) add the multifidus, set the neutral posture."""
    model = osim.Model(str(osim_path))
    info: dict[str, Any] = {"geometry": geometry}
    info["constraints_disabled"] = _disable_constraints(osim, model)
    model.finalizeConnections()
    chain = _find_joint_chain(model)
    if tuple(c["label"] for c in chain[:7]) != JOINTS or chain[7]["label"] != "C7-T1":
        raise ValueError(f"joint chain {[c['label'] for c in chain]} != thesis joints {JOINTS} + C7-T1")
    info["functions_replaced_by_identity"] = _identity_rotation_functions(osim, model, [c["joint"] for c in chain])
    neck_joints = {c["joint"] for c in chain}
    mons = read_osim_muscles(multifidus_path)
    state = model.initSystem()
    _set_neutral(model, state, neck_joints)

    if geometry == GEOMETRY_GENERIC:
        gf = generic_body_factors(osim_path, multifidus_path)
        info["body_scale_factors"] = gf
        ss = osim.ScaleSet()
        for body, rec in gf.items():
            sc = osim.Scale()
            sc.setSegmentName(body)
            sc.setScaleFactors(osim.Vec3(rec["factor"], rec["factor"], rec["factor"]))
            sc.setApply(True)
            ss.cloneAndAppend(sc)
        model.scale(state, ss, False, -1.0)
        state = model.initSystem()
        _set_neutral(model, state, neck_joints)
        mesh_second = read_mesh_scale_factors(multifidus_path)
        point_scale = {b: mesh_second[b] for b in gf if b in mesh_second}
        info["path_replacements"] = _reconcile_paths(osim, model, state, table, mons, point_scale)
        mult_divisor = point_scale
        info["multifidus_point_divisor"] = "second-file mesh scale (per body)"
    elif geometry == GEOMETRY_MORTENSEN:
        ratio = estimate_scale_factors(osim_path, multifidus_path)
        mult_divisor = {b: v["factor"] for b, v in ratio.items()}
        info["multifidus_point_divisor"] = "second/first point ratio (per body)"
    else:
        raise ValueError(f"unknown geometry {geometry!r}")
    info["multifidus_point_divisors"] = {}

    # --- add the multifidus slips ---
    bodies = {model.getBodySet().get(i).getName() for i in range(model.getBodySet().getSize())}
    added = {}
    for name in table.loc[table.source == MULTIFIDUS, "osim_name"]:
        if name not in mons:
            raise KeyError(f"{multifidus_path.name}: muscle {name!r} not found")
        rec = mons[name]
        if rec["unsupported_points"]:
            raise ValueError(f"{multifidus_path.name}: {name} uses {rec['unsupported_points']}; only PathPoints are supported")
        alpha = rec["pennation_angle_at_optimal"]
        m = osim.Millard2012EquilibriumMuscle(name, rec["max_isometric_force"], rec["optimal_fiber_length"],
                                              rec["tendon_slack_length"], 0.0 if math.isnan(alpha) else alpha)
        m.set_ignore_tendon_compliance(True)
        pts = []
        for p in rec["points"]:
            if p.body not in bodies or p.body not in mult_divisor:
                raise KeyError(f"{name}: body {p.body!r} missing in the model or without scale factor")
            info["multifidus_point_divisors"][p.body] = mult_divisor[p.body]
            loc = p.location / mult_divisor[p.body]
            m.addNewPathPoint(p.name, model.getBodySet().get(p.body), _vec3(osim, loc))
            pts.append({"name": p.name, "body": p.body, "location": loc.tolist()})
        model.addForce(m)
        added[name] = {"points": pts, "file_lopt": rec["optimal_fiber_length"], "file_lts": rec["tendon_slack_length"]}
    model.finalizeConnections()
    state = model.initSystem()
    _set_neutral(model, state, neck_joints)
    # keep the file's lopt:lts ratio, fitted to this geometry's neutral path length
    # (irrelevant for moment arms; keeps --save-osim models usable)
    for name, rec in added.items():
        m = model.getMuscles().get(name)
        length = m.getLength(state)
        tot = rec["file_lopt"] + rec["file_lts"]
        m.setOptimalFiberLength(length * rec["file_lopt"] / tot)
        m.setTendonSlackLength(length * rec["file_lts"] / tot)
        rec["neutral_length_m"] = length
    info["multifidus_added"] = added
    state = model.initSystem()
    _set_neutral(model, state, neck_joints)
    return _Built(geometry, model, state, chain, info)


def _reconcile_paths(osim, model, state, table, mons, point_scale) -> dict[str, Any]:
    """Compare each thesis muscle's path in the rescaled model with the second
    file's path (divided by its mesh scale), in the skull frame at neutral.

    Identical paths (all points within SAME_POINT_TOL) are kept; where they
    differ and all of the second file's bodies exist here, the second file's
    neutral point positions are used, each attached to the body this file
    attaches it to (the suprahyoid points on cerv1: this reproduces Table B.1
    and restores the left/right symmetry that the first file lacks; the second
    file moves the left stylohyoid points to cerv3, which would make the left
    and right stylohyoids span different joints).
    """
    skull = model.getBodySet().get("skull")
    bodies = {model.getBodySet().get(i).getName() for i in range(model.getBodySet().getSize())}
    report: dict[str, Any] = {"kept_identical": [], "replaced": {}, "not_comparable": {}}
    for name in table.loc[table.source == GENERIC, "osim_name"]:
        m = model.getMuscles().get(name)
        pps = m.getGeometryPath().updPathPointSet()
        here = []
        for k in range(pps.getSize()):
            pp = osim.PathPoint.safeDownCast(pps.get(k))
            if pp is None:
                raise ValueError(f"{name}: path point {k} is not a plain PathPoint")
            body = pp.getParentFrame().findBaseFrame().getName()
            here.append((body, _np3(pp.get_location())))
        other = mons.get(name)
        if other is None or other["unsupported_points"]:
            report["not_comparable"][name] = "missing in second file"
            continue
        if any(p.body not in bodies or p.body not in point_scale for p in other["points"]):
            report["not_comparable"][name] = "second file uses bodies " + ",".join(sorted({p.body for p in other["points"]}))
            continue
        if len(other["points"]) != len(here):
            report["not_comparable"][name] = "different number of path points"
            continue
        a = np.array([_point_in(model, state, b, loc, skull) for b, loc in here])
        new_locs = [p.location / point_scale[p.body] for p in other["points"]]
        b = np.array([_point_in(model, state, p.body, loc, skull) for p, loc in zip(other["points"], new_locs)])
        dmax = float(np.max(np.linalg.norm(a - b, axis=1)))
        if dmax < SAME_POINT_TOL:
            report["kept_identical"].append(name)
            continue
        # keep this file's bodies (which vertebra a point rides on); take the
        # second file's neutral position, re-expressed in that body's frame
        pts = []
        for k, ((body, _), pos) in enumerate(zip(here, b)):
            loc = _np3(skull.findStationLocationInAnotherFrame(state, _vec3(osim, pos), model.getBodySet().get(body)))
            osim.PathPoint.safeDownCast(pps.get(k)).setLocation(_vec3(osim, loc))
            pts.append({"body": body, "location": loc.tolist()})
        report["replaced"][name] = {
            "max_point_displacement_m": dmax,
            "points": pts,
            "second_file_bodies": [p.body for p in other["points"]],
        }
    model.finalizeConnections()
    return report


def _compute(osim, built: _Built, table: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame, dict[str, Any]]:
    """Moment arms (thesis sign), coordinate table and checks for a built model."""
    model, state, chain = built.model, built.state, built.chain
    skull = model.getBodySet().get("skull")
    cset = model.getCoordinateSet()
    coord_rows, coord_objs = [], {}
    for c in chain[:7]:
        j = model.getJointSet().get(c["joint"])
        st = osim.CustomJoint.safeDownCast(j).getSpatialTransform()
        child_origin = _np3(j.getChildFrame().findStationLocationInAnotherFrame(state, osim.Vec3(0, 0, 0), skull))
        parent_origin = _np3(j.getParentFrame().findStationLocationInAnotherFrame(state, osim.Vec3(0, 0, 0), skull))
        if np.max(np.abs(child_origin - parent_origin)) > 1e-9:
            raise ValueError(f"{c['joint']}: parent/child frame origins differ at neutral")
        seen = set()
        for k in range(3):
            ta = st.getTransformAxis(k)
            axis_skull = _np3(j.getParentFrame().expressVectorInAnotherFrame(state, ta.getAxis(), skull))
            axis_skull /= np.linalg.norm(axis_skull)
            dots = {a: float(np.dot(axis_skull, THESIS_AXIS_VECTORS[a])) for a in AXES}
            axis_name = max(dots, key=lambda a: abs(dots[a]))
            if abs(dots[axis_name]) < 0.999 or axis_name in seen:
                raise ValueError(f"{c['joint']} rotation{k + 1}: axis {axis_skull} not a distinct skull-frame axis")
            seen.add(axis_name)
            _, slope = _function_value_slope(osim, ta.get_function(), 0.0)
            # child is the cranial body (checked by the chain walk), so a positive
            # coordinate rotates the cranial segment about +axis
            sign = int(np.sign(dots[axis_name]) * np.sign(slope))
            coord_name = ta.get_coordinates(0)
            key = f"{c['label']}_{axis_name}"
            coord_objs[key] = (cset.get(coord_name), sign)
            ax = sign * axis_skull
            coord_rows.append({"coordinate": key, "joint": c["label"], "axis": axis_name, "osim_coordinate": coord_name,
                               "sign": sign, "centre_x": child_origin[0], "centre_y": child_origin[1],
                               "centre_z": child_origin[2], "axis_x": ax[0], "axis_y": ax[1], "axis_z": ax[2],
                               "osim_joint": c["joint"]})
    coordinates = pd.DataFrame(coord_rows).set_index("coordinate").loc[list(COORDINATES)].reset_index()

    # moment arms, with a central finite-difference check of r = -dL/dq
    mus_set = model.getMuscles()
    R = np.zeros((len(table), len(COORDINATES)))
    fd_err = np.zeros_like(R)
    for i, osim_name in enumerate(table["osim_name"]):
        m = mus_set.get(osim_name)
        for k, key in enumerate(COORDINATES):
            coord, sign = coord_objs[key]
            r = float(m.computeMomentArm(state, coord))
            q0 = coord.getValue(state)
            coord.setValue(state, q0 + FD_STEP, False)
            model.realizePosition(state)
            lp = m.getLength(state)
            coord.setValue(state, q0 - FD_STEP, False)
            model.realizePosition(state)
            lm = m.getLength(state)
            coord.setValue(state, q0, False)
            model.realizePosition(state)
            fd_err[i, k] = r + (lp - lm) / (2 * FD_STEP)
            R[i, k] = 0.0 if abs(r) < ZERO_TOL else sign * r
    moment_arms = pd.concat([table[["index", "name"]], pd.DataFrame(R, columns=list(COORDINATES))], axis=1)

    # frame checks
    orient = {}
    for b in ["skull", *(f"cerv{i}" for i in range(1, 8)), "spine"]:
        T = model.getBodySet().get(b).findTransformBetween(state, skull)
        M = _rot(T.R())
        orient[b] = float(np.max(np.abs(M - np.eye(3))))
    markers = {}
    ms = model.getMarkerSet()
    for i in range(ms.getSize()):
        mk = ms.get(i)
        if mk.getName() in ("GLA", "RZF", "RZP", "LZF", "LZP"):
            markers[mk.getName()] = _np3(mk.getParentFrame().findStationLocationInAnotherFrame(state, mk.get_location(), skull)).round(6).tolist()
    c7t1 = model.getJointSet().get(chain[7]["joint"])
    Tg = skull.getTransformInGround(state)
    checks = {
        "max_abs_computeMomentArm_minus_finite_difference_m": float(np.max(np.abs(fd_err))),
        "finite_difference_step_rad": FD_STEP,
        "max_abs_left_right_mirror_error_m": _symmetry_error(moment_arms),
        "left_right_mirror_error_by_muscle_m": _symmetry_by_muscle(moment_arms),
        "max_body_orientation_deviation_from_skull_at_neutral": orient,
        "skull_rotation_in_ground_at_neutral": _rot(Tg.R()).round(6).tolist(),
        "skull_markers_skull_frame_m": markers,
        "C7-T1_centre_skull_frame_m": _np3(c7t1.getChildFrame().findStationLocationInAnotherFrame(state, osim.Vec3(0, 0, 0), skull)).tolist(),
    }
    return moment_arms, coordinates, checks


def _symmetry_error(moment_arms: pd.DataFrame) -> float:
    """Max |mirror error| over R/L pairs: pitch equal, roll and yaw opposite."""
    vals = moment_arms[list(COORDINATES)].to_numpy()
    sgn = np.array([1.0 if c.endswith("pitch") else -1.0 for c in COORDINATES])
    return float(np.max(np.abs(vals[0::2] - sgn * vals[1::2])))


def _symmetry_by_muscle(moment_arms: pd.DataFrame, tol: float = 1e-6) -> dict[str, float]:
    vals = moment_arms[list(COORDINATES)].to_numpy()
    sgn = np.array([1.0 if c.endswith("pitch") else -1.0 for c in COORDINATES])
    err = np.abs(vals[0::2] - sgn * vals[1::2]).max(axis=1)
    names = moment_arms["name"].to_numpy()[0::2]
    return {str(n): float(e) for n, e in zip(names, err) if e > tol}


#: Strength scale factors of Mortensen et al. (2018) relative to the unscaled
#: generic model: extensors x1.4, flexors and hyoids x2.7.
MORTENSEN_STRENGTH_SCALES: tuple[float, ...] = (1.4, 2.7)


def _strengths(table: pd.DataFrame, osim_path: Path, multifidus_path: Path, path_source: dict[str, str]) -> pd.DataFrame:
    """Strength columns.

    ``osim_max_isometric_force_N`` is the *unscaled* generic value that the
    thesis says it used ("default strength values", no flexor/extensor
    scaling): the first file's value divided by its Mortensen (2018) factor
    (1.4 or 2.7, whichever is nearer to the ratio between the two files) for
    rows 1-72, the second file's value for rows 73-96.
    """
    gen, mons = read_osim_muscles(osim_path), read_osim_muscles(multifidus_path)
    musc = table.copy()
    musc["source_file"] = np.where(musc.source == MULTIFIDUS, multifidus_path.name, osim_path.name)
    unscaled, f_mort, f_mons, scale = [], [], [], []
    for n in musc.osim_name:
        fm = gen[n]["max_isometric_force"] if n in gen else float("nan")
        fn = mons[n]["max_isometric_force"] if n in mons else float("nan")
        f_mort.append(fm)
        f_mons.append(fn)
        if n in gen:
            ratio = fm / fn if n in mons else float("nan")
            sc = min(MORTENSEN_STRENGTH_SCALES, key=lambda s: abs(s - ratio)) if not math.isnan(ratio) else float("nan")
            scale.append(sc)
            unscaled.append(fm / sc)
        else:
            scale.append(float("nan"))
            unscaled.append(fn)
    musc["osim_max_isometric_force_N"] = unscaled
    musc["mortensen2014_max_isometric_force_N"] = f_mort
    musc["mortensen2014_scale"] = scale
    musc["neckshoulder_max_isometric_force_N"] = f_mons
    musc["path_source_file"] = [path_source.get(n, osim_path.name) for n in musc.osim_name]
    return musc[["index", "name", "osim_name", "source_file", "side", "osim_max_isometric_force_N",
                 "mortensen2014_max_isometric_force_N", "mortensen2014_scale", "neckshoulder_max_isometric_force_N",
                 "path_source_file"]]


@dataclass
class Derivation:
    muscles: pd.DataFrame
    moment_arms: pd.DataFrame  # primary: generic (unscaled) geometry
    coordinates: pd.DataFrame
    moment_arms_mortensen: pd.DataFrame  # Mortensen2014 file as is
    coordinates_mortensen: pd.DataFrame
    provenance: dict[str, Any]
    comparison: pd.DataFrame | None
    b3_strengths: pd.DataFrame | None = None


def derive_tables(
    osim_path: Path | str,
    multifidus_osim_path: Path | str,
    *,
    b1: pd.DataFrame | None = None,
    osim_source: str | None = None,
    multifidus_source: str | None = None,
    save_osim: Path | str | None = None,
) -> Derivation:
    """Run the derivation for both geometries and return the tables (no files written)."""
    osim = _import_opensim()
    osim_path, multifidus_osim_path = Path(osim_path), Path(multifidus_osim_path)
    table = thesis_muscle_table()

    results = {}
    for geometry in (GEOMETRY_GENERIC, GEOMETRY_MORTENSEN):
        built = _build_model(osim, osim_path, multifidus_osim_path, geometry, table)
        ma, co, checks = _compute(osim, built, table)
        results[geometry] = (built, ma, co, checks)
        if save_osim and geometry == GEOMETRY_GENERIC:
            built.model.printToXML(str(save_osim))

    gbuilt = results[GEOMETRY_GENERIC][0]
    path_source = {n: multifidus_osim_path.name for n in gbuilt.info["path_replacements"]["replaced"]}
    path_source.update({n: multifidus_osim_path.name for n in table.loc[table.source == MULTIFIDUS, "osim_name"]})
    muscles = _strengths(table, osim_path, multifidus_osim_path, path_source)

    comparison = None
    if b1 is not None and len(b1):
        comparison = compare_with_b1(results[GEOMETRY_GENERIC][1], b1,
                                     extra={"mortensen2014_m": results[GEOMETRY_MORTENSEN][1]})

    geo_prov = {}
    for geometry, (built, _, _, checks) in results.items():
        geo_prov[geometry] = {**built.info, "checks": checks, "joint_chain": built.chain}
    provenance: dict[str, Any] = {
        "inputs": {
            "osim": {**_source_info(osim_path, osim_source), "role": "bodies, joints, muscles 1-72"},
            "multifidus_osim": {**_source_info(multifidus_osim_path, multifidus_source),
                                "role": "multifidus slips 73-96, generic-geometry scale, suprahyoid points"},
        },
        "opensim_version": str(osim.__version__),
        "python_version": sys.version.split()[0],
        "date_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "sign_convention": SIGN_CONVENTION,
        "coordinate_order": list(COORDINATES),
        "primary_geometry": GEOMETRY_GENERIC,
        "files": {GEOMETRY_GENERIC: [MOMENT_ARMS_CSV, COORDINATES_CSV],
                  GEOMETRY_MORTENSEN: [MORTENSEN_MOMENT_ARMS_CSV, MORTENSEN_COORDINATES_CSV]},
        "neutral_posture": "all coordinates of the 7 thesis joints and of C7-T1 set to 0 (the file defaults "
                           "are within 2e-6 rad of 0); the ground-to-thorax joint keeps its default (gndpitch "
                           "0.384 rad), which only orients the whole model in ground",
        "multifidus_scale_factors_second_over_first": estimate_scale_factors(osim_path, multifidus_osim_path),
        "geometries": geo_prov,
        "thesis_muscle_order": table[["index", "name", "osim_name"]].values.tolist(),
        "unprinted_b1_rows": list(UNPRINTED_B1_ROWS),
    }
    return Derivation(muscles, results[GEOMETRY_GENERIC][1], results[GEOMETRY_GENERIC][2],
                      results[GEOMETRY_MORTENSEN][1], results[GEOMETRY_MORTENSEN][2], provenance, comparison)


def _header(prov: dict[str, Any], what: str, extra: Sequence[str] = ()) -> str:
    gi, mi = prov["inputs"]["osim"], prov["inputs"]["multifidus_osim"]
    lines = [
        what,
        "derived by: python -m neckstrength.model.opensim.derive (see docs/model_derivation.md)",
        f"source: {gi['file']} from {gi.get('repository')} commit {gi.get('commit')} ({gi.get('path', '')}), sha256 {gi['sha256']}",
        f"source: {mi['file']} from {mi.get('repository')} commit {mi.get('commit')} ({mi.get('path', '')}), sha256 {mi['sha256']}",
        f"opensim {prov['opensim_version']}; date {prov['date_utc']}",
        f"sign convention: {prov['sign_convention']}",
        *extra,
    ]
    return "".join(f"# {ln}\n" for ln in lines)


def _clean(df: pd.DataFrame, decimals: int) -> pd.DataFrame:
    """Round float columns and remove negative zeros."""
    out = df.copy()
    for c in out.columns:
        if pd.api.types.is_float_dtype(out[c]):
            out[c] = out[c].round(decimals) + 0.0
    return out


GENERIC_NOTE = ("geometry: unscaled generic neck (ModelOfNeckAndShoulder / its mesh scale 0.865351 for neck bodies, "
                "Mortensen2014 / its mesh scale for thorax and shoulder girdle); reproduces thesis Table B.1")


MORTENSEN_NOTE = ("geometry: Mortensen2014_rigidTorso.osim as it is (not the thesis geometry: cervical vertebrae "
                  "1.092x, skull 0.947x, thorax 0.891x of it); multifidus brought to its scale")


def write_tables(d: Derivation, out_dir: Path | str, command_line: str) -> list[Path]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    prov = dict(d.provenance)
    prov["command_line"] = command_line
    written = []

    def _write(df: pd.DataFrame, name: str, what: str, extra: Sequence[str], decimals: int) -> None:
        p = out / name
        with open(p, "w", encoding="utf-8", newline="") as fh:
            fh.write(_header(prov, what, extra))
            _clean(df, decimals).to_csv(fh, index=False, lineterminator="\n")
        written.append(p)

    _write(d.muscles, MUSCLES_CSV, "Full neck model: the 96 muscle elements in thesis Table B.1 order.", (
        "rows 15-30 and 47-62 are not printed in the seed's Table B.1; their order follows a public MATLAB enumeration of the thesis muscles",
        "osim_max_isometric_force_N: unscaled generic convention (thesis Sec. 4.2.4: default strengths, no flexor/extensor scaling): rows 1-72 mortensen2014_max_isometric_force_N / mortensen2014_scale, rows 73-96 the ModelOfNeckAndShoulder value; Table B.1 wins where printed",
        "mortensen2014_max_isometric_force_N: value in Mortensen2014_rigidTorso.osim (Mortensen et al. 2018 convention: unscaled x1.4 extensors, x2.7 flexors/hyoids); mortensen2014_scale: that factor",
        "neckshoulder_max_isometric_force_N: value in ModelOfNeckAndShoulder.osim (unscaled; differs for long col (9.57 vs 11.97) and its T1/T2 multifidus values 64.05 are copies of semispinalis)",
        "source_file: file the muscle comes from; path_source_file: file whose path points the primary (generic) geometry uses",
        "side: R for names without suffix, L for names ending in ' L' / '_L'",
    ), 4)
    ma_note = ("rows: thesis muscle index 1..96; columns joint-major: C0-C1_pitch = row 1 of R, C6-C7_pitch = row 19; "
               "0 means the muscle does not span the joint")
    _write(d.moment_arms, MOMENT_ARMS_CSV, "Full neck model: moment arms (m) of the 96 muscles about the 21 joint coordinates, neutral posture.",
           (GENERIC_NOTE, ma_note), 6)
    co_note = "sign: factor applied to the OpenSim moment arm about osim_coordinate; axis_*: unit vector of the positive thesis rotation"
    _write(d.coordinates, COORDINATES_CSV, "Full neck model: joint centres and rotation axes in the skull frame (m), neutral posture.",
           (GENERIC_NOTE, co_note), 6)
    _write(d.moment_arms_mortensen, MORTENSEN_MOMENT_ARMS_CSV, "Variant: moment arms (m) in the Mortensen2014 geometry (reference only).",
           (MORTENSEN_NOTE, ma_note), 6)
    _write(d.coordinates_mortensen, MORTENSEN_COORDINATES_CSV, "Variant: joint centres and axes in the Mortensen2014 geometry (reference only).",
           (MORTENSEN_NOTE, co_note), 6)
    if d.comparison is not None:
        _write(d.comparison, COMPARISON_CSV, "Derived moment arms vs. every nonblank moment arm printed in thesis Table B.1.", (
            f"B.1 source: {prov.get('b1_source', 'unknown')}",
            "derived_m: primary (generic) geometry; diff_m = derived_m - b1_m; rel_diff = diff_m / |b1_m|; "
            "mortensen2014_m: same moment arm in the Mortensen2014 geometry",
            "B.1 rows 11-12 (sternohyoid) and the C0-C1 cells of rows 35-36 are misplaced in the seed text (see docs/model_derivation.md)",
        ), 6)
    if d.b3_strengths is not None and len(d.b3_strengths):
        _write(d.b3_strengths, B3_STRENGTHS_CSV,
               "Strengths of the muscles without a printed Table B.1 strength, implied by thesis Tables B.2/B.3 and the derived moment arms.", (
                   "fit per s3m24 group: F_g = ||F_i|| and R_g = sum F_i r_i / F_g (thesis Sec. 4.2.1.3), known F_i from Table B.1",
                   "se_N: standard error from print rounding; max_abs_residual_rounding_sd: worst residual in units of the rounding sd",
                   "model_unscaled_N: osim_max_isometric_force_N of full_model_muscles.csv, for comparison",
               ), 2)
    p = out / PROVENANCE_JSON
    p.write_text(json.dumps(prov, indent=1, default=_json_default) + "\n", encoding="utf-8")
    written.append(p)
    return written


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(type(o))


THESIS_B1_CSV = "table_B1_muscles.csv"


THESIS_B2_CSV = "table_B2_groups_s3m24.csv"


THESIS_B3_CSV = "table_B3_params_s3m24.csv"


def _thesis_inputs(thesis_dir: Path | None, seed: Path | None) -> dict[str, Any]:
    """Tables B.1-B.3 from the project's transcriptions if present, else the seed text."""
    out: dict[str, Any] = {"b1": None, "b1_strengths": None, "b2": None, "b3": None, "sources": {}}

    def _csv(name: str) -> Path | None:
        if thesis_dir is None:
            return None
        p = Path(thesis_dir) / name
        return p if p.exists() else None

    def _desc(p: Path) -> str:
        return f"{p.as_posix()} (sha256 {sha256_file(p)})"

    p1 = _csv(THESIS_B1_CSV)
    if p1 is not None:
        out["b1"] = read_b1_table(p1)
        out["b1_strengths"] = pd.read_csv(p1, comment="#")[["index", "name", "strength_N"]]
        out["sources"]["B.1"] = _desc(p1)
    elif seed is not None:
        out["b1"] = parse_b1_from_seed(seed)
        out["b1_strengths"] = parse_b1_strengths_from_seed(seed)
        out["sources"]["B.1"] = f"parsed from seed text {_desc(seed)}"
    p2, p3 = _csv(THESIS_B2_CSV), _csv(THESIS_B3_CSV)
    if p2 is not None and p3 is not None:
        out["b2"], out["b3"] = read_b2_table(p2), read_b3_table(p3)
        out["sources"]["B.2"], out["sources"]["B.3"] = _desc(p2), _desc(p3)
    elif seed is not None:
        out["b2"], out["b3"] = parse_b2_groups(seed), parse_b3_groups(seed)
        out["sources"]["B.2"] = out["sources"]["B.3"] = f"parsed from seed text {_desc(seed)}"
    return out


def derive_full_model(
    osim_path: Path | str,
    multifidus_osim_path: Path | str,
    out_dir: Path | str,
    *,
    thesis_dir: Path | str | None = "data/thesis",
    seed: Path | str | None = None,
    osim_source: str | None = None,
    multifidus_source: str | None = None,
    save_osim: Path | str | None = None,
    command_line: str | None = None,
) -> Derivation:
    """Derive the full-model tables and write them to ``out_dir``.

    Tables B.1-B.3 (for ``momentarm_vs_B1.csv`` and ``b3_implied_strengths.csv``)
    come from the project's transcriptions in ``thesis_dir`` when present,
    otherwise from the thesis text ``seed``; without either, those two files
    are not written.
    """
    th = _thesis_inputs(Path(thesis_dir) if thesis_dir is not None else None,
                        Path(seed) if seed is not None else None)
    d = derive_tables(osim_path, multifidus_osim_path, b1=th["b1"], osim_source=osim_source,
                      multifidus_source=multifidus_source, save_osim=save_osim)
    d.provenance["thesis_table_sources"] = th["sources"]
    d.provenance["b1_source"] = th["sources"].get("B.1", "none")
    if d.comparison is not None:
        mis = d.comparison["note"] != ""
        ok, re_ = d.comparison[~mis], d.comparison[mis]
        d.provenance["b1_comparison"] = {
            "misplaced_cells_excluded": [[k[0], k[1], v[0], v[1]] for k, v in B1_MISPLACED.items()],
            GEOMETRY_GENERIC: summarize_comparison(ok, "derived_m"),
            GEOMETRY_MORTENSEN: summarize_comparison(ok, "mortensen2014_m"),
            "misplaced_cells_max_abs_diff_reinterpreted_m":
                float((re_["reinterpreted_derived_m"] - re_["b1_m"]).abs().max()) if len(re_) else None,
        }
    if th["b1_strengths"] is not None and th["b2"] is not None and th["b3"] is not None:
        d.b3_strengths = infer_strengths_from_b3(d.moment_arms, th["b1_strengths"], th["b2"], th["b3"], d.muscles)
        d.provenance["b3_implied_strengths"] = {
            "sources": {k: th["sources"][k] for k in ("B.1", "B.2", "B.3")},
            "max_abs_residual_rounding_sd": float(d.b3_strengths["max_abs_residual_rounding_sd"].max()),
            "file": B3_STRENGTHS_CSV,
        }
    if command_line is None:
        command_line = f"derive_full_model({osim_path!s}, {multifidus_osim_path!s}, {out_dir!s})"
    write_tables(d, out_dir, command_line)
    return d


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m neckstrength.model.opensim.derive",
                                 description="Derive the full 96-muscle neck model tables from OpenSim models.")
    ap.add_argument("--osim", required=True, type=Path, help="generic model, e.g. Mortensen2014_rigidTorso.osim")
    ap.add_argument("--multifidus-osim", required=True, type=Path,
                    help="model with the multifidus slips, e.g. ModelOfNeckAndShoulder.osim (also fixes the "
                         "generic scale; required)")
    ap.add_argument("--out", required=True, type=Path, help="output directory, e.g. data/model")
    ap.add_argument("--thesis-dir", type=Path, default=Path("data/thesis"),
                    help="project transcriptions of thesis Tables B.1-B.3, used where present (default: %(default)s)")
    ap.add_argument("--seed", type=Path, default=None, help="thesis text to parse Tables B.1-B.3 from where "
                                                            "--thesis-dir lacks them")
    ap.add_argument("--osim-source", default=None, help="'owner/repo@commit' provenance for --osim if its sha256 is unknown")
    ap.add_argument("--multifidus-source", default=None, help="'owner/repo@commit' provenance for --multifidus-osim")
    ap.add_argument("--save-osim", type=Path, default=None,
                    help="also write the derived generic-geometry OpenSim model (keep it outside the project)")
    args = ap.parse_args(argv)
    argv_list = list(sys.argv[1:] if argv is None else argv)
    cmd = "python -m neckstrength.model.opensim.derive " + " ".join(argv_list)
    d = derive_full_model(args.osim, args.multifidus_osim, args.out, thesis_dir=args.thesis_dir, seed=args.seed,
                          osim_source=args.osim_source, multifidus_source=args.multifidus_source,
                          save_osim=args.save_osim, command_line=cmd)
    print(f"wrote tables to {args.out}")
    for geometry, g in d.provenance["geometries"].items():
        chk = g["checks"]
        print(f"[{geometry}] max |computeMomentArm - finite difference| = "
              f"{chk['max_abs_computeMomentArm_minus_finite_difference_m']:.1e} m; "
              f"max L/R mirror error = {chk['max_abs_left_right_mirror_error_m']:.1e} m")
    if d.comparison is not None:
        for geometry in (GEOMETRY_GENERIC, GEOMETRY_MORTENSEN):
            sm = d.provenance["b1_comparison"][geometry]
            print(f"B.1 [{geometry}]: n={sm['n']} max |diff| = {sm['max_abs_diff_m']:.2e} m, "
                  f"median |rel| = {sm['median_abs_rel_diff']:.4f}, max |rel| (|B.1| >= 5 mm) = {sm['max_abs_rel_diff']:.4f}")
    if d.b3_strengths is not None:
        print(f"B.3-implied strengths of {len(d.b3_strengths)} unprinted rows; worst residual "
              f"{d.provenance['b3_implied_strengths']['max_abs_residual_rounding_sd']:.2f} rounding sd")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
