"""Which additional measurements tell the leading candidates apart (issue 17, item 5): expected log Bayes factor,
greedy design, the measurement pool, and the proposal in a diagnosis."""

import numpy as np
import pandas as pd
import pytest

from neckstrength.config import discriminate_settings, head_from_config
from neckstrength.gap import diagnose as dg
from neckstrength.gap import discriminate as dc
from neckstrength.gap import report as rp
from neckstrength.gap.effects import EFFECTS, compose
from neckstrength.gap.fit import FitSettings, Simulator
from neckstrength.gap.report import _discrimination_lines


def test_expected_log_bf_is_zero_for_equal_predictions_and_grows_with_their_difference():
    sig2 = 0.1 ** 2
    assert dc.expected_log_bf([3.0], [[sig2]], [3.0], [[sig2]]) == pytest.approx(0.0, abs=1e-12)
    vals = [dc.expected_log_bf([3.0], [[sig2]], [3.0 + d], [[sig2]]) for d in (0.0, 0.05, 0.1, 0.2, 0.4)]
    assert np.all(np.diff(vals) > 0)
    # equal variances: KL = d^2 / (2 sigma^2) (normal distributions, closed form)
    assert vals[2] == pytest.approx(0.1 ** 2 / (2 * sig2), rel=1e-10)
    # two independent measurements add; shared parameter uncertainty (correlated predictive) adds less
    two = dc.expected_log_bf([3.0, 3.0], np.eye(2) * sig2, [3.1, 3.1], np.eye(2) * sig2)
    assert two == pytest.approx(2 * vals[2], rel=1e-10)
    shared = np.full((2, 2), 0.5 * sig2) + np.eye(2) * sig2
    assert dc.expected_log_bf([3.0, 3.0], shared, [3.1, 3.1], shared) < two


def test_greedy_picks_the_discriminating_measurement():
    sigma = 0.05
    mu = np.zeros((2, 5))
    mu[1, 3] = 0.3                                   # only measurement 3 separates the two candidates
    cov = np.zeros((2, 5, 5))
    chosen, trace = dc.greedy_design(mu, cov, sigma, 2)
    assert chosen == [3, 3]                          # and its repeat beats the useless ones
    assert trace[1][0].min() == pytest.approx(2 * trace[0][0].min(), rel=1e-9)
    # two equally different measurements; the candidates' parameter uncertainty is large at 3: 4 wins
    mu[1, 4] = 0.3
    cov[:, 3, 3] = 0.2 ** 2
    assert dc.greedy_design(mu, cov, sigma, 1)[0] == [4]
    # three candidates: measurement 1 separates 0 from 1 only (hugely), measurement 2 all pairs moderately
    mu3 = np.zeros((3, 3))
    mu3[:, 1] = [0.0, 1.0, 0.0]
    mu3[:, 2] = [0.0, 0.15, 0.3]
    cov3 = np.zeros((3, 3, 3))
    for obj in ("saturating", "min"):
        assert dc.greedy_design(mu3, cov3, sigma, 1, obj)[0] == [2]
    assert dc.greedy_design(mu3, cov3, sigma, 1, "sum")[0] == [1]
    with pytest.raises(ValueError, match="objective"):
        dc.greedy_design(mu3, cov3, sigma, 1, "max")


def test_surface_pool_lies_on_the_head_and_skips_the_face(cfg, ctx_p2):
    head = head_from_config(cfg)
    s = dc.DiscriminateSettings()
    sp = dc.surface_points(head, s)
    P = sp[["px", "py", "pz"]].to_numpy()
    N = sp[["nx", "ny", "nz"]].to_numpy()
    assert all(abs(head.implicit(p) - 1) < 1e-9 for p in P)
    assert np.allclose(np.linalg.norm(N, axis=1), 1) and np.all(((P - head.centre) * N).sum(axis=1) > 0)
    assert len(sp) == 12 * 4 - 6                     # 30 deg x 4 elevations, minus 6 face points
    pool = dc.measurement_pool(ctx_p2, head, s, cfg["geometry"]["plane_bands"])
    assert (pool["kind"] == "repeat").sum() == ctx_p2.K
    new = pool[pool["kind"] == "new"]
    assert len(new) == 6 and np.allclose(new[["pz", "nz"]], 0)   # planar model: sagittal points only
    assert np.allclose(np.linalg.norm(pool[[f"u_{c}" for c in ("Mx", "My", "Mz", "Fx", "Fy", "Fz")]], axis=1), 1)


