"""The deficit decision (issue 31): hypothesis priors, evidence, Bayes factor, undo, the study's summaries."""

from __future__ import annotations

import math
from dataclasses import fields
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.stats import truncnorm, uniform

from neckstrength.estimation.datasets import simulated_dataset, thesis_f_actual
from neckstrength.sequential.cohort import CohortSettings, draw_truth
from neckstrength.sequential.decision import DecisionSettings, DeficitDecision, HypothesisPrior
from neckstrength.sequential.decision_study import reliability_table, roc_auc, roc_table, sequential_table
from neckstrength.sequential.joint import JointPosterior, JointSettings
from neckstrength.wrench import solve

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def p2m7(p2m7_full_config):
    _, model, directions = p2m7_full_config
    fa = thesis_f_actual(model, ROOT / "data" / "thesis", "Sim", table="table_6_1_p2m7_sequential.csv")
    data = simulated_dataset(model, directions, "Sim", fa)
    return model, data


def test_hypothesis_priors_are_normalised_truncated_normals_and_uniforms():
    """log_pdf against scipy's truncnorm / uniform (an independent implementation); draws inside the support."""
    f0 = np.array([100.0, 200.0, 50.0])
    g = np.array([0])
    x = np.array([[45.0, 230.0, 40.0], [70.0, 150.0, 60.0]])
    for deficit in (False, True):
        p = HypothesisPrior(f0, 0.3, g, (0.2, 0.6), deficit)
        ref = np.zeros(len(x))
        for j in range(3):
            if j == 0 and deficit:
                ref += uniform(loc=20.0, scale=40.0).logpdf(x[:, j])
            else:
                lo = 60.0 if j == 0 else 0.0
                sd = 0.3 * f0[j]
                ref += truncnorm((lo - f0[j]) / sd, np.inf, loc=f0[j], scale=sd).logpdf(x[:, j])
        got = p.log_pdf(x)
        fin = np.isfinite(ref)
        assert np.array_equal(np.isfinite(got), fin)
        assert np.allclose(got[fin], ref[fin], rtol=1e-10)
        F = p.sample(20000, np.random.default_rng(3))
        assert np.all(np.isfinite(p.log_pdf(F)))
        if deficit:
            assert F[:, 0].min() >= 20.0 and F[:, 0].max() <= 60.0
            assert abs(F[:, 0].mean() - 40.0) < 0.5
        else:
            assert F[:, 0].min() >= 60.0
            a = (60.0 - 100.0) / 30.0
            assert abs(F[:, 0].mean() - truncnorm(a, np.inf, loc=100, scale=30).mean()) < 0.6


def test_evidence_matches_plain_importance_sampling_from_the_prior(p2m7):
    """log p(y) of three tests from the sequential sampler (tempering, resampling) against the plain Monte Carlo
    mean of the likelihood over 100,000 prior draws (a reference the sampler does not define)."""
    model, data = p2m7
    f0 = model.strengths
    settings = JointSettings(n_candidates=3000, noise_rel=0.05, resample_ess=0.3, n_moves=3, max_resamples=20)
    tests = data.directions[:3]
    post = JointPosterior(model, data.directions, data.U, data.force_scale, f0, settings, np.random.default_rng(5))
    for d in tests:
        post.update(d, float(data.forces[data.directions.index(d)]))
    ref = JointPosterior(model, data.directions, data.U, data.force_scale, f0,
                         JointSettings(n_candidates=100_000, noise_rel=0.05), np.random.default_rng(6))
    ll = np.zeros(100_000)
    for d in tests:
        i = data.directions.index(d)
        w = data.forces[i] * data.force_scale[i]
        ll += ref._test_loglik(ref.W[:, i], w)
    log_z_ref = float(np.log(np.mean(np.exp(ll - ll.max()))) + ll.max())
    assert post.n_resamples >= 1                                  # the tempering and resampling path was used
    assert post.log_evidence == pytest.approx(log_z_ref, abs=max(0.3, 4 * math.sqrt(post.log_evidence_var)))


def test_decision_undo_equals_replay_and_evidence_favours_the_truth(p2m7):
    model, data = p2m7
    f0 = model.strengths
    s = DecisionSettings(group=("TS-E",), n_candidates=400, n_moves=2)
    js = JointSettings()
    fa = f0.copy()
    gi = s.group_indices(model.muscle_names)
    fa[gi] *= 0.3
    w, _, st = solve(model, fa[None], data.U)
    forces = w[0] / data.force_scale
    a = DeficitDecision(model, data.directions, data.U, data.force_scale, f0, s, js, np.random.default_rng(11))
    b = DeficitDecision(model, data.directions, data.U, data.force_scale, f0, s, js, np.random.default_rng(11))
    d0, d1 = data.directions[:2]
    a.push(d0, forces[0])
    a.push(d1, forces[1] * 1.3)            # a mis-entry, undone
    a.undo()
    a.push(d1, forces[1])
    b.push(d0, forces[0])
    b.push(d1, forces[1])
    assert a.log_bf() == b.log_bf() and a.p_deficit() == b.p_deficit()
    assert np.array_equal(a.posts["deficit"].F, b.posts["deficit"].F)
    for d in data.directions[2:]:
        a.push(d, forces[data.directions.index(d)])
    assert a.log_bf() > 0.0 and a.decision() != "no deficit"        # the forces favour the true hypothesis
    assert 0 <= a.p_deficit(prevalence=0.1) < a.p_deficit() < a.p_deficit(prevalence=0.9) <= 1
    est = a.estimate()
    assert list(est["muscle"]) == list(model.muscle_names) and np.all(est["sd_c"] >= 0)
    sc = a.scores() if a.remaining else None
    assert sc is None or np.all(sc["score"] >= 0)


