"""Posture-dependent model tables (issue 20): moment arms, skull-frame Jacobians, force-length factors.

A derivation command like :mod:`neckstrength.model.opensim.derive` (needs ``opensim`` and the two reference
.osim files); the default pipeline reads the tables it writes to ``data/model/postures/``.

How a posture is put on the joints (docs/postures.md):

* the model file's own coupling: each of its six independent coordinates (``pitch1/roll1/yaw1`` upper neck,
  ``pitch2/roll2/yaw2`` lower neck) drives its joints with the slopes of the file's
  ``CoordinateCouplerConstraint`` s and of the two SimmSpline joint functions (C1-C2 and C7-T1), which the
  derivation records when it disables them. Joint angle = slope x independent value;
* a head-on-thorax rotation ``theta`` about one axis is split between the upper and the lower independent
  coordinate in proportion to the file's range of motion of each in that direction (``split='range'``, e.g.
  flexion: pitch1 min -0.279 rad, pitch2 min -0.785 rad, so 26 % upper), then scaled so that the joint angles
  add up to ``theta`` exactly (all axes of one kind stay parallel in a single-axis posture, so the angles add).

Per posture the derivation writes, in the primary (generic) geometry of ``derive``:

* ``moment_arms_<posture>.csv``: 96 x 21 moment arms ``-dL/dq`` (thesis signs, as ``full_model_moment_arms``);
* ``coordinates_<posture>.csv``: per coordinate the skull-frame twist of the skull per unit joint rotation
  ``(omega, v)`` (= the row ``[a, c x a]`` of ``J^T``), the unit axis ``a`` and the joint centre ``c`` (checked: ``c x a = v``);
* ``force_length_<posture>.csv``: each element's fibre length with a rigid tendon at its tendon slack length
  (the file's Millard2012EquilibriumMuscle, ``ignore_tendon_compliance``), the normalised length, the value of
  the muscle's own ``ActiveForceLengthCurve`` there (``factor``) and ``factor_rel = factor / factor(neutral)``;
* ``jacobians.csv``: ``J^T`` of every kinematic variant (s7, s3, s2, p7, p3, p2) in every posture;
* ``postures.csv`` (the joint angles of every posture) and ``postures_provenance.json``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from neckstrength.model.opensim import derive as D

#: The postures of issue 20: (axis of the head-on-thorax rotation, angle in thesis signs, deg).
#: pitch + = extension, roll + = right side-bend, yaw + = left axial rotation (Table B.1 convention).
POSTURES: dict[str, tuple[str | None, float]] = {
    "neutral": (None, 0.0),
    "flex20": ("pitch", -20.0),
    "ext20": ("pitch", 20.0),
    "rotL30": ("yaw", 30.0),
    "rotR30": ("yaw", -30.0),
    "bendL15": ("roll", -15.0),
    "bendR15": ("roll", 15.0),
}

UPPER = {"pitch": "pitch1", "roll": "roll1", "yaw": "yaw1"}

LOWER = {"pitch": "pitch2", "roll": "roll2", "yaw": "yaw2"}

#: Joint labels of the chain, cranial first, with C7-T1 (not a thesis joint, but it moves in a posture).
CHAIN = (*D.JOINTS, "C7-T1")

PROVENANCE = "postures_provenance.json"

POSTURES_CSV = "postures.csv"

JACOBIANS_CSV = "jacobians.csv"

KINEMATIC_VARIANTS: dict[str, tuple[str, tuple[str, ...]]] = {
    "s7": ("spatial", D.JOINTS), "s3": ("spatial", ("C0-C1", "C4-C5", "C6-C7")), "s2": ("spatial", ("C0-C1", "C6-C7")),
    "p7": ("planar", D.JOINTS), "p3": ("planar", ("C0-C1", "C4-C5", "C6-C7")), "p2": ("planar", ("C0-C1", "C6-C7")),
}

TWIST_STEP = 1e-6


def file_name(kind: str, posture: str) -> str:
    return f"{kind}_{posture}.csv"


def coupling_slopes(info: dict[str, Any], chain: Sequence[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """{independent coordinate: {joint coordinate: slope}} from the records of the disabled couplers and the
    replaced joint functions (the model file's own distribution of each independent coordinate)."""
    out: dict[str, dict[str, float]] = {}
    for c in info["constraints_disabled"]:
        if c.get("type") != "CoordinateCouplerConstraint" or len(c["independent"]) != 1:
            raise ValueError(f"constraint {c['name']}: only one-to-one coordinate couplers are supported")
        out.setdefault(c["independent"][0], {})[c["dependent"]] = float(c["slope"])
    for f in info["functions_replaced_by_identity"]:
        out.setdefault(f["coordinate"], {})[f["coordinate"]] = float(f["slope_at_0"])
    for indep in (*UPPER.values(), *LOWER.values()):
        out.setdefault(indep, {}).setdefault(indep, 1.0)
    return out


def posture_angles(model, slopes: dict[str, dict[str, float]], axis: str | None, theta_deg: float,
                   split: str | float = "range") -> tuple[dict[str, float], dict[str, float]]:
    """Joint coordinate values (rad) of a posture and the independent coordinate values that give them.

    ``split``: 'range' (upper share = the file's range of motion of the upper coordinate in that direction over
    the sum of both) or a number, the upper-neck share of the rotation. The values are scaled so that the joint
    angles of the chain add up to ``theta``.
    """
    if axis is None or theta_deg == 0.0:
        return {}, {}
    cs = model.getCoordinateSet()
    up, lo = UPPER[axis], LOWER[axis]
    if split == "range":
        def rom(name):
            c = cs.get(name)
            return abs(c.getRangeMax()) if theta_deg > 0 else abs(c.getRangeMin())
        share = rom(up) / (rom(up) + rom(lo))
    else:
        share = float(split)
        if not 0.0 <= share <= 1.0:
            raise ValueError(f"split must be 'range' or a share in [0, 1], got {split!r}")
    theta = math.radians(theta_deg)
    su, sl = sum(slopes[up].values()), sum(slopes[lo].values())
    indep = {up: theta * share / su, lo: theta * (1.0 - share) / sl}
    values: dict[str, float] = {}
    for k, v in indep.items():
        for dep, s in slopes[k].items():
            values[dep] = values.get(dep, 0.0) + s * v
    return values, {**indep, "upper_share": share}


def _skull_pose(model, state) -> tuple[np.ndarray, np.ndarray]:
    T = model.getBodySet().get("skull").getTransformInGround(state)
    return D._rot(T.R()), D._np3(T.p())


def skull_twist(model, state, coord) -> np.ndarray:
    """(omega, v) of the skull per unit rate of ``coord``, in the skull frame at the current posture (central
    finite difference of the skull pose): the row of ``J^T`` for that coordinate."""
    R0, _ = _skull_pose(model, state)
    q0 = coord.getValue(state)
    out = []
    for h in (TWIST_STEP, -TWIST_STEP):
        coord.setValue(state, q0 + h, False)
        model.realizePosition(state)
        out.append(_skull_pose(model, state))
    coord.setValue(state, q0, False)
    model.realizePosition(state)
    (Rp, pp), (Rm, pm) = out
    dR = R0.T @ (Rp - Rm) / (2 * TWIST_STEP)          # = omega^ (body frame)
    omega = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]]) / 2.0
    v = R0.T @ (pp - pm) / (2 * TWIST_STEP)
    return np.concatenate([omega, v])


