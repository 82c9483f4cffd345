"""Geometry: adjoint map, unit wrenches, Jacobian rows, reconstructed test directions."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from neckstrength.model.geometry import (
    HeadEllipsoid,
    assign_planes,
    direction_table,
    jacobian_transpose,
    read_point_spec,
    reconstruct_test_points,
    unit_wrench,
    wrench_from_force,
)

ROOT = Path(__file__).resolve().parents[2]
CFG = yaml.safe_load(open(ROOT / "config" / "config.yaml"))
HEAD = HeadEllipsoid(tuple(CFG["geometry"]["head"]["centre"]), tuple(CFG["geometry"]["head"]["semi_axes"]))
# Skull markers of Mortensen2014_rigidTorso.osim (skull frame, m; shared/models/README.md) and the
# Appendix A posterior pad centre (C0-C1 is 8 cm anterior and 2 cm inferior to it).
ANCHORS = {"GLA": (0.105, 0.064, -0.001), "RZF": (0.092, 0.015, 0.050), "RZP": (0.027, 0.021, 0.080),
           "pad": (-0.08, 0.02, 0.0)}


@pytest.fixture(scope="module")
def directions():
    pts = reconstruct_test_points(read_point_spec(ROOT / CFG["geometry"]["test_point_spec"]), HEAD)
    return assign_planes(direction_table(pts, HEAD))


def test_wrench_of_forward_push_on_forehead_is_flexion():
    # head pushes forward (+x) at a point above the origin: flexion moment (Mz < 0, pitch + = extension)
    w = wrench_from_force(np.array([0.1, 0.08, 0.0]), np.array([1.0, 0.0, 0.0]))
    assert np.allclose(w, [0, 0, -0.08, 1, 0, 0])


def test_moment_is_cross_product_and_independent_of_force_along_lever():
    rng = np.random.default_rng(1)
    for _ in range(20):
        p, F = rng.normal(size=3), rng.normal(size=3)
        w = wrench_from_force(p, F)
        assert np.allclose(w[:3], np.cross(p, F)) and np.allclose(w[3:], F)


def test_25_unit_wrenches_and_7_sagittal(directions):
    assert len(directions) == 25
    U = directions[[f"u_{c}" for c in ("Mx", "My", "Mz", "Fx", "Fy", "Fz")]].to_numpy()
    assert np.allclose(np.linalg.norm(U, axis=1), 1.0)
    sag = directions[directions["sagittal"]]
    assert sorted(sag["name"]) == sorted(["forehead", "backHigh", "back", "backLow", "noseBelow", "chinFront",
                                          "chinUnder"])
    # sagittal directions have no out-of-plane components (Mx, My, Fz)
    assert np.allclose(sag[["u_Mx", "u_My", "u_Fz"]].to_numpy(), 0.0, atol=1e-12)
    assert not np.any(np.isclose(directions[~directions["sagittal"]]["u_Fz"], 0.0))


def test_left_right_mirror(directions):
    d = directions.set_index("name")
    for r in [n for n in d.index if n.endswith("R") and n[:-1] + "L" in d.index]:
        a, b = d.loc[r], d.loc[r[:-1] + "L"]
        # mirror z -> -z: Mx, My, Fz flip; Mz, Fx, Fy stay
        assert np.allclose([a.u_Mz, a.u_Fx, a.u_Fy], [b.u_Mz, b.u_Fx, b.u_Fy])
        assert np.allclose([a.u_Mx, a.u_My, a.u_Fz], [-b.u_Mx, -b.u_My, -b.u_Fz])
        assert a.pz > 0 > b.pz


def test_outward_normals_point_away_from_head(directions):
    c = np.asarray(HEAD.centre)
    for r in directions.to_dict("records"):
        p = np.array([r["px"], r["py"], r["pz"]])
        n = np.array([r["nx"], r["ny"], r["nz"]])
        assert np.dot(p - c, n) > 0, r["name"]


def test_anchor_markers_lie_near_head_surface():
    for name, p in ANCHORS.items():
        assert abs(HEAD.radial_offset(np.array(p))) < 0.012, name


def test_pushing_back_is_extension_and_forward_is_flexion(directions):
    d = directions.set_index("name")
    for n in ("back", "backHigh", "backLow"):
        assert d.loc[n, "u_Mz"] > 0 and d.loc[n, "u_Fx"] < 0
    assert d.loc["forehead", "u_Mz"] < 0 and d.loc["forehead", "u_Fx"] > 0


def test_every_plane_of_the_grid_has_directions(directions):
    planes = {p for s in directions["planes"] for p in s.split(";")}
    assert len(planes) == 9


def test_jacobian_rows_give_moment_about_joint():
    rng = np.random.default_rng(3)
    c = rng.normal(scale=0.05, size=(4, 3))
    a = rng.normal(size=(4, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    JT = jacobian_transpose(c, a)
    for _ in range(10):
        w = rng.normal(size=6)
        M, F = w[:3], w[3:]
        for i in range(4):
            assert JT[i] @ w == pytest.approx(a[i] @ (M - np.cross(c[i], F)))


def test_unit_wrench_scale_converts_force():
    p = np.array([0.1, 0.05, 0.0])
    u, s = unit_wrench(p, np.array([1.0, 0, 0]))
    assert s == pytest.approx(np.sqrt(1 + 0.05 ** 2))
    assert np.allclose(u * s, wrench_from_force(p, np.array([1.0, 0, 0])))


def test_written_directions_read_back_exactly(tmp_path):
    """The pipeline's directions file holds the directions the command line builds in memory, to the last bit
    (rounded to 6 decimals, a gap diagnosis's p-value differed between the two paths)."""
    from neckstrength.config import build_directions, load_config
    from neckstrength.pipeline.common import load_directions
    from neckstrength.pipeline.model import model_directions

    cfg = load_config(ROOT / "config" / "config.yaml")
    out = tmp_path / "directions.csv"
    model_directions(cfg, out)
    built, read = build_directions(cfg), load_directions(out)
    num = built.select_dtypes("number").columns
    assert list(read.columns) == list(built.columns)
    assert np.array_equal(read[num].to_numpy(float), built[num].to_numpy(float), equal_nan=True)
