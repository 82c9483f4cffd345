"""Skull frame, test points, unit wrenches and skull-frame Jacobians.

Conventions (thesis Sec. 4.2.3.1 and Appendix A):

- Skull frame: origin at the C0-C1 joint centre, x anterior, y superior, z right.
- A wrench is ordered ``(Mx, My, Mz, Fx, Fy, Fz)`` and is the wrench the head
  exerts on the measuring device, resolved at the skull-frame origin. A force
  ``F`` applied at point ``p`` gives ``w = (p x F, F)``: this is the adjoint map
  of Sec. 4.2.3.1 written out (the thesis prints ``[[R, 0], [p^ R, R]]`` acting
  on the force, whose moment block is ``p x F`` for ``R = I``).
- Joint coordinates: pitch = rotation about +z (extension +), roll = about +x
  (right side-bend +), yaw = about +y (left rotation +), matching Table B.1.
- The torque a skull wrench ``w`` demands at a joint coordinate with unit axis
  ``a`` through centre ``c`` is ``a . (M - c x F) = [a, c x a] . w``; stacking
  these rows gives ``J^T`` (n x 6), the transpose of the skull-frame Jacobian.
- The planar task space is ``(Mz, Fx, Fy)`` (Sec. 4.2.1.1).

Test-point coordinates are not in the thesis. :func:`reconstruct_test_points`
rebuilds them on an ellipsoidal head surface anchored to skull markers of the
public OpenSim neck model and to Appendix A; see ``docs/geometry.md``. A user
with measured coordinates supplies a points table instead (config
``geometry.test_points``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.io import Column, DataValidationError, Schema, read_table

WRENCH_COMPONENTS = ("Mx", "My", "Mz", "Fx", "Fy", "Fz")


PLANAR_COMPONENTS = ("Mz", "Fx", "Fy")


PLANAR_INDEX = np.array([2, 3, 4])


AXIS_VECTORS = {"pitch": np.array([0.0, 0.0, 1.0]), "roll": np.array([1.0, 0.0, 0.0]),
                "yaw": np.array([0.0, 1.0, 0.0])}


#: Header lines of a written direction table (``results/geometry/directions.csv``).
DIRECTIONS_HEADER = ["test directions: points and outward normals (skull frame, m), unit wrenches "
                     "u = (p x n, n)/|.| ordered (Mx,My,Mz,Fx,Fy,Fz)",
                     "force_scale = |(p x n, n)|: force (N) = LP wrench magnitude / force_scale",
                     "geometry is a reconstruction unless method = measured (docs/geometry.md)"]


def skew(p: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``p^`` with ``p^ v = p x v`` (thesis Sec. 4.2.3.1)."""
    px, py, pz = p
    return np.array([[0.0, -pz, py], [pz, 0.0, -px], [-py, px, 0.0]])


def adjoint_force(p: np.ndarray) -> np.ndarray:
    """6x3 map from a force applied at ``p`` to the skull-frame wrench ``(p x F, F)``."""
    return np.vstack([skew(np.asarray(p, float)), np.eye(3)])


def wrench_from_force(p: np.ndarray, force: np.ndarray) -> np.ndarray:
    """Skull-frame wrench ``(M, F)`` of force ``force`` applied at point ``p``."""
    return adjoint_force(p) @ np.asarray(force, float)


def unit_wrench(p: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, float]:
    """Unit wrench ``u`` of a unit force along ``n`` at ``p``, and the norm before scaling.

    The norm ``s = |(p x n, n)|`` converts between the LP's wrench magnitude
    ``w`` (in the mixed N / N*m norm of the thesis) and the applied force:
    ``force = w / s``.
    """
    n = np.asarray(n, float)
    n = n / np.linalg.norm(n)
    w = wrench_from_force(p, n)
    s = float(np.linalg.norm(w))
    return w / s, s