def test_decision_eig_prefers_a_test_that_separates_the_hypotheses(p2m7):
    """Before any test, the direction whose force moves most with the deficit group scores highest."""
    model, data = p2m7
    f0 = model.strengths
    s = DecisionSettings(group=("TS-E",), n_candidates=1500)
    dec = DeficitDecision(model, data.directions, data.U, data.force_scale, f0, s, JointSettings(),
                          np.random.default_rng(2))
    sc = dec.scores().set_index("direction")["score"]
    gi = s.group_indices(model.muscle_names)
    weak = f0.copy()
    weak[gi] *= 0.4
    w, _, _ = solve(model, np.vstack([f0, weak]), data.U)
    drop = pd.Series(np.log(w[0] / w[1]), index=data.directions)
    assert sc.idxmax() in set(drop.nlargest(3).index)
    assert sc[drop.idxmin()] < sc.max()


def test_settings_validate_and_config_defaults_match_the_dataclass():
    from neckstrength.config import decision_settings, load_config

    with pytest.raises(ValueError, match="prevalence"):
        DecisionSettings(prevalence=1.0)
    with pytest.raises(ValueError, match="deficit_range"):
        DecisionSettings(deficit_range=(0.6, 0.2))
    cfg = load_config(ROOT / "config" / "config.yaml")
    got = decision_settings({"clinician": {"decision": {}}})
    assert got == DecisionSettings()
    with pytest.raises(ValueError, match="unknown settings"):
        decision_settings({"clinician": {"decision": {"prevalance": 0.2}}})
    import yaml

    schema = yaml.safe_load((ROOT / "workflow" / "schemas" / "config.schema.yaml").read_text())
    props = schema["properties"]["clinician"]["properties"]["decision"]["properties"]
    defaults = {f.name: f.default for f in fields(DecisionSettings)}
    for k, v in props.items():
        want = defaults[k]
        assert (tuple(v["default"]) if isinstance(v["default"], list) else v["default"]) == want, k
    assert decision_settings(cfg).noise == cfg["clinician"]["decision"]["noise"]


def test_cohort_truths_stay_in_their_classes():
    f0 = np.full(6, 100.0)
    names = ["mf-R", "mf-L", "trap-R", "trap-L", "SCM-R", "SCM-L"]
    c = CohortSettings(n_deficit=1, n_normal=1)
    rng = np.random.default_rng(0)
    for _ in range(200):
        d = draw_truth(f0, names, ("mf",), True, c, rng)
        n = draw_truth(f0, names, ("mf",), False, c, rng)
        assert np.all((d[:2] >= 20) & (d[:2] <= 60)) and np.all(n[:2] >= 60)
    # the other groups vary (population spread), sides close to each other
    many = np.array([draw_truth(f0, names, ("mf",), False, c, rng) for _ in range(500)])
    assert 0.2 < np.log(many[:, 2]).std() < 0.3
    assert np.abs(np.log(many[:, 2] / many[:, 3])).mean() < 0.1


def _fake_runs():
    rows = []
    rng = np.random.default_rng(1)
    for i in range(40):
        kind = "deficit" if i < 20 else "normal"
        for t in range(0, 6):
            lbf = (t * (1.0 if kind == "deficit" else -1.0)) + rng.normal(0, 1.0)
            p = 1 / (1 + math.exp(-lbf))
            rows.append({"participant": i, "kind": kind, "true_ratio": 0.4 if kind == "deficit" else 1.0,
                         "protocol": "forces", "t": t, "log_bf": lbf, "p_deficit": p})
    return pd.DataFrame(rows)


def test_study_summaries():
    assert roc_auc(np.array([3.0, 2.0]), np.array([1.0, 0.0])) == 1.0
    assert roc_auc(np.array([1.0]), np.array([1.0])) == 0.5
    runs = _fake_runs()
    roc = roc_table(runs, (1, 5), 0.05, 0.95)
    assert list(roc["t"]) == [1, 5]
    assert roc["auc"].iloc[1] > roc["auc"].iloc[0] > 0.5
    assert roc["sensitivity_at_fa0.05"].between(0, 1).all()
    per, seq = sequential_table(runs, 0.95)
    assert set(per["decision"]) <= {"deficit", "no deficit", "undecided"}
    dd = seq.set_index("kind")
    assert dd.loc["deficit", "share_deficit"] > 0.5 and dd.loc["normal", "share_no_deficit"] > 0.5
    rel = reliability_table(runs, (1, 5))
    assert rel["n"].sum() == 80 and (rel["ci95_low"] <= rel["share_with_deficit"]).all()
    assert (rel["share_with_deficit"] <= rel["ci95_high"]).all()