def _set_posture(model, state, chain_coords: Sequence[str], values: dict[str, float]) -> None:
    cs = model.getCoordinateSet()
    for name in chain_coords:
        cs.get(name).setValue(state, float(values.get(name, 0.0)), False)
    model.realizePosition(state)


def _force_length(osim, model, state, table: pd.DataFrame) -> pd.DataFrame:
    rows = []
    mus = model.getMuscles()
    for r in table.to_dict("records"):
        m = osim.Millard2012EquilibriumMuscle.safeDownCast(mus.get(r["osim_name"]))
        if m is None:
            raise ValueError(f"{r['osim_name']}: only Millard2012EquilibriumMuscle is supported for force-length")
        L = m.getLength(state)
        lopt, lts = m.getOptimalFiberLength(), m.getTendonSlackLength()
        h = lopt * math.sin(m.getPennationAngleAtOptimalFiberLength())
        lf = math.sqrt(h * h + max(L - lts, 0.0) ** 2)
        ln = lf / lopt
        fl = float(m.get_ActiveForceLengthCurve().calcValue(ln))
        rows.append({"index": r["index"], "name": r["name"], "mt_length_m": L, "fiber_length_m": lf,
                     "optimal_fiber_length_m": lopt, "tendon_slack_length_m": lts,
                     "norm_fiber_length": ln, "pennation_rad": math.atan2(h, max(L - lts, 1e-12)), "factor": fl})
    return pd.DataFrame(rows)


