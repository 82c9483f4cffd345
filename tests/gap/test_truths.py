"""The user-facing benchmark's truths (gap.truths) and its model-free scoring (gap.scoring), issue 32 item 5."""

import ast
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from neckstrength.gap import truths as T
from neckstrength.gap.scoring import score_cases, wilson_interval
from neckstrength.postures import load_posture_tables
from neckstrength.wrench import solve

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def setup(cfg, ctx_s3):
    return T.TruthSetup(ctx_s3.full, ctx_s3.model, ctx_s3.directions, ctx_s3.head_centre, ctx_s3.tie_sides,
                        load_posture_tables(cfg["data"]["model_dir"]))


def _gap_imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return {n for n in names if n.startswith("neckstrength.gap")}


def test_truths_do_not_use_the_diagnosis_and_the_diagnosis_does_not_see_them():
    assert _gap_imports(ROOT / "src/neckstrength/gap/truths.py") == set()
    for mod in ("diagnose", "engine", "calibrate", "fit", "effects", "window"):
        assert not {"neckstrength.gap.truths", "neckstrength.gap.scoring"} & _gap_imports(
            ROOT / f"src/neckstrength/gap/{mod}.py")


def test_neutral_truths_reproduce_the_base_model(setup):
    fc = T.TruthForces(setup)
    f = setup.model.strengths * np.exp(np.random.default_rng(0).normal(0, 0.3, setup.model.m))
    base = fc.base(f)
    # the direction table's convention: w(u) / force_scale with u the table's unit wrench
    U = setup.directions[[f"u_{c}" for c in ("Mx", "My", "Mz", "Fx", "Fy", "Fz")]].to_numpy(float)
    w, _, _ = solve(setup.model, f[None], U, return_alpha=False)
    np.testing.assert_allclose(base, w[0] / setup.directions["force_scale"].to_numpy(float), rtol=1e-9)
    neutral = {"direction_error": {"push_direction": fc.N.tolist()}, "asymmetry": {"log_LR_ratio": 0.0},
               "origin_offset": {"dx_m": 0.0, "dy_m": 0.0}, "submaximal_effort": {"effort_min": 1.0, "v": [1, 0, 0]},
               "posture_drift": {"drift_deg": 0.0}, "anthropometric_scaling": {"head_scale": 0.0, "neck_scale": 0.0}}
    for truth, p in neutral.items():
        np.testing.assert_allclose(T.make_forces(setup, truth, f, p, fc), base, rtol=1e-9, err_msg=truth)
    # and a non-neutral size changes them
    moved = {"origin_offset": {"dx_m": 0.02, "dy_m": 0.0}, "posture_drift": {"drift_deg": 12.0},
             "anthropometric_scaling": {"head_scale": 0.1, "neck_scale": -0.1}}
    for truth, p in moved.items():
        assert np.max(np.abs(T.make_forces(setup, truth, f, p, fc) / base - 1)) > 0.01, truth


def test_direction_error_pushes_within_the_cone_and_takes_the_true_maximum(setup):
    fc = T.TruthForces(setup)
    rng = np.random.default_rng(3)
    s = T.CaseSettings(cone_deg=(12.0, 12.0))
    p = T.draw_params(setup, "direction_error", s, rng, fc)
    D = np.asarray(p["push_direction"])
    ang = np.degrees(np.arccos(np.clip(np.sum(D * fc.N, axis=1), -1, 1)))
    assert ang.max() <= 12.0 + 1e-9 and ang.min() >= 0 and np.ptp(ang) > 3.0
    np.testing.assert_allclose(ang, p["angle_deg"], atol=1e-6)
    f = setup.model.strengths
    got = T.make_forces(setup, "direction_error", f, p, fc)
    # the largest force along the drawn direction, checked with the reference LP (HiGHS) on 3 tests
    for k in (0, 7, 19):
        W = np.r_[np.cross(fc.P[k], D[k]), D[k]]
        w, _, _ = solve(setup.model, f[None], (W / np.linalg.norm(W))[None], method="highs", return_alpha=False)
        assert got[k] == pytest.approx(w[0, 0] / np.linalg.norm(W), rel=1e-6)