def test_estimate_writes_the_decision_for_a_model_with_the_group(tmp_path):
    """`neckstrength estimate` runs the same decision on the participant's table (s3m24, CI sizes)."""
    import os

    from neckstrength.config import build_directions, estimate_settings, full_model_from_config, load_config, \
        model_from_config
    from neckstrength.estimate import _decision, _prepare_inputs
    from neckstrength.io import read_directions

    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        cfg = load_config(ROOT / "config" / "config.ci.yaml")
        full = full_model_from_config(cfg)
        d = build_directions(cfg)
        models = {m: model_from_config(full, cfg, m) for m in ("s3m24", "p2m7")}
        s = estimate_settings(cfg, "s3m24")
        prep = _prepare_inputs(s.bootstrap_direction, models["s3m24"], d, "S003",
                               ROOT / "data" / "thesis" / "table_A2_max_force.csv", None, tmp_path, lambda x: None)
        d_used = read_directions(prep["directions"])
        got = _decision(s, models["s3m24"], d_used, "S003", prep, tmp_path, 1, lambda x: None)
        assert _decision(estimate_settings(cfg, "p2m7"), models["p2m7"], d_used, "S003", prep, tmp_path, 1,
                         lambda x: None) == {}                                            # no mf in p2m7
    finally:
        os.chdir(cwd)
    hist = pd.read_csv(tmp_path / "decision.csv", comment="#")
    assert len(hist) == len(prep["used"]) + 1 and hist["t"].tolist() == list(range(len(hist)))
    # S003's forces: the model fits them only to about 30% RMS, far beyond 3 x the 5% noise: not decidable
    assert got["decision"] == "model misfit" and hist["misfit_rms"].iloc[-1] > 0.15 and 0 <= got["p_deficit"] <= 1
    assert got["log_bf"] == pytest.approx(hist["log_bf"].iloc[-1], rel=1e-5)
    # CI sizes (300 candidates) differ from the recalibration's (1000): the model's own P, labelled heuristic
    assert "heuristic" in got["p_deficit_label"] and "n_candidates 300" in got["p_deficit_label"]
    assert (hist["p_deficit"] == hist["p_model"]).all() and not hist["p_calibrated"].any()


def test_two_threads_give_the_same_numbers(p2m7):
    model, data = p2m7
    s = DecisionSettings(group=("TS-E",), n_candidates=300, n_moves=2)
    out = []
    for threads in (1, 2):
        dec = DeficitDecision(model, data.directions, data.U, data.force_scale, model.strengths, s, JointSettings(),
                              np.random.default_rng(4), n_threads=threads)
        assert dec.parallel == (threads == 2)
        for d, f in zip(data.directions[:4], data.forces[:4]):
            dec.push(d, float(f) * 0.8)
        out.append((dec.log_bf(), dec.posts["deficit"].F.copy()))
    # the same to the solver's rounding (another basis cache can return another optimal vertex's last bits)
    assert out[0][0] == pytest.approx(out[1][0], rel=1e-9, abs=1e-9)
    assert np.allclose(out[0][1], out[1][1], rtol=1e-9, atol=0)


def test_forces_the_model_cannot_fit_are_not_decided(p2m7):
    """Forces no strength vector reproduces (alternately x 0.5 and x 2 of a fitted truth's): 'model misfit', not a
    confident deficit or no-deficit from whichever hypothesis misfits less; the same forces unscaled are decided
    or undecided as usual."""
    model, data = p2m7
    s = DecisionSettings(group=("TS-E",), n_candidates=300, n_moves=2, min_tests=1)
    w, _, _ = solve(model, model.strengths[None], data.U)
    good = w[0] / data.force_scale
    bad = good * np.where(np.arange(len(good)) % 2 == 0, 0.5, 2.0)
    out = {}
    for name, forces in (("good", good), ("bad", bad)):
        dec = DeficitDecision(model, data.directions, data.U, data.force_scale, model.strengths, s, JointSettings(),
                              np.random.default_rng(9))
        for d, f in zip(data.directions, forces):
            dec.push(d, float(f))
        out[name] = (dec.decision(), dec.misfit_rms())
    assert out["bad"][0] == "model misfit" and out["bad"][1] > 3 * s.noise
    assert out["good"][0] != "model misfit" and out["good"][1] < 3 * s.noise


