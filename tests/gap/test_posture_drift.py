"""posture_drift (issue 32 item 3): every test in its own posture, drifted along the torque it demands, from the
shipped posture tables; each test's LP with its own moment arms and J^T. Checked against the benchmark's truth
generator (:mod:`neckstrength.gap.truths`, separate code: J^T interpolated from the tables, its own drift
direction), which the diagnosis must name, with the drift near the truth's, and not name on data without a drift."""

import json
from pathlib import Path

import numpy as np
import pandas as pd

import neckstrength.gap.diagnose as dg
from neckstrength.estimation.parameters import free_parameters
from neckstrength.gap.effects import EFFECTS, POSTURE_AXES, base_instance, compose
from neckstrength.gap.fit import FitSettings, Simulator
from neckstrength.gap.truths import TruthForces, TruthSetup, make_forces

ROOT = Path(__file__).resolve().parents[2]


def test_posture_axes_are_the_shipped_tables():
    """The effect's axis and angle of each table are postures.csv's (the sign decides which way a test drifts)."""
    post = pd.read_csv(ROOT / "data" / "model" / "postures" / "postures.csv", comment="#")
    shipped = {r.posture: (r.axis, float(r.theta_deg)) for r in post.itertuples() if r.posture != "neutral"}
    assert shipped == POSTURE_AXES


def test_the_head_drifts_the_way_it_pushes(ctx_s3):
    """Pushing with the forehead flexes, with the back of the head extends, with the right temple bends to the right
    (positive roll, bendR15), with the left to the left; every test drifts by the whole angle."""
    ang = EFFECTS["posture_drift"](ctx_s3).drift_angles(base_instance(ctx_s3), 10.0)
    k = {n: i for i, n in enumerate(ctx_s3.directions["name"])}
    assert ang[k["forehead"], 0] < -9.9 and ang[k["backHigh"], 0] > 9.9
    assert ang[k["templeAboveR"], 1] > 5.0 > -5.0 > ang[k["templeAboveL"], 1]
    np.testing.assert_allclose(np.linalg.norm(ang, axis=1), 10.0)


def test_combines_with_added_rows_and_the_window(ctx_p2):
    """With kinematic's added rows and columns the drifted tests keep their own matrices (padded); with the exact
    window (each test's window with its own matrices) the forces are at least the target's."""
    e, kin, win = (EFFECTS[n](ctx_p2) for n in ("posture_drift", "kinematic", "direction_tolerance"))
    F = ctx_p2.model.strengths[None]
    drift = Simulator(ctx_p2, compose(ctx_p2, [e], [np.array([12.0])])).forces(F)[0]
    inst = compose(ctx_p2, [e, kin], [np.array([12.0]), np.array([0.5])])
    R, JT = inst.test_matrices()
    assert R.shape == (ctx_p2.K,) + inst.R.shape and JT.shape == (ctx_p2.K,) + inst.JT.shape
    f_kin = Simulator(ctx_p2, inst).forces(F)[0]
    assert np.all(f_kin <= drift * (1 + 1e-9)) and np.all(f_kin > 0)   # passive capacity can only take force away
    f_win = Simulator(ctx_p2, compose(ctx_p2, [e, win], [np.array([12.0]), np.array([0.5])])).forces(F)[0]
    assert np.all(f_win >= drift * (1 - 0.006)) and np.any(f_win > drift * 1.01)


def test_diagnosis_names_a_drift_made_by_the_truth_generator(ctx_s3):
    """Three s3m24 participants (strengths off the baseline, SD 0.2; 2% log-normal noise; seed 32) made by the
    benchmark's truth generator: an 11-deg posture drift, no effect, and a left/right asymmetry. The uncalibrated
    diagnosis with five candidates (posture_drift, asymmetry, submaximal_effort, origin_offset,
    anthropometric_scaling) names posture_drift for the drift, with drift_deg within 1.5 deg of 11, and halves the
    held-out RMS; for the other two its best drift is 0 and it names something else. (Fixed seed, no chance rate:
    the calibrated rate of such a decision is the benchmark's, docs/gap_diagnosis.md.)"""
    ctx = ctx_s3
    setup = TruthSetup(ctx.full, ctx.model, ctx.directions, ctx.head_centre, ctx.tie_sides, dict(ctx.postures))
    fc = TruthForces(setup)
    rng = np.random.default_rng(32)
    pidx, _ = free_parameters(ctx.model, ctx.tie_sides)
    f = ctx.model.strengths * np.exp(rng.normal(0, 0.2, int(pidx.max()) + 1))[pidx]
    # the two constructions agree to about 1% at the truth's drift (the candidate rebuilds J^T from the
    # interpolated joint centres and axes), against an effect of up to 20%
    clean = make_forces(setup, "posture_drift", f, {"drift_deg": 11.0}, fc)
    cand = Simulator(ctx, compose(ctx, [EFFECTS["posture_drift"](ctx)], [np.array([11.0])])).forces(f[None])[0]
    base = make_forces(setup, "none", f, {}, fc)
    assert np.max(np.abs(cand / clean - 1)) < 0.015 < 0.1 < np.max(np.abs(clean / base - 1))
    data = []
    for truth, par in (("posture_drift", {"drift_deg": 11.0}), ("none", {}), ("asymmetry", {"log_LR_ratio": 0.5})):
        T = make_forces(setup, truth, f, par, fc) * np.exp(rng.normal(0, 0.02, ctx.K))
        data.append(dg.BlindData(truth, T))
    s = dg.DiagnosisSettings(effects=("posture_drift", "asymmetry", "submaximal_effort", "origin_offset",
                                      "anthropometric_scaling"), grid_points=5, folds=5, pairs_top=0, bootstrap=50,
                             starts=1, reach_samples=0, reach_iter=0, fit=FitSettings(max_iter=10), seed=5)
    res = {r.name: r for r in dg.diagnose(ctx, data, s)}

    def drift(r):
        row = r.effects.set_index("candidate").loc["posture_drift"]
        return json.loads(row["theta_values"])["posture_drift"][0]

    r = res["posture_drift"]
    assert r.summary["chosen"] == "posture_drift"
    assert abs(drift(r) - 11.0) <= 1.5
    assert r.summary["rms_after"] < 0.5 * r.summary["rms_before"]
    for name in ("none", "asymmetry"):
        assert res[name].summary["chosen"] != "posture_drift" and drift(res[name]) == 0.0