def test_drift_follows_the_demanded_torque():
    assert T.drift_weights(["pitch", "roll", "yaw"], np.array([2.0, 0.0, 0.0]), 10.0) == {"ext20": 0.5}
    w = T.drift_weights(["pitch", "roll", "yaw", "pitch"], np.array([-1.0, 0.0, -1.0, -2.0]), 15.0)
    # torque (pitch -3, yaw -1): flexion and right rotation, angles in that proportion
    assert set(w) == {"flex20", "rotR30"}
    assert w["flex20"] * 20 / (w["rotR30"] * 30) == pytest.approx(3.0)
    assert np.hypot(w["flex20"] * 20, w["rotR30"] * 30) == pytest.approx(15.0)


def test_measured_noise_interval_covers_the_true_scatter():
    """Calibration check of the repeats' chi-square interval: 400 simulated 25 x 3 trial sets at sigma 0.05."""
    rng = np.random.default_rng(20261127)
    hits = 0
    for _ in range(400):
        trials = 100 * np.exp(rng.normal(0, 0.05, (25, 3)))
        _, df, lo, hi = T.pooled_log_sd(trials)
        hits += lo <= 0.05 <= hi
    assert df == 50 and 0.92 <= hits / 400 <= 0.98


def test_generated_cases_are_stratified_producible_and_reproducible(setup):
    s = T.CaseSettings(replicates=2, controls=2, rich_controls=1)
    plan = T.stratified_plan(s)
    assert len(plan) == 2 + 1 + 2 * len(T.EFFECT_TRUTHS) and plan[0] == "none"
    a = T.generate_truth_cases(setup, s, np.random.default_rng(5), limit=9)
    b = T.generate_truth_cases(setup, s, np.random.default_rng(5))
    assert [c.truth for c in a] == plan[:9]
    for x, y in zip(a, b[:9]):
        np.testing.assert_array_equal(x.trials, y.trials)
    for c in b:
        assert c.trials.shape == (setup.directions.shape[0], 3)
        np.testing.assert_array_equal(c.forces, c.trials.max(axis=1))
        assert 0.5 * c.noise < c.noise_sd < 2 * c.noise and c.noise_low < c.noise_sd < c.noise_high
    with pytest.raises(ValueError, match="unknown truths"):
        T.generate_truth_cases(setup, T.CaseSettings(truths=("fatigue",)), np.random.default_rng(0))


def test_wilson_interval_reference_values():
    # Wilson (1927) score interval; 0/30 and 24/30 (e.g. Newcombe 1998, Stat Med 17:857, method 3)
    assert wilson_interval(0, 30) == pytest.approx((0.0, 0.1135), abs=1e-4)
    assert wilson_interval(24, 30) == pytest.approx((0.6269, 0.9049), abs=1e-4)
    assert all(np.isnan(wilson_interval(0, 0)))


def test_scoring_counts_detectable_cases_against_the_controls_threshold():
    rows = [{"case": f"c{i}", "truth": "none", "target": "none", "target_candidate": True,
             "named": "asymmetry" if i == 0 else "none", "gap_heldout_base": 0.01 * (i + 1),
             "gap_over_noise": 1.0, "consistent_with_noise": True, "rms_rel_heldout_base": 0.05,
             "noise_sigma": 0.05} for i in range(20)]
    rows += [{"case": "e1", "truth": "asymmetry", "target": "asymmetry", "target_candidate": True,
              "named": "asymmetry", "gap_heldout_base": 0.5, "gap_over_noise": 5.0, "consistent_with_noise": False,
              "rms_rel_heldout_base": 0.4, "noise_sigma": 0.05},
             {"case": "e2", "truth": "asymmetry", "target": "asymmetry", "target_candidate": True,
              "named": "none", "gap_heldout_base": 0.01, "gap_over_noise": 1.0, "consistent_with_noise": True,
              "rms_rel_heldout_base": 0.06, "noise_sigma": 0.05},
             {"case": "e3", "truth": "posture_drift", "target": "posture_drift", "target_candidate": False,
              "named": "none", "gap_heldout_base": 0.4, "gap_over_noise": 4.0, "consistent_with_noise": True,
              "rms_rel_heldout_base": 0.2, "noise_sigma": 0.05}]
    pc, tab, thr = score_cases(rows)
    assert thr == pytest.approx(np.quantile(0.01 * np.arange(1, 21), 0.95))
    assert list(pc.loc[pc["truth"] != "none", "detectable"]) == [True, False, True]
    t = tab.set_index("group")
    head = t.iloc[0]
    assert (head["cases"], head["count"]) == (1, 1)                  # e3 is not a candidate, e2 not detectable
    assert (t.iloc[1]["cases"], t.iloc[1]["count"]) == (2, 1)
    fa = t.iloc[2]
    assert (fa["cases"], fa["count"]) == (20, 1) and fa["goal_shown"] == "point estimate only"
    cwn = t.iloc[5]
    assert cwn["count"] == 1                                          # e3: consistent with noise at 4x the noise
    refit = t.iloc[6]                 # refitted residual known where nothing was named: 19 controls, e2, e3
    assert (refit["cases"], refit["count"]) == (21, 1)