def test_proposal_appears_in_a_diagnosis_when_the_leaders_are_close(cfg, ctx_p2):
    ctx = ctx_p2
    rng = np.random.default_rng(3)
    F = ctx.model.strengths[None] * np.exp(rng.normal(0, 0.2, (1, ctx.model.m)))
    inst = compose(ctx, [EFFECTS["origin_offset"](ctx)], [np.array([0.015, -0.01])])
    T = Simulator(ctx, inst).forces(F)[0] * np.exp(rng.normal(0, 0.03, ctx.K))
    s = dg.DiagnosisSettings(effects=("origin_offset", "kinematic"), grid_points=3, folds=7, pairs_top=0,
                             bootstrap=100, starts=1, reach_samples=0, reach_iter=0, fit=FitSettings(max_iter=10),
                             seed=1)
    diag = dg.diagnose(ctx, [dg.BlindData("x", T)], s)[0]
    p_best = float(diag.effects.sort_values("rank")["p_best"].iloc[0])
    head = head_from_config(cfg)
    ds = discriminate_settings(cfg)
    assert ds is not None and ds.p_best_below == 0.7 and ds.measurements == 3
    # P(best) not below the threshold: nothing proposed, and the report says why
    dc.attach_proposal(ctx, T, diag, head, dc.DiscriminateSettings(p_best_below=p_best), cfg["geometry"]["plane_bands"])
    assert diag.discrimination.empty and not diag.summary["discrimination"]["proposed"]
    assert "No additional measurements proposed" in "\n".join(_discrimination_lines(diag))
    # below: a table of 3 measurements x 3 pairs of the top 3 candidates
    s_on = dc.DiscriminateSettings(p_best_below=p_best + 0.01, fit=FitSettings(max_iter=10))
    dc.attach_proposal(ctx, T, diag, head, s_on, cfg["geometry"]["plane_bands"])
    tab, info = diag.discrimination, diag.summary["discrimination"]
    assert info["proposed"] and info["candidates"] == list(diag.effects.sort_values("rank")["candidate"][:3])
    assert sorted(set(tab["step"])) == [1, 2, 3] and len(tab) == 3 * (3 - len(info["indistinguishable_pairs"]))
    pool = dc.measurement_pool(ctx, head, s_on, cfg["geometry"]["plane_bands"])
    assert set(tab["measurement"]) <= set(pool["name"])
    assert (tab[["elbf_if_a", "elbf_if_b"]].to_numpy() >= -1e-12).all()
    last = tab[tab["step"] == 3]
    assert (last["cum_elbf_if_a"].to_numpy() >= tab[tab["step"] == 1]["cum_elbf_if_a"].to_numpy() - 1e-9).all()
    text = "\n".join(_discrimination_lines(diag))
    assert "Which tests would tell the leading candidates apart" in text and info["measurements"][0] in text
    # the candidates' predictives in two processes: the same proposal
    dc.attach_proposal(ctx, T, diag, head, s_on, cfg["geometry"]["plane_bands"], workers=2)
    pd.testing.assert_frame_equal(diag.discrimination, tab)
    assert diag.summary["discrimination"] == info