@dataclass(frozen=True)
class HeadEllipsoid:
    """Axis-aligned ellipsoid standing in for the cranial surface (skull frame, m)."""

    centre: tuple[float, float, float]
    semi_axes: tuple[float, float, float]

    def point(self, azimuth_deg: float, elevation_deg: float) -> tuple[np.ndarray, np.ndarray]:
        """Surface point and outward unit normal.

        Azimuth is measured in the transverse plane from +x (anterior) towards +z
        (right); elevation from the transverse plane through the centre towards +y.
        """
        az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
        c = np.asarray(self.centre, float)
        a = np.asarray(self.semi_axes, float)
        d = np.array([np.cos(el) * np.cos(az), np.sin(el), np.cos(el) * np.sin(az)])
        p = c + a * d
        n = (p - c) / a**2
        return p, n / np.linalg.norm(n)

    def implicit(self, p: np.ndarray) -> float:
        """``sum(((p - c) / a)^2)``: 1 on the surface, < 1 inside."""
        return float(np.sum(((np.asarray(p) - np.asarray(self.centre)) / np.asarray(self.semi_axes)) ** 2))

    def radial_offset(self, p: np.ndarray) -> float:
        """Signed distance-like offset of ``p`` from the surface along the ray from the centre (m)."""
        c = np.asarray(self.centre, float)
        v = np.asarray(p, float) - c
        r = np.linalg.norm(v)
        return float(r - r / np.sqrt(self.implicit(p)))


SPEC_SCHEMA = Schema(
    name="test-point specification",
    columns=(
        Column("name", "str"),
        Column("mirror_of", "str", required=False, allow_missing=True),
        Column("method", "str", choices=("ellipsoid", "landmark")),
        Column("azimuth_deg", "float", "deg", -180, 180, allow_missing=True),
        Column("elevation_deg", "float", "deg", -90, 90, allow_missing=True),
        Column("px", "float", "m", -0.3, 0.3, allow_missing=True),
        Column("py", "float", "m", -0.3, 0.3, allow_missing=True),
        Column("pz", "float", "m", -0.3, 0.3, allow_missing=True),
        Column("nx", "float", "1", -1, 1, allow_missing=True),
        Column("ny", "float", "1", -1, 1, allow_missing=True),
        Column("nz", "float", "1", -1, 1, allow_missing=True),
        Column("rationale", "str", required=False, allow_missing=True),
    ),
    unique=("name",),
)


POINTS_SCHEMA = Schema(
    name="test points (skull frame)",
    columns=(
        Column("name", "str"),
        Column("px", "float", "m", -0.3, 0.3),
        Column("py", "float", "m", -0.3, 0.3),
        Column("pz", "float", "m", -0.3, 0.3),
        Column("nx", "float", "1", -1, 1),
        Column("ny", "float", "1", -1, 1),
        Column("nz", "float", "1", -1, 1),
    ),
    unique=("name",),
)


def reconstruct_test_points(spec: pd.DataFrame, head: HeadEllipsoid) -> pd.DataFrame:
    """Build the test-point table (point, outward normal) from a specification.

    ``spec`` rows have ``method`` 'ellipsoid' (azimuth/elevation on ``head``) or
    'landmark' (explicit point and normal, for the face where the cranial
    ellipsoid does not apply). A row with ``mirror_of`` set is the left/right
    mirror (z -> -z) of the named row.
    """
    rows = {}
    order = []
    for r in spec.to_dict("records"):
        name = r["name"]
        order.append(name)
        if r.get("mirror_of"):
            continue
        if r["method"] == "ellipsoid":
            p, n = head.point(r["azimuth_deg"], r["elevation_deg"])
        else:
            p = np.array([r["px"], r["py"], r["pz"]], float)
            n = np.array([r["nx"], r["ny"], r["nz"]], float)
            n = n / np.linalg.norm(n)
        rows[name] = (p, n, r["method"])
    for r in spec.to_dict("records"):
        src = r.get("mirror_of")
        if not src:
            continue
        if src not in rows:
            raise DataValidationError(spec.attrs.get("source", "test-point spec"),
                                      f"mirror_of refers to unknown point '{src}'", field_name="mirror_of")
        p, n, m = rows[src]
        flip = np.array([1.0, 1.0, -1.0])
        rows[r["name"]] = (p * flip, n * flip, m)
    out = []
    for name in order:
        p, n, m = rows[name]
        out.append({"name": name, "px": p[0], "py": p[1], "pz": p[2], "nx": n[0], "ny": n[1], "nz": n[2],
                    "method": m})
    return pd.DataFrame(out)


