"""The import on the SYNTHETIC example lab and the Appendix A rules it applies."""

import numpy as np
import pandas as pd
import pytest

from neckstrength.io import read_activations, read_measurements
from neckstrength.model.geometry import wrench_from_force
from neckstrength.trials import MatchSettings, default_frames, match, select_trials, to_skull, write_import
from neckstrength.trials.resolve import wrench_parts


def test_pad_frame_resolves_to_c0():
    # a force at a point 5 cm above the pad centre: C0-C1 is 8 cm anterior and 2 cm inferior to the pad centre
    pad = default_frames()["pad"]
    assert np.allclose(pad.origin, (-0.08, 0.02, 0.0))
    p_skull = np.array([-0.08, 0.07, 0.0])
    F = np.array([-100.0, 10.0, 20.0])
    w_pad = wrench_from_force(p_skull - np.array(pad.origin), F)      # measured about the pad centre
    assert np.allclose(to_skull(w_pad, pad), wrench_from_force(p_skull, F))
    moved = default_frames(pad_to_c0_m=(0.10, -0.02, 0.0))["pad"]
    assert not np.allclose(to_skull(w_pad, moved), wrench_from_force(p_skull, F))


def test_rotated_frame():
    R = ((0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0))       # frame axes rotated 90 deg about z
    fr = default_frames(extra={"cell": {"origin": [0, 0, 0], "rotation": R}})["cell"]
    assert np.allclose(to_skull(np.array([0, 0, 0, 1.0, 0, 0]), fr), [0, 0, 0, 0, 1.0, 0])
    with pytest.raises(ValueError, match="orthonormal"):
        default_frames(extra={"bad": {"rotation": [[2, 0, 0], [0, 1, 0], [0, 0, 1]]}})


def _rot(v, deg):
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return R @ v


def test_direction_window_eq_a2():
    u = np.array([0.0, 0.0, -0.048, 0.917, 0.395, 0.0])          # 'forehead'
    u = u / np.linalg.norm(u)
    s = MatchSettings()
    for deg, ok in ((15, True), (25, False)):
        w = 100 * np.r_[u[:3], _rot(u[3:], deg)]
        m = match(w, u, s)
        assert m["matched"] is ok and m["angle_F_deg"] == pytest.approx(deg, abs=1e-6)
    # same directions, moment part x4: R_fm moves by more than 0.10
    w = 100 * np.r_[4 * u[:3], u[3:]]
    m = match(w, u, s)
    assert not m["matched"] and m["R_fm_error"] > 0.10 and "R_fm" in m["mismatch"]
    Mu, Fu, r = wrench_parts(u)
    assert r == pytest.approx(np.linalg.norm(u[3:]) / (np.linalg.norm(u[:3]) + np.linalg.norm(u[3:])))
    # pure moment target (cardinal): force direction ignored, moment angle judged
    ext = np.array([0, 0, 1.0, 0, 0, 0])
    assert match(np.array([0, 0, 30.0, -50, 0, 0]), ext, s, cardinal=True)["matched"]
    assert not match(np.r_[30 * _rot(np.array([0, 0, 1.0]), 0) + [15, 0, 0], 0, 0, 0], ext, s, cardinal=True)[
        "matched"]


def _trials(mags, matched=None):
    n = len(mags)
    return pd.DataFrame({"participant": "P01", "direction": "back", "block": "main", "trial": np.arange(1, n + 1),
                         "magnitude": mags, "matched": matched if matched is not None else [True] * n,
                         "mismatch": ["" if (matched is None or m) else "force direction off" for m in
                                      (matched or [True] * n)]})


def test_repeat_rule_keeps_largest_and_flags_missing_third():
    s = select_trials(_trials([100.0, 105.0]))
    assert list(s["kept"]) == [False, True] and s.loc[1, "flag"] == "" and "not the largest" in s.loc[0, "reason"]
    s = select_trials(_trials([100.0, 115.0]))
    assert "no third" in s.loc[1, "flag"]
    s = select_trials(_trials([100.0, 115.0, 112.0]))
    assert list(s["kept"]) == [False, True, False] and s.loc[1, "flag"] == ""
    s = select_trials(_trials([100.0, 130.0, 90.0], [True, False, True]))
    assert list(s["kept"]) == [True, False, False] and s.loc[1, "reason"].startswith("direction not matched")
    s = select_trials(_trials([100.0, 130.0, 90.0], [True, False, True]), mismatch_action="flag")
    assert list(s["kept"]) == [False, True, False] and "not matched" in s.loc[1, "flag"]


def test_example_import(example_import, directions):
    r = example_import
    sel = r.selected
    # every trial not kept has a reason; every mismatched trial is excluded for it; at most one kept per set
    assert (sel.loc[~sel["kept"], "reason"] != "").all()
    assert (~sel.loc[~sel["matched"], "kept"]).all()
    assert sel.groupby(["participant", "direction", "block"])["kept"].sum().max() == 1
    mism = sel[~sel["matched"]]
    assert len(mism) == r.summary["excluded_mismatch"] > 0
    big = np.fmax(mism["angle_M_deg"].fillna(0), mism["angle_F_deg"].fillna(0)) > 20
    assert (big | (mism["R_fm_error"] > 0.10)).all()
    assert r.summary["fatigued"] == ["P03"]
    f = r.fatigue.set_index("participant")
    assert f.loc["P03", "mean_change_rel"] < -0.15 and abs(f.loc["P01", "mean_change_rel"]) < 0.10
    assert r.emg_missing.to_dict("records") == [{"participant": "P02", "channel": "LS_L"}]
    # P02's wrenches are in the pad frame: after resolution they match as well as the skull-frame participants
    share = sel[~sel["direction"].isin(["extension", "flexion", "sidebendR", "sidebendL", "rotationR", "rotationL"])
                ].groupby("participant")["matched"].mean()
    assert share["P02"] > 0.75 and share["P01"] > 0.75
    # a cell without a value is listed
    ex = r.exclusions
    miss = ex[ex["what"] == "direction"]
    assert len(miss) == r.summary["missing_directions"]
    for row in miss.itertuples():
        assert np.isnan(r.max_force.set_index("direction").loc[row.direction, row.participant])


def test_example_outputs_load_in_pipeline_layouts(example_import, directions, tmp_path):
    from neckstrength.trials import default_outputs

    outputs = default_outputs(tmp_path)
    write_import(example_import, outputs)
    m = read_measurements(outputs["max_force"], list(directions["name"]))
    a = read_activations(outputs["activation"], list(directions["name"]))
    assert list(m.columns) == ["P01", "P02", "P03"] and len(m) == 25
    v = a.to_numpy(float)
    assert np.isnan(v).sum() == 1 and np.nanmin(v) >= 0 and np.nanmax(v) <= 1     # P01 has no chinUnder value
    by = pd.read_csv(outputs["activation_by_muscle"], comment="#")
    assert by[(by["participant"] == "P02") & (by["muscle"] == "LS") & (by["side"] == "L")]["activation"].isna().all()
    text = outputs["report"].read_text()
    assert "P03 | 6 |" in text and "YES" in text and "direction not matched" in text
    assert outputs["figure"].stat().st_size > 10000
