"""The shipped posture tables (data/model/postures, docs/postures.md).

Tolerances: the tables are written to 6 decimals (moment arms, m) and 8 decimals (Jacobian rows), so values that are
equal in the derivation agree to 0.5e-6 m / 0.5e-8 after rounding; 2e-6 allows for that. The re-derivation with
OpenSim compares with 2e-6 as the full-model test does.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from neckstrength.model.full import COORDINATES, load_full_model
from neckstrength.postures.tables import POSTURE_NAMES, check_posture_tables, load_posture_tables

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "data" / "model"
THESIS = ROOT / "data" / "thesis"


@pytest.fixture(scope="module")
def tables():
    return load_posture_tables(MODEL)


@pytest.fixture(scope="module")
def full():
    return load_full_model(MODEL, THESIS, "derived")


def test_all_issue_postures_are_shipped_with_provenance(tables):
    assert tuple(tables) == POSTURE_NAMES
    prov = json.loads((MODEL / "postures" / "postures_provenance.json").read_text())
    assert prov["opensim_version"] == "4.6"
    for k in ("osim", "multifidus_osim"):
        assert len(prov["inputs"][k]["sha256"]) == 64
    assert prov["command_line"].startswith("python -m neckstrength.model.opensim.postures")
    full_prov = json.loads((MODEL / "full_model_provenance.json").read_text())
    assert prov["inputs"]["osim"]["sha256"] == full_prov["inputs"]["osim"]["sha256"]
    for t in tables.values():
        assert t.moment_arms.shape == (21, 96) and t.JT.shape == (21, 6) and t.factor.shape == (96,)


def test_neutral_posture_reproduces_the_full_model_tables(tables, full):
    t = tables["neutral"]
    assert np.max(np.abs(t.moment_arms - full.moment_arms)) <= 2e-6
    assert np.max(np.abs(t.centres - full.centres)) <= 2e-6
    assert np.max(np.abs(t.axes - full.axes)) <= 2e-6
    np.testing.assert_allclose(t.factor_rel, 1.0, atol=1e-9)


def test_consistency_checks_pass_and_catch_a_broken_table(tables, full):
    errs = check_posture_tables(tables, full)
    assert max(errs.values()) <= 2e-6
    bad = dict(tables)
    R = tables["rotL30"].moment_arms.copy()
    R[COORDINATES.index("C0-C1_yaw"), 0] += 1e-3
    bad["rotL30"] = type(tables["rotL30"])(**{**tables["rotL30"].__dict__, "moment_arms": R})
    with pytest.raises(ValueError, match="mirror"):
        check_posture_tables(bad, full)


def test_postures_rotate_the_head_by_the_stated_angle_and_move_the_joints():
    post = pd.read_csv(MODEL / "postures" / "postures.csv", comment="#").set_index("posture")
    for p, theta in (("flex20", 20), ("ext20", 20), ("rotL30", 30), ("rotR30", 30), ("bendL15", 15), ("bendR15", 15)):
        assert post.loc[p, "skull_rotation_from_neutral_deg"] == pytest.approx(theta, abs=1e-3)
    # the joint angles of a single-axis posture add up to the head-on-thorax rotation
    joints = ["C0-C1", "C1-C2", "C2-C3", "C3-C4", "C4-C5", "C5-C6", "C6-C7", "C7-T1"]
    assert sum(post.loc["flex20", f"{j}_pitch"] for j in joints) == pytest.approx(math.radians(-20), abs=1e-7)
    assert sum(post.loc["rotL30", f"{j}_yaw"] for j in joints) == pytest.approx(math.radians(30), abs=1e-7)
    # C1-C2 carries the largest share of axial rotation (the file's couplers: 0.889 of the upper coordinate)
    yaw = {j: post.loc["rotL30", f"{j}_yaw"] for j in joints}
    assert max(yaw, key=yaw.get) == "C1-C2"


def test_posture_changes_geometry_and_force_length(tables):
    # extension tilts nothing out of the sagittal plane but moves the lower joint centres forward in the skull frame
    ext, flex = tables["ext20"], tables["flex20"]
    k = COORDINATES.index("C6-C7_pitch")
    assert abs(ext.centres[k, 2]) < 1e-9 and ext.centres[k, 0] < tables["neutral"].centres[k, 0]
    # axial rotation tilts the lower pitch axes out of the skull's z axis
    assert abs(tables["rotL30"].axes[k, 0]) > 0.3
    # extension shortens the posterior muscles: semispinalis capitis loses active force (descending limb otherwise)
    names = list(ext.names)
    i = names.index("semi cap sklc5")
    assert ext.factor_rel[i] != pytest.approx(1.0, abs=1e-3)
    assert np.max(np.abs(ext.moment_arms - flex.moment_arms)) > 1e-3


def test_rederive_posture_tables_matches_shipped(tmp_path):
    """With OpenSim (a test extra): neutral and ext20 re-derived from the reference models match the shipped
    tables (the derivation is deterministic; 2e-6 = CSV rounding)."""
    pytest.importorskip("opensim", exc_type=ImportError)  # missing or broken install (as the full-model test)
    from neckstrength.model.opensim import postures as P

    sys_path = Path(__file__).resolve().parents[1] / "model"
    import importlib.util

    spec = importlib.util.spec_from_file_location("_derive_test", sys_path / "test_opensim_derive.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    models = mod._reference_models()
    d = P.derive_postures(models / "Mortensen2014_rigidTorso.osim", models / "ModelOfNeckAndShoulder.osim",
                          ["neutral", "ext20"], fd_check=False)
    P.write_posture_tables(d, tmp_path, "test")
    for kind in ("moment_arms", "coordinates", "force_length"):
        for p in ("neutral", "ext20"):
            new = pd.read_csv(tmp_path / f"{kind}_{p}.csv", comment="#")
            old = pd.read_csv(MODEL / "postures" / f"{kind}_{p}.csv", comment="#")
            pd.testing.assert_frame_equal(new, old, check_exact=False, atol=2e-6, obj=f"{kind}_{p}")