def direction_table(points: pd.DataFrame, head: HeadEllipsoid | None = None,
                    sagittal_tol: float = 1e-9) -> pd.DataFrame:
    """Add unit wrenches, force scale, sagittal flag and head-centred angles to a points table."""
    recs = []
    for r in points.to_dict("records"):
        p = np.array([r["px"], r["py"], r["pz"]])
        n = np.array([r["nx"], r["ny"], r["nz"]])
        u, s = unit_wrench(p, n)
        rec = dict(r)
        for k, c in enumerate(WRENCH_COMPONENTS):
            rec[f"u_{c}"] = u[k]
        rec["force_scale"] = s
        rec["sagittal"] = bool(abs(p[2]) <= sagittal_tol and abs(n[2]) <= sagittal_tol)
        if head is not None:
            v = p - np.asarray(head.centre)
            rec["azimuth_deg"] = float(np.degrees(np.arctan2(v[2], v[0])))
            rec["elevation_deg"] = float(np.degrees(np.arcsin(v[1] / np.linalg.norm(v))))
        recs.append(rec)
    return pd.DataFrame(recs)


def assign_planes(directions: pd.DataFrame, elevation_bands: Sequence[float] = (-30.0, 20.0),
                  azimuth_bands: Sequence[float] = (60.0, 120.0)) -> pd.DataFrame:
    """Membership of each direction in the 3x3 plane grid of Fig. 4.2.

    Sagittal row: by side (z > 0 right, z = 0 mid, z < 0 left). Transverse row:
    by elevation (inferior <= bands[0] < mid < bands[1] <= superior). Coronal row:
    by |azimuth| (anterior < bands[0] <= mid <= bands[1] < posterior). The thesis
    draws these planes without coordinates; the bands are configurable.
    """
    out = []
    for r in directions.to_dict("records"):
        planes = []
        z = r["pz"]
        planes.append("sagittal_right" if z > 1e-6 else ("sagittal_left" if z < -1e-6 else "sagittal_mid"))
        el = r["elevation_deg"]
        planes.append("transverse_inferior" if el <= elevation_bands[0]
                      else ("transverse_superior" if el >= elevation_bands[1] else "transverse_mid"))
        az = abs(r["azimuth_deg"])
        planes.append("coronal_anterior" if az < azimuth_bands[0]
                      else ("coronal_posterior" if az > azimuth_bands[1] else "coronal_mid"))
        out.append({"name": r["name"], "planes": ";".join(planes)})
    return directions.merge(pd.DataFrame(out), on="name")


PLANE_GRID = (("sagittal_right", "sagittal_mid", "sagittal_left"),
              ("transverse_superior", "transverse_mid", "transverse_inferior"),
              ("coronal_anterior", "coronal_mid", "coronal_posterior"))


def plane_angle(row: dict, plane: str) -> float:
    """Polar angle of a direction's point within a plane, for radar plots (radians)."""
    x, y, z = row["px"], row["py"], row["pz"]
    if plane.startswith("sagittal"):
        return float(np.arctan2(y, x))
    if plane.startswith("transverse"):
        return float(np.arctan2(z, x))
    return float(np.arctan2(y, z))


def read_test_points(path: str | Path) -> pd.DataFrame:
    """Read a user/derived test-point table and check unit normals."""
    df = read_table(path, POINTS_SCHEMA)
    for i, r in enumerate(df.to_dict("records")):
        nn = np.linalg.norm([r["nx"], r["ny"], r["nz"]])
        if abs(nn - 1.0) > 1e-3:
            raise DataValidationError(path, f"normal has length {nn:.4f}, must be a unit vector", i + 1,
                                      None, "nx")
    return df


def read_point_spec(path: str | Path) -> pd.DataFrame:
    return read_table(path, SPEC_SCHEMA)


def jacobian_transpose(centres: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """``J^T`` (n x 6) for joint coordinates with unit ``axes`` through ``centres``.

    Row i is ``[a_i, c_i x a_i]``: the torque about coordinate i demanded by a
    unit skull wrench component (Sec. 4.2.1.3).
    """
    centres = np.atleast_2d(np.asarray(centres, float))
    axes = np.atleast_2d(np.asarray(axes, float))
    return np.hstack([axes, np.cross(centres, axes)])