def test_scoring_counts_the_second_reading_apart_from_the_decision():
    """The Bayes evidence's reading (summary["evidence"]) is scored against the same targets and controls as the
    decision, and a case without it is left out of its groups."""
    from neckstrength.gap.scoring import case_row

    effects = pd.DataFrame({"candidate": ["none", "asymmetry"], "gap_cv": [0.3, 0.1], "rms_rel_cv": [0.2, 0.05]})

    def one(name, truth, target, named, ev_named, gap):
        summ = {"named": named, "noise_sigma": 0.05, "gap_over_noise": 2.0,
                **({"evidence": {"named": ev_named, "best_effect": "asymmetry", "p_no_effect": 0.01,
                                 "fit_p_best_effect": 0.5}} if ev_named else {})}
        r = case_row(name, truth, target, ["asymmetry"], summ, effects.assign(gap_cv=[gap, gap / 2]))
        return r

    rows = [one(f"c{i}", "none", "none", "none", "asymmetry" if i == 0 else "none", 0.01 * (i + 1))
            for i in range(20)]
    rows += [one("e1", "asymmetry", "asymmetry", "none", "asymmetry", 0.5),
             one("e2", "asymmetry", "asymmetry", "asymmetry", "none", 0.6),
             one("e3", "asymmetry", "asymmetry", "asymmetry", None, 0.7)]
    assert rows[0]["evidence_named"] == "asymmetry" and "evidence_named" not in rows[-1]
    pc, tab, _ = score_cases(rows)
    t = tab.set_index("group")
    ev = t.loc["Bayes evidence reading: detectable effect cases whose target is a candidate: named correctly"]
    assert (ev["cases"], ev["count"]) == (2, 1)                      # e3 has no reading; e1 right, e2 wrong
    assert t.iloc[0]["count"] == 2                                    # the decision: e2 and e3
    fa = t.loc["Bayes evidence reading: controls: an effect named (false alarm)"]
    assert (fa["cases"], fa["count"]) == (20, 1)


def test_reduced_benchmark_runs_end_to_end(tmp_path):
    """The benchmark script on the CI config (p2m7): 3 cases, scored; a rerun resumes them."""
    cfg = ROOT / "config" / "config.ci.yaml"
    out = tmp_path / "users"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_gap_users.py"), "--config", str(cfg), "--out",
           str(out), "--limit", "3", "--replicates", "1", "--controls", "1", "--rich-controls", "1",
           "--null-replicates", "3", "--chunk", "3"]
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = [json.loads(x) for x in (out / "rows.jsonl").read_text().splitlines()]
    assert [x["truth"] for x in rows] == ["none", "rich96", "direction_error"]
    assert all(x["noise_source"] == "repeats" for x in rows)
    for x in rows:                     # the decision's inputs, for scoring other selection rules offline
        di = x["decision_inputs"]
        assert len(di["gap_obs"]) == 1 + len(di["effects"]) == 1 + len(di["mu"]) and len(di["t_null"]) == 3
        assert np.shape(di["delta_null"]) == (3, len(di["effects"])) and len(di["gap_null_none"]) == 3
    tab = pd.read_csv(out / "scores.csv")
    assert tab["group"].str.contains("false alarm").any()
    # the offline selection rules: maxT re-decided from the stored inputs reproduces the run's decisions
    sel = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_gap_selection.py"), str(out / "rows.jsonl")],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert sel.returncode == 0, sel.stderr[-2000:]
    assert "3 cases; re-decided, the run's decision differs in:" in sel.stdout and "largest_improvement 0" in sel.stdout
    assert "largest_improvement" in sel.stdout and "smallest_rms" in sel.stdout
    r2 = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r2.returncode == 0 and "3 cases (3 done before)" in r2.stdout
    r3 = subprocess.run(cmd + ["--only", "u002,u999"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r3.returncode != 0 and "--only: no case u999" in r3.stderr