def derive_postures(osim_path: Path | str, multifidus_osim_path: Path | str, postures: Sequence[str] | None = None,
                    split: str | float = "range", fd_check: bool = True) -> dict[str, Any]:
    """Derive the posture tables (generic geometry). Returns {posture: {moment_arms, coordinates, force_length,
    angles}} and 'provenance'."""
    osim = D._import_opensim()
    osim_path, multifidus_osim_path = Path(osim_path), Path(multifidus_osim_path)
    postures = list(POSTURES) if postures is None else list(postures)
    unknown = [p for p in postures if p not in POSTURES]
    if unknown:
        raise ValueError(f"unknown postures {unknown}; known: {list(POSTURES)}")
    if "neutral" not in postures:
        postures = ["neutral", *postures]
    table = D.thesis_muscle_table()
    built = D._build_model(osim, osim_path, multifidus_osim_path, D.GEOMETRY_GENERIC, table)
    model = built.model
    _, neutral_coords, _ = D._compute(osim, built, table)   # coordinate mapping and signs at neutral
    for i in range(model.getMuscles().getSize()):
        model.getMuscles().get(i).set_ignore_tendon_compliance(True)
    state = model.initSystem()
    chain_coords = []
    for c in built.chain:
        st = osim.CustomJoint.safeDownCast(model.getJointSet().get(c["joint"])).getSpatialTransform()
        chain_coords += [st.getTransformAxis(k).get_coordinates(0) for k in range(3)]
    slopes = coupling_slopes(built.info, built.chain)
    cset = model.getCoordinateSet()
    coord_of = {r["coordinate"]: (cset.get(r["osim_coordinate"]), int(r["sign"]))
                for r in neutral_coords.to_dict("records")}
    out: dict[str, Any] = {}
    fd_max = axis_err = 0.0
    for name in postures:
        axis, theta = POSTURES[name]
        values, indep = posture_angles(model, slopes, axis, theta, split)
        _set_posture(model, state, chain_coords, values)
        R = np.zeros((len(table), len(D.COORDINATES)))
        for i, osim_name in enumerate(table["osim_name"]):
            m = model.getMuscles().get(osim_name)
            for k, key in enumerate(D.COORDINATES):
                coord, sign = coord_of[key]
                r = float(m.computeMomentArm(state, coord))
                if fd_check and abs(r) > D.ZERO_TOL:
                    q0 = coord.getValue(state)
                    coord.setValue(state, q0 + D.FD_STEP, False)
                    model.realizePosition(state)
                    lp = m.getLength(state)
                    coord.setValue(state, q0 - D.FD_STEP, False)
                    model.realizePosition(state)
                    lm = m.getLength(state)
                    coord.setValue(state, q0, False)
                    model.realizePosition(state)
                    fd_max = max(fd_max, abs(r + (lp - lm) / (2 * D.FD_STEP)))
                R[i, k] = 0.0 if abs(r) < D.ZERO_TOL else sign * r
        ma = pd.concat([table[["index", "name"]], pd.DataFrame(R, columns=list(D.COORDINATES))], axis=1)
        crow = []
        skull = model.getBodySet().get("skull")
        for key in D.COORDINATES:
            coord, sign = coord_of[key]
            tw = sign * skull_twist(model, state, coord)
            a = tw[:3] / np.linalg.norm(tw[:3])
            joint = model.getJointSet().get(built.chain[D.JOINTS.index(key.split("_")[0])]["joint"])
            c = D._np3(joint.getChildFrame().findStationLocationInAnotherFrame(state, osim.Vec3(0, 0, 0), skull))
            axis_err = max(axis_err, float(np.max(np.abs(np.cross(c, a) - tw[3:]))),
                           abs(float(np.linalg.norm(tw[:3])) - 1.0))
            crow.append({"coordinate": key, "centre_x": c[0], "centre_y": c[1], "centre_z": c[2],
                         "axis_x": a[0], "axis_y": a[1], "axis_z": a[2],
                         **{f"JT_{w}": tw[k] for k, w in enumerate(("Mx", "My", "Mz", "Fx", "Fy", "Fz"))}})
        fl = _force_length(osim, model, state, table)
        Rsk, _ = _skull_pose(model, state)
        _set_posture(model, state, chain_coords, {})
        R0, _ = _skull_pose(model, state)
        rel = R0.T @ Rsk
        ang = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(rel) - 1) / 2))))
        out[name] = {"moment_arms": ma, "coordinates": pd.DataFrame(crow), "force_length": fl,
                     "angles": {"posture": name, "axis": axis or "", "theta_deg": theta,
                                "skull_rotation_from_neutral_deg": ang, **indep,
                                **{f"{lab}_{ax}": values.get(chain_coords[3 * j + k], 0.0)
                                   for j, lab in enumerate(CHAIN) for k, ax in enumerate(D.AXES)}}}
    neutral_fl = out["neutral"]["force_length"]["factor"].to_numpy()
    for name in postures:
        f = out[name]["force_length"]
        f["factor_rel"] = f["factor"].to_numpy() / neutral_fl
    out["provenance"] = {
        "inputs": {"osim": D._source_info(osim_path), "multifidus_osim": D._source_info(multifidus_osim_path)},
        "opensim_version": str(osim.__version__),
        "python_version": sys.version.split()[0],
        "date_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "geometry": D.GEOMETRY_GENERIC,
        "sign_convention": D.SIGN_CONVENTION.replace("; neutral posture (all intervertebral angles 0)", ""),
        "postures": {p: {"axis": POSTURES[p][0], "theta_deg": POSTURES[p][1]} for p in postures},
        "split": split,
        "coupling_slopes": slopes,
        "force_length_curve": "each muscle's own Millard2012EquilibriumMuscle ActiveForceLengthCurve (OpenSim "
                              "default quintic Bezier: min 0.4441, transition 0.73, max 1.8123 normalised fibre "
                              "length) at the fibre length of a rigid tendon at tendon slack length, fixed-width "
                              "pennation; factor_rel = factor / factor(neutral)",
        "checks": {"max_abs_computeMomentArm_minus_finite_difference_m": fd_max,
                   "twist_step_rad": TWIST_STEP,
                   "max_abs_twist_minus_joint_centre_axis_row": axis_err},
    }
    return out