def test_extra_trials_update_favours_the_injected_effect_and_rejects_bad_rows(cfg, ctx_p2, tmp_path):
    """The update step: the proposed measurements, measured on the truth, give the injected effect the highest
    posterior among the top candidates; a bad trial row is named by file, row and field."""
    from neckstrength.gap.discriminate import extended_context
    from neckstrength.session import InputError

    ctx = ctx_p2
    rng = np.random.default_rng(3)
    F = ctx.model.strengths[None] * np.exp(rng.normal(0, 0.2, (1, ctx.model.m)))
    theta = np.array([0.015, -0.01])
    T = Simulator(ctx, compose(ctx, [EFFECTS["origin_offset"](ctx)], [theta])).forces(F)[0] * np.exp(
        rng.normal(0, 0.03, ctx.K))
    s = dg.DiagnosisSettings(effects=("origin_offset", "kinematic"), grid_points=3, folds=7, pairs_top=0,
                             bootstrap=100, starts=1, reach_samples=0, reach_iter=0, fit=FitSettings(max_iter=10),
                             seed=1)
    diag = dg.diagnose(ctx, [dg.BlindData("x", T)], s)[0]
    head, bands = head_from_config(cfg), cfg["geometry"]["plane_bands"]
    # without the posture tests (the truth below is simulated at neutral; the posture tests' predictions are
    # tested in tests/gap/test_protocols.py)
    ds = dc.DiscriminateSettings(p_best_below=1.01, fit=FitSettings(max_iter=10), postures=())
    dc.attach_proposal(ctx, T, diag, head, ds, bands)
    info = diag.summary["discrimination"]
    assert "origin_offset" in info["candidates"]
    pool = dc.measurement_pool(ctx, head, ds, bands)
    chosen = pool.set_index("name").loc[info["measurements"]].reset_index()
    ext = extended_context(ctx, chosen)
    truth = Simulator(ext, compose(ext, [EFFECTS["origin_offset"](ext)], [theta])).forces(F)[0][ctx.K:]
    path = tmp_path / "extra.csv"
    path.write_text("measurement,force_N\n" + "".join(f"{m},{f * np.exp(rng.normal(0, 0.01)):.4f}\n"
                                                       for m, f in zip(info["measurements"], truth)))
    trials = dc.read_extra_trials(path, pool)
    dc.attach_update(ctx, T, diag, head, trials, ds, bands)
    u = diag.summary["update"]
    assert u["favoured"] == "origin_offset" and u["trials"] == len(info["measurements"])
    assert abs(sum(u["posterior"].values()) - 1) < 1e-9 and diag.update["candidate"].iloc[0] == "origin_offset"
    assert "## Additional trials" in "\n".join(rp._update_lines(diag))
    # the update reused the proposal's predictions; computed afresh they give the same posterior
    del diag._predictions
    fresh = dc.update_with_trials(ctx, T, diag, head, trials, ds, bands)[1]
    assert fresh["posterior"] == pytest.approx(u["posterior"], rel=1e-9)
    bad = tmp_path / "bad.csv"
    bad.write_text(f"measurement,force_N\n{info['measurements'][0]},100\nnoSuchPoint,90\n")
    with pytest.raises(InputError, match=r"bad.csv, line 3, field 'measurement'"):
        dc.read_extra_trials(bad, pool)
    bad.write_text(f"measurement,force_N\n{info['measurements'][0]},-4\n")
    with pytest.raises(InputError, match=r"line 2, field 'force_N'"):
        dc.read_extra_trials(bad, pool)


def test_predictive_density_and_choice_match_the_normal_predictive():
    """predictive_logpdf is the multivariate normal log density (repeats share the parameter part); the choice
    favours the candidate whose prediction the trials match, and rules out one that cannot produce a test."""
    from scipy.stats import multivariate_normal

    K, sigma = 2, 0.05
    cov = np.zeros((5, 5))
    cov[2:, 2:] = 0.02 ** 2
    a = dc.CandidatePrediction("a", {}, np.zeros(1), 0.0, np.log([10.0, 10.0, 50.0, 60.0, 70.0]), cov)
    b = dc.CandidatePrediction("b", {}, np.zeros(1), 0.0, np.log([10.0, 10.0, 55.0, 60.0, 77.0]), cov)
    c = dc.CandidatePrediction("c", {}, np.zeros(1), 0.0, np.array([2.3, 2.3, np.log(50.0), -np.inf, 4.0]), cov)
    idx, y = [0, 0, 2], np.log([51.0, 49.5, 70.5])                # pool column 0 measured twice
    lp = dc.predictive_logpdf([a, b, c], K, idx, y, sigma)
    ix = K + np.array(idx)
    ref = multivariate_normal(a.log_force[ix], cov[np.ix_(ix, ix)] + sigma ** 2 * np.eye(3)).logpdf(y)
    assert lp[0] == pytest.approx(ref, rel=1e-12) and lp[0] > lp[1] and np.isfinite(lp[2])
    label, w = dc.predictive_choice([a, b], K, idx, y, sigma)
    assert label == "a" and w[0] > 0.9 and abs(w.sum() - 1) < 1e-12
    label, w = dc.predictive_choice([a, b], K, idx, y, sigma, prior=[1e-9, 1 - 1e-9])   # a prior can overrule
    assert label == "b"
    assert dc.predictive_choice([a, c], K, [1], np.log([60.0]), sigma)[1][1] == 0.0     # c cannot produce it