def _synthetic_runs(n: int = 400, slope: float = 0.6, intercept: float = 0.8, seed: int = 0) -> pd.DataFrame:
    """Runs whose deficit status follows a known logistic law of log BF (made here, not by the decision)."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        kind = "deficit" if i % 4 in (0, 3) else "normal"        # half and half, in both parity folds
        for t in (5, 10, 15, 25):
            rows.append({"participant": i, "protocol": "forces", "t": t, "kind": kind})
    df = pd.DataFrame(rows)
    # draw log BF given the class so that logit P(deficit | x) = slope x + intercept at a 50% share:
    # x | class ~ N(+-m, s^2) gives logit = 2 m x / s^2; add the intercept by shifting both means
    s = 1.5
    m = slope * s * s / 2
    shift = -intercept / slope
    sign = np.where(df["kind"] == "deficit", 1.0, -1.0)
    df["log_bf"] = sign * m + shift + s * rng.standard_normal(len(df))
    return df


def test_recalibration_recovers_a_known_logistic_law_and_checks_itself_held_out():
    from neckstrength.sequential.decision import DecisionCalibration
    from neckstrength.sequential.decision_study import recalibrate

    runs = _synthetic_runs()
    cal, rel, rule = recalibrate(runs, DecisionSettings(), "s3m24", 25, (5, 10, 15, 25))
    # the law is linear: the fitted map's log LR at a few points within 0.35 of the truth
    for x in (-3.0, -1.0, 0.0, 1.0, 3.0):
        assert cal.log_lr(x) == pytest.approx(0.6 * x + 0.8, abs=0.35)
    assert cal.slope > 0 and cal.slope + cal.bend / 2 > 0                 # monotone
    assert cal.cohort_share == pytest.approx(0.5) and cal.n_patients == 400
    assert rel["within_ci"].sum() >= len(rel) - 1 and str(int(rel["within_ci"].sum())) in cal.check
    assert set(rule["t"]) == {5, 10, 15, 25}
    assert rule["threshold_fa0.05_false_alarm"].max() <= 0.12           # held out: near the 5% it was set for
    back = DecisionCalibration.from_frame(cal.to_frame(), source="x")
    assert back.log_lr(1.3) == pytest.approx(cal.log_lr(1.3)) and back.group == cal.group
    with pytest.raises(ValueError, match="columns"):
        DecisionCalibration.from_frame(cal.to_frame().drop(columns=["slope"]))


def test_recalibrated_probability_is_used_only_where_it_holds(p2m7):
    """A recalibration measured for other settings is not applied (the model's P, labelled heuristic); one that
    holds changes P as its map says; EMG entries switch it off, and undo switches it back on."""
    from neckstrength.sequential.decision import DecisionCalibration

    model, data = p2m7
    f0 = model.strengths
    base = DecisionSettings(group=("TS-E",), n_candidates=300, n_moves=2)
    cal = DecisionCalibration(model=model.name, group=("TS-E",), deficit_range=(0.2, 0.6), population_sd=0.3,
                              noise=0.05, n_candidates=300, sampler="resample_move",
                              n_directions=len(data.directions), cohort_share=0.5, n_patients=10, t_from=0, slope=0.5,
                              intercept=1.0, bend=0.0, check="test")
    other = DecisionCalibration(**{**cal.__dict__, "model": "s3m24"})
    from dataclasses import replace

    w, _, _ = solve(model, f0[None], data.U)
    forces = w[0] / data.force_scale
    dec = DeficitDecision(model, data.directions, data.U, data.force_scale, f0, replace(base, calibration=cal),
                          JointSettings(), np.random.default_rng(4))
    off = DeficitDecision(model, data.directions, data.U, data.force_scale, f0, replace(base, calibration=other),
                          JointSettings(), np.random.default_rng(4))
    for d in data.directions[:3]:
        dec.push(d, forces[data.directions.index(d)])
        off.push(d, forces[data.directions.index(d)])
    assert dec.calibrated and not off.calibrated
    late = DecisionCalibration(**{**cal.__dict__, "t_from": 5})          # fitted from the 5th test on
    assert "3 tests, recalibrated from the 5th" in late.applies(model.name, base, len(data.directions), n_tests=3)
    assert late.applies(model.name, base, len(data.directions), n_tests=5) == ""
    assert "measured on s3m24" in off.calibration_note() and "heuristic" in off.p_label()
    assert off.p_deficit() == off.p_model()
    x = dec.log_bf()
    assert dec.p_deficit() == pytest.approx(1 / (1 + math.exp(-(0.5 * x + 1.0))))
    assert dec.p_model() == pytest.approx(1 / (1 + math.exp(-x)))
    assert "recalibrated" in dec.p_label() and dec.history[-1]["p_calibrated"]
    n = len(model.muscle_names)
    dec.push(data.directions[3], forces[3], (np.zeros(n), np.ones(n)))
    assert not dec.calibrated and "EMG" in dec.calibration_note()
    dec.undo()
    assert dec.calibrated


def test_shipped_recalibration_loads_and_holds_for_the_shipped_s3m24_settings():
    from neckstrength.config import decision_settings, load_config
    from neckstrength.io import DataValidationError

    cfg = load_config(ROOT / "config" / "config.yaml")
    s = decision_settings(cfg)
    assert s.calibration is not None and s.calibration.model == "s3m24"
    assert s.calibration.applies("s3m24", s, 25) == ""
    assert "noise" in s.calibration.applies("s3m24", decision_settings(cfg, noise=0.08), 25)
    assert "7 of 7" in s.calibration.check or "of 7" in s.calibration.check
    with pytest.raises(DataValidationError, match="calibration"):
        decision_settings({"clinician": {"decision": {"calibration": "no/such/file.csv"}}})


def test_decision_with_tests_in_several_postures():
    """The decision over (posture, direction) tests: a posture test moves the evidence, undo restores it exactly, the
    forces of a weak group favour the deficit, and the recalibration (measured in neutral) does not apply."""
    from neckstrength.config import build_directions, load_config
    from neckstrength.model.full import load_full_model
    from neckstrength.model.reduction import named_model
    from neckstrength.postures.datasets import posture_dataset, posture_grid
    from neckstrength.postures.model import build_posture_set
    from neckstrength.postures.tables import load_posture_tables
    from neckstrength.sequential.decision import DecisionCalibration

    cfg = load_config(ROOT / "config" / "config.ci.yaml")
    full = load_full_model(ROOT / "data" / "model", ROOT / "data" / "thesis", "derived")
    d = build_directions({**cfg, "geometry": {**cfg["geometry"],
                                              "test_point_spec": str(ROOT / cfg["geometry"]["test_point_spec"])}})
    neutral = named_model(full, "p3m12", ROOT / "data" / "thesis", "anatomy")
    ps = build_posture_set(full, neutral, load_posture_tables(ROOT / "data" / "model"), ["neutral", "flex20"])
    grid = posture_grid(ps, d)
    U = grid[[c for c in grid.columns if c.startswith("u") and c[1:].isdigit()]].to_numpy(float)
    fs = grid["force_scale"].to_numpy(float)
    f0 = neutral.strengths
    s = DecisionSettings(group=("multif",), n_candidates=300, n_moves=2)
    fa = f0.copy()
    fa[s.group_indices(neutral.muscle_names)] *= 0.35
    data = posture_dataset(ps, grid, "weak", fa)
    labels = list(grid["label"])
    cal = DecisionCalibration(model=neutral.name, group=("multif",), deficit_range=(0.2, 0.6), population_sd=0.3,
                              noise=0.05, n_candidates=300, sampler="resample_move", n_directions=len(labels),
                              cohort_share=0.5, n_patients=10, t_from=0, slope=1.0, intercept=0.0, bend=0.0, check="test")
    from dataclasses import replace

    dec = DeficitDecision(neutral, labels, U, fs, f0, replace(s, calibration=cal), JointSettings(),
                          np.random.default_rng(8), pset=ps, test_postures=list(grid["posture"]))
    assert dec.postures == ["neutral", "flex20"] and not dec.calibrated and "postures" in dec.calibration_note()
    neutral_labels = [x for x, p in zip(labels, grid["posture"]) if p == "neutral"]
    flex = [x for x, p in zip(labels, grid["posture"]) if p == "flex20"]
    for x in neutral_labels[:3]:
        dec.push(x, data.forces[labels.index(x)])
    before = dec.log_bf()
    dec.push(flex[0], data.forces[labels.index(flex[0])])
    assert dec.log_bf() != before
    dec.undo()
    assert dec.log_bf() == before
    for x in flex[:4]:
        dec.push(x, data.forces[labels.index(x)])
    assert dec.log_bf() > 0                              # the forces of a 35% group favour the deficit
    label, sc = dec.propose()
    assert label in dec.remaining and len(sc) == len(labels) - 7


def test_session_screen_says_which_probability_it_prints(p2m7):
    """The session's line under the decision: 'recalibrated' with the check where the recalibration holds, 'NOT
    calibrated: heuristic, ...' with the reason where it does not."""
    from dataclasses import replace

    from neckstrength.sequential.decision import DecisionCalibration
    from neckstrength.session.render import decision_p_label

    model, data = p2m7
    base = DecisionSettings(group=("TS-E",), n_candidates=300, n_moves=2)
    cal = DecisionCalibration(model=model.name, group=("TS-E",), deficit_range=(0.2, 0.6), population_sd=0.3,
                              noise=0.05, n_candidates=300, sampler="resample_move",
                              n_directions=len(data.directions), cohort_share=0.5, n_patients=10, t_from=0, slope=0.5,
                              intercept=1.0, bend=0.0, check="cross-fitted reliability: 7 of 7 bins")
    on = DeficitDecision(model, data.directions, data.U, data.force_scale, model.strengths,
                         replace(base, calibration=cal), JointSettings(), np.random.default_rng(4))
    off = DeficitDecision(model, data.directions, data.U, data.force_scale, model.strengths,
                          replace(base, calibration=cal, noise=0.08), JointSettings(), np.random.default_rng(4))
    assert "recalibrated on 10 simulated patients" in decision_p_label(on) and "7 of 7" in decision_p_label(on)
    assert "NOT calibrated: heuristic" in decision_p_label(off) and "noise 0.08" in decision_p_label(off)


def _guard_runs(n: int, scale: float = 1.0, seed: int = 3, protocol: str = "forces") -> pd.DataFrame:
    """Runs whose best-fit RMS at t is noise x a known curve x a log-normal spread (made here, not by the decision);
    ``scale`` multiplies every RMS (a worse fit than the model's)."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        lvl = rng.normal(0, 0.2)                  # a patient's own level, shared over t (as a real run's)
        for t in range(0, 11):
            rms = np.nan if t == 0 else 0.05 * (1 - np.exp(-t / 3)) * np.exp(lvl + rng.normal(0, 0.1)) * scale
            rows.append({"participant": i, "kind": "deficit" if i % 2 else "normal", "protocol": protocol, "t": t,
                         "misfit_rms": rms, "log_bf": 0.0, "p_deficit": 0.5})
    return pd.DataFrame(rows)


def test_misfit_guard_flags_its_level_of_the_models_own_patients_held_out_and_worse_fits_more():
    """The guard fitted on 400 patients flags about its level (5%) of the others held out, and most patients whose
    fits are 2x worse. Chance: the held-out count is Binomial(400, ~0.05) (sd 0.011); the bounds 0.015-0.10 are
    3 sd away (fixed seed, so the test cannot flake)."""
    from neckstrength.sequential.decision import MisfitGuard
    from neckstrength.sequential.decision_study import fit_misfit_guard, misfit_flag_table, misfit_flags

    s = DecisionSettings(n_candidates=1000)
    runs = _guard_runs(400)
    guard, check = fit_misfit_guard(runs, s, "s3m24", 25, 0.05)
    assert guard.t_from == 5 and guard.t_max == 10 and len(guard.log_sd) == 6 and guard.n_patients == 400
    row = check.set_index("level").loc[0.05]
    assert 0.015 <= row["held_out_share"] <= 0.10
    assert check.set_index("level").loc[0.01, "factor"] > row["factor"] > 0.5
    # in sample the rule flags at most its level (the quantile is taken 'higher')
    assert misfit_flags(runs, guard, 5)["flagged"].mean() <= 0.05
    worse = _guard_runs(200, scale=2.0, seed=4, protocol="worse")
    tab = misfit_flag_table(pd.concat([runs, worse]), guard, 5).set_index(["protocol", "kind"])
    assert tab.loc[("worse", "normal"), "share_flagged"] > 0.8
    assert np.isnan(guard.threshold(4)) and np.isnan(guard.threshold(11)) and guard.threshold(5) > 0
    back = MisfitGuard.from_frame(guard.to_frame(), source="x")
    assert back.log_median == pytest.approx(guard.log_median, rel=1e-7) and back.factor == pytest.approx(guard.factor)
    assert back.log_sd == pytest.approx(guard.log_sd, rel=1e-7)
    assert back.applies("s3m24", s, 25) == ""
    assert "noise" in back.applies("s3m24", DecisionSettings(noise=0.08), 25)
    assert "postures" in back.applies("s3m24", s, 25, several_postures=True)
    with pytest.raises(ValueError, match="misfit_rms"):
        fit_misfit_guard(runs.drop(columns="misfit_rms"), s, "s3m24", 25, 0.05)


def test_the_decision_prints_the_calibrated_guard_and_falls_back_to_the_heuristic_where_it_does_not_hold(p2m7):
    """A guard measured for this decision decides 'model misfit' at its threshold (a tiny factor flags, a huge one
    does not) and says 'calibrated'; one measured for another model is not used: the heuristic, with the reason."""
    from neckstrength.sequential.decision import MisfitGuard

    model, data = p2m7
    base = dict(group=("TS-E",), n_candidates=300, n_moves=2, min_tests=2)
    w, _, _ = solve(model, model.strengths[None], data.U)
    forces = w[0] / data.force_scale * np.exp(0.05 * np.random.default_rng(0).standard_normal(len(w[0])))

    def run(guard):
        s = DecisionSettings(**base, misfit_guard=guard)
        dec = DeficitDecision(model, data.directions, data.U, data.force_scale, model.strengths, s, JointSettings(),
                              np.random.default_rng(9))
        for d, f in zip(data.directions[:3], forces[:3]):
            dec.push(d, float(f))
        return dec

    def guard(factor, name=model.name):
        return MisfitGuard(model=name, noise=0.05, n_candidates=300, sampler="resample_move",
                           n_directions=len(data.directions), level=0.05, t_from=2, factor=factor,
                           log_median=(np.log(0.3), np.log(0.4)), log_sd=(1.0, 1.0), n_patients=10,
                           check="test")

    tiny, huge, other = run(guard(-50.0)), run(guard(50.0)), run(guard(-50.0, "s3m24"))
    for dec in (tiny, huge, other):
        assert np.isfinite(dec.misfit_rms()) and dec.history[-1]["misfit_rms"] == dec.misfit_rms()
    assert tiny.decision() == "model misfit" and tiny.misfit_check().calibrated and tiny.history[-1]["misfit_flagged"]
    assert "calibrated: flags 5%" in tiny.history[-1]["misfit_label"] and "FLAGGED" in tiny.misfit_check().label
    assert huge.decision() != "model misfit" and huge.misfit_check().threshold == pytest.approx(0.4 * np.exp(50.0))
    oc = other.misfit_check()
    assert not oc.calibrated and oc.threshold == pytest.approx(3.0 * 0.05) and "model p2m7" in oc.label
    assert oc.flagged == (other.misfit_rms() > 0.15)
    early = run(guard(-50.0))
    early.undo()
    early.undo()
    assert not early.misfit_check().flagged and "not checked before 2 tests" in early.misfit_check().label


def test_alg4_protocol_reads_algorithm4_as_a_score(p2m7):
    """The study's alg4 protocol runs Algorithm 4 on the participant's forces and scores -log of the group's f_c
    ratio; the ROC table takes it (no probability: no rule columns), the stopping rule and reliability skip it."""
    from dataclasses import replace as dc_replace

    from neckstrength.abc.algorithm4 import ABCSettings
    from neckstrength.sequential.decision_study import DecisionStudySettings, run_decision_study

    model, data = p2m7
    dirs = list(data.directions)
    s = DecisionSettings(group=("TS-E",), n_candidates=200, n_moves=1, min_tests=1)
    study = DecisionStudySettings(cohort=CohortSettings(n_deficit=2, n_normal=2), protocols=("alg4",),
                                  alg4_tests=(3, len(dirs)), bootstrap_direction=dirs[0], n_max=3)

    def rng_for(what, i):
        return np.random.default_rng([7, i, len(what)])

    runs = run_decision_study(model, dirs, data.U, data.force_scale, model.strengths, s, JointSettings(), study,
                              rng_for, abc=ABCSettings(sigma0=0.3, max_iter=2), alg4_order=lambda i: dirs[::-1])
    assert list(runs["t"]) == [3, len(dirs)] * 4 and runs["p_deficit"].isna().all()
    assert np.allclose(runs["score"], -np.log(runs["alg4_ratio"])) and (runs["alg4_ratio"] > 0).all()
    assert (runs.loc[runs["t"] == 3, "direction"] == dirs[0]).all()     # the bootstrap direction kept in
    roc = roc_table(runs, (3, len(dirs)), 0.05, 0.95)
    assert list(roc["protocol"]) == ["alg4", "alg4"] and roc["auc"].between(0, 1).all()
    assert roc["rule_sensitivity_p0.95"].isna().all()
    assert sequential_table(runs, 0.95)[0].empty and reliability_table(runs, (3,)).empty
    with pytest.raises(ValueError, match="alg4_order"):
        run_decision_study(model, dirs, data.U, data.force_scale, model.strengths, s, JointSettings(),
                           dc_replace(study, alg4_tests=(3,)), rng_for, participants=[0],
                           abc=ABCSettings(max_iter=1))


def test_a_protocols_cache_signature_depends_on_what_its_runs_depend_on_only():
    """Adding a protocol or changing a read-out (checkpoints, misfit level) keeps the forces runs; an EMG band
    changes only the EMG protocols' signatures; Algorithm 4's settings only alg4's."""
    from dataclasses import replace as dc_replace

    from neckstrength.pipeline.clinician import _protocol_signature
    from neckstrength.sequential.decision_study import DecisionStudySettings

    s, js = DecisionSettings(), JointSettings()
    a = DecisionStudySettings(protocols=("forces",), emg_groups=("SCM",))
    b = dc_replace(a, protocols=("forces", "forces+emg", "alg4"), checkpoints=(5,), misfit_level=0.01)
    c = dc_replace(b, emg_band=0.1)

    def sig(st, p, extra=None):
        return _protocol_signature(s, st, js, 1, "s3m24", p, extra)

    assert sig(a, "forces") == sig(b, "forces") == sig(c, "forces")
    assert sig(b, "forces+emg") != sig(c, "forces+emg") and sig(b, "forces+emg") != sig(b, "forces")
    assert sig(b, "alg4", "abc1") != sig(b, "alg4", "abc2") and sig(b, "forces", None) != sig(dc_replace(
        b, n_max=10), "forces", None)
    assert sig(a, "forces") != _protocol_signature(dc_replace(s, noise=0.08), a, js, 1, "s3m24", "forces", None)
    # a settings field added later at its default keeps the runs made before it existed
    from dataclasses import make_dataclass

    from neckstrength.pipeline.clinician import _lean_repr

    Old = make_dataclass("S", [("a", int, 1)])
    New = make_dataclass("S", [("a", int, 1), ("b", float, 0.5)])
    assert _lean_repr(Old()) == _lean_repr(New()) != _lean_repr(New(b=0.6))
    assert _lean_repr(New(a=2)) == _lean_repr(Old(a=2)) == "S(a=2)"
    # measuring fewer patients under a protocol keeps the runs it has (each run is one patient's own)
    d = dc_replace(b, patients_per_kind=(("alg4", 3),))
    assert sig(b, "alg4", "abc1") == sig(d, "alg4", "abc1") and sig(b, "forces") == sig(d, "forces")


def test_patients_per_kind_measures_the_first_k_of_each_kind_under_a_protocol():
    from neckstrength.config import decision_study_settings, load_config
    from neckstrength.sequential.cohort import CohortSettings
    from neckstrength.sequential.decision_study import DecisionStudySettings

    st = DecisionStudySettings(cohort=CohortSettings(n_deficit=4, n_normal=3), protocols=("forces", "alg4"),
                               patients_per_kind=(("alg4", 2), ("forces+postures", 9)))
    # deficit patients 0-3, normal 4-6, run alternating so a study stopped part-way has both kinds
    assert st.participants("forces") == st.participants() == [0, 4, 1, 5, 2, 6, 3]
    assert st.participants("alg4") == [0, 4, 1, 5]
    assert DecisionStudySettings(cohort=st.cohort, patients_per_kind=(("forces+postures", 9),)).participants(
        "forces+postures") == [0, 4, 1, 5, 2, 6, 3]                # k above the cohort: all
    with pytest.raises(ValueError, match="patients_per_kind"):
        DecisionStudySettings(patients_per_kind=(("alg5", 2),))
    with pytest.raises(ValueError, match="patients_per_kind"):
        DecisionStudySettings(patients_per_kind=(("alg4", 0),))
    cfg = load_config(str(ROOT / "config" / "config.yaml"))
    study, _ = decision_study_settings(cfg, "s3m24")
    assert dict(study.patients_per_kind)["alg4"] >= 1
    assert len(study.participants("forces")) == study.cohort.n_deficit + study.cohort.n_normal


def test_a_study_stopped_before_its_first_normal_patient_gives_tables_and_a_figure_that_say_so(tmp_path):
    """roc_table and the figure on runs of one kind: NaN where both kinds are needed and a note naming the missing
    kind (a warning too), the rule's sensitivity still read; the other tables as before."""
    from neckstrength.sequential.decision_plots import fig_decision_study

    runs = _fake_runs()
    only = runs[runs["kind"] == "deficit"]
    with pytest.warns(UserWarning, match="forces: no normal participants among its 20 runs"):
        roc = roc_table(only, (1, 5), 0.05, 0.95)
    assert list(roc["n_normal"]) == [0, 0] and roc["auc"].isna().all() and roc["auc_se"].isna().all()
    assert roc["sensitivity_at_fa0.05"].isna().all() and roc["rule_false_alarm_p0.95"].isna().all()
    assert roc["rule_sensitivity_p0.95"].between(0, 1).all() and roc["note"].str.contains("no normal").all()
    assert "note" not in roc_table(runs, (1, 5), 0.05, 0.95).columns      # both kinds: the table as before
    per, seq = sequential_table(only, 0.95)
    assert list(seq["kind"]) == ["deficit"]
    rel = reliability_table(only, (1, 5))
    fig_decision_study(only, rel, (1, 5), 0.95, tmp_path / "fig.png", "one kind")
    assert (tmp_path / "fig.png").stat().st_size > 10_000


def test_the_decision_figure_has_a_roc_panel_per_protocol_in_the_studys_order_and_no_legend_over_a_panel(
        tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    from neckstrength.sequential.decision_plots import fig_decision_study

    kept = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    runs = _fake_runs()
    runs = pd.concat([runs.assign(protocol="forces+emg"), runs], ignore_index=True)     # rows: emg first
    assert list(dict.fromkeys(roc_table(runs, (1, 5))["protocol"])) == ["forces", "forces+emg"]
    fig_decision_study(runs, reliability_table(runs, (1, 5)), (1, 5), 0.95, tmp_path / "fig.png", "two protocols")
    fig = kept[-1]
    fig.canvas.draw()
    titles = [a.get_title() for a in fig.axes]
    assert titles[:2] == ["ROC: forces (log Bayes factor)\n20 deficit, 20 normal patients",
                          "ROC: forces+emg (log Bayes factor)\n20 deficit, 20 normal patients"], titles
    legends = [a.get_legend() for a in fig.axes if a.get_legend() is not None]
    assert len(legends) == 4
    over = [(a.get_title(), [t.get_text() for t in leg.get_texts()][:2]) for leg in legends for a in fig.axes
            if leg.get_window_extent().overlaps(a.get_window_extent())]
    assert not over, over
    plt.close(fig)


def test_a_study_in_alternating_order_gives_each_patient_the_rows_it_gets_alone(p2m7):
    """Every patient draws from its own index's streams: the study's run order (deficit and normal alternating)
    leaves each patient's rows as when that patient runs alone (how the pipeline runs them)."""
    from neckstrength.sequential.decision_study import DecisionStudySettings, run_decision_study

    model, data = p2m7
    dirs = list(data.directions)
    s = DecisionSettings(group=("TS-E",), n_candidates=100, n_moves=1, min_tests=1)
    study = DecisionStudySettings(cohort=CohortSettings(n_deficit=2, n_normal=1), n_max=2)

    def rng_for(what, i):
        return np.random.default_rng([11, i, len(what)])

    def run(participants=None):
        return run_decision_study(model, dirs, data.U, data.force_scale, model.strengths, s, JointSettings(), study,
                                  rng_for, participants=participants)

    both = run()
    assert list(dict.fromkeys(both["participant"])) == [0, 2, 1]
    assert list(dict.fromkeys(both["kind"]))[:2] == ["deficit", "normal"]
    for i in (0, 1, 2):
        alone = run([i])
        pd.testing.assert_frame_equal(both[both["participant"] == i].reset_index(drop=True), alone, rtol=1e-9)


def test_a_protocols_cache_keeps_its_columns_and_sets_a_file_of_other_settings_aside(tmp_path):
    from neckstrength.pipeline.clinician import _append_cache, _read_cache

    f = tmp_path / "forces.csv"
    _append_cache(f, "abc", pd.DataFrame({"participant": [0], "t": [1], "log_bf": [0.5]}))
    _append_cache(f, "abc", pd.DataFrame({"participant": [1], "log_bf": [0.7], "t": [2], "new": [3]}))
    got = _read_cache(f, "abc")
    assert list(got.columns) == ["participant", "t", "log_bf"] and list(got["log_bf"]) == [0.5, 0.7]
    assert _read_cache(f, "other").empty and not f.exists()
    kept = list(tmp_path.glob("forces.*.csv"))                    # set aside, not deleted
    assert len(kept) == 1
    _append_cache(f, "other", pd.DataFrame({"participant": [5], "t": [1], "log_bf": [0.1]}))
    back = _read_cache(f, "abc")                                  # back to the first settings: their runs return
    assert list(back["log_bf"]) == [0.5, 0.7] and len(list(tmp_path.glob("forces.*.csv"))) == 1
    assert list(_read_cache(f, "other")["participant"]) == [5]


def test_the_study_on_one_blas_thread_gives_the_same_runs(p2m7):
    """run_decision_study's one_blas_thread (default) runs the samplers with numpy's BLAS on one thread (seen from
    inside the run, through its progress callback) and gives the same rows, number for number, as the default
    BLAS threads (benchmarks/bench_decision_speed.py times both)."""
    from threadpoolctl import threadpool_info

    from neckstrength.sequential.decision_study import DecisionStudySettings, run_decision_study

    model, data = p2m7
    dirs = list(data.directions)
    s = DecisionSettings(group=("TS-E",), n_candidates=200, n_moves=2, min_tests=1)
    study = DecisionStudySettings(cohort=CohortSettings(n_deficit=1, n_normal=1), n_max=4)

    def rng_for(what, i):
        return np.random.default_rng([11, i, len(what)])

    def blas_threads():
        return max([x["num_threads"] for x in threadpool_info() if x["user_api"] == "blas"], default=1)

    seen = {}
    runs = {}
    for one in (True, False):
        seen[one] = []
        runs[one] = run_decision_study(model, dirs, data.U, data.force_scale, model.strengths, s, JointSettings(),
                                       study, rng_for, progress=lambda _: seen[one].append(blas_threads()),
                                       one_blas_thread=one)
    assert seen[True] == [1, 1] and seen[False] == [blas_threads()] * 2
    assert len(runs[True]) == 2 * 5
    pd.testing.assert_frame_equal(runs[True], runs[False], check_exact=True)