def write_posture_tables(d: dict[str, Any], out_dir: Path | str, command_line: str) -> list[Path]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    prov = dict(d["provenance"])
    prov["command_line"] = command_line
    gi, mi = prov["inputs"]["osim"], prov["inputs"]["multifidus_osim"]
    head = [
        "derived by: python -m neckstrength.model.opensim.postures (see docs/postures.md)",
        f"source: {gi['file']} from {gi.get('repository')} commit {gi.get('commit')}, sha256 {gi['sha256']}",
        f"source: {mi['file']} from {mi.get('repository')} commit {mi.get('commit')}, sha256 {mi['sha256']}",
        f"opensim {prov['opensim_version']}; date {prov['date_utc']}; geometry: generic (as full_model_*.csv)",
    ]
    written = []
    names = [p for p in d if p != "provenance"]

    def _w(df: pd.DataFrame, fname: str, what: str, decimals: int) -> None:
        p = out / fname
        with open(p, "w", encoding="utf-8", newline="") as fh:
            fh.write("".join(f"# {ln}\n" for ln in [what, *head]))
            D._clean(df, decimals).to_csv(fh, index=False, lineterminator="\n")
        written.append(p)

    for name in names:
        _w(d[name]["moment_arms"], file_name("moment_arms", name),
           f"Moment arms (m), posture {name}; columns joint-major as full_model_moment_arms.csv; thesis signs", 6)
        _w(d[name]["coordinates"], file_name("coordinates", name),
           f"Joint coordinates in the skull frame, posture {name}: JT_* = skull twist (omega, v at the skull origin) "
           "per unit rotation = row [a, c x a] of J^T; axis a = omega/|omega|; centre c = joint centre (m)", 8)
        _w(d[name]["force_length"], file_name("force_length", name),
           f"Active force-length factor of each element, posture {name} (rigid tendon at slack length, the "
           "muscle's own Millard2012 ActiveForceLengthCurve); factor_rel = factor / factor(neutral)", 6)
    _w(pd.DataFrame([d[n]["angles"] for n in names]), POSTURES_CSV,
       "Postures: head-on-thorax rotation, the model's independent coordinates and every joint angle (rad)", 8)
    jac = []
    for name in names:
        co = d[name]["coordinates"].set_index("coordinate")
        for var, (space, joints) in KINEMATIC_VARIANTS.items():
            axes = ("pitch",) if space == "planar" else D.AXES
            comps = ("Mz", "Fx", "Fy") if space == "planar" else ("Mx", "My", "Mz", "Fx", "Fy", "Fz")
            for j in joints:
                for a in axes:
                    key = f"{j}_{a}"
                    jac.append({"posture": name, "variant": var, "coordinate": key,
                                **{c: (co.loc[key, f"JT_{c}"] if c in comps else np.nan)
                                   for c in ("Mx", "My", "Mz", "Fx", "Fy", "Fz")}})
    _w(pd.DataFrame(jac), JACOBIANS_CSV, "Skull-frame J^T (rows: coordinates of the variant; planar variants: "
       "Mz, Fx, Fy only) of every kinematic variant in every posture", 8)
    p = out / PROVENANCE
    prov["files"] = sorted(x.name for x in written)
    p.write_text(json.dumps(prov, indent=1, default=D._json_default) + "\n", encoding="utf-8")
    written.append(p)
    return written


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m neckstrength.model.opensim.postures",
                                 description="Derive posture-dependent model tables (issue 20).")
    ap.add_argument("--osim", required=True, type=Path)
    ap.add_argument("--multifidus-osim", required=True, type=Path)
    ap.add_argument("--out", default=Path("data/model/postures"), type=Path)
    ap.add_argument("--postures", nargs="*", default=None, help=f"subset of {list(POSTURES)} (default: all)")
    ap.add_argument("--split", default="range", help="'range' or the upper-neck share of each rotation (0-1)")
    args = ap.parse_args(argv)
    split = args.split if args.split == "range" else float(args.split)
    argv_list = list(sys.argv[1:] if argv is None else argv)
    # the model files are identified by sha256 in the provenance; their folder on the deriving machine is not
    # recorded (it would be meaningless elsewhere)
    for k, a in enumerate(argv_list[:-1]):
        if a in ("--osim", "--multifidus-osim"):
            argv_list[k + 1] = "<models>/" + Path(argv_list[k + 1]).name
    d = derive_postures(args.osim, args.multifidus_osim, args.postures, split)
    write_posture_tables(d, args.out, "python -m neckstrength.model.opensim.postures " + " ".join(argv_list))
    for name in d:
        if name != "provenance":
            a = d[name]["angles"]
            fl = d[name]["force_length"]["factor_rel"]
            print(f"{name}: skull rotation {a['skull_rotation_from_neutral_deg']:.2f} deg; factor_rel "
                  f"{fl.min():.3f}..{fl.max():.3f}")
    print(f"max |computeMomentArm - FD| = {d['provenance']['checks']['max_abs_computeMomentArm_minus_finite_difference_m']:.1e} m")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
