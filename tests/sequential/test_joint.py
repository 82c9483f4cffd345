"""Joint sequential estimator (beyond the thesis): importance weights, information gain, estimates, criteria."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from neckstrength import sequential as sq
from neckstrength.estimation.datasets import simulated_dataset, thesis_f_actual
from neckstrength.sequential.joint import JointPosterior, JointSettings, run_joint

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def setup(p2m7_full_config):
    _, model, directions = p2m7_full_config
    fa = thesis_f_actual(model, ROOT / "data" / "thesis", "Sim", table="table_6_1_p2m7_sequential.csv")
    data = simulated_dataset(model, directions, "Sim", fa)
    f0, _, _ = sq.scaled_baseline(model, data)
    return model, data, f0


def _post(setup, n=20000, seed=1, **kw):
    model, data, f0 = setup
    return JointPosterior(model, data.directions, data.U, data.force_scale, f0, JointSettings(n_candidates=n, **kw),
                          np.random.default_rng(seed))


def _measure(data):
    return lambda d: (float(data.forces[data.directions.index(d)]), None)


def test_resampling_weights_are_unbiased(setup):
    """Resampled candidates with weights p_0 / q must represent the same distribution: with no test the weighted
    mean and sd are the prior's (wrong weights, e.g. q / p_0, would shift them by the proposal's own spread)."""
    model, data, f0 = setup
    post = _post(setup, n=40000, inflate=1.5)
    before = post.estimate()
    post.resample()
    after = post.estimate()
    assert post.n_resamples == 1
    assert np.all(np.abs(after["f_c"] - f0) / f0 < 0.01)
    assert np.all(np.abs(after["sd_c"] / (0.3 * f0) - 1) < 0.06)
    assert np.all(np.abs(before["f_c"] - after["f_c"]) / f0 < 0.015)
    # after two tests: the posterior mean survives a resample within Monte Carlo error
    post = _post(setup, n=40000)
    for d in ("back", "chinFront"):
        post.update(d, data.forces[data.directions.index(d)])
    e1 = post.estimate()
    post.resample()
    e2 = post.estimate()
    assert np.all(np.abs(e1["f_c"] - e2["f_c"]) < 0.25 * e1["sd_c"])
    # after resample-move the candidates are draws from the target: equal weights, some moves accepted
    assert post.ess_share() == pytest.approx(1.0)
    assert 0.05 < post.last_acceptance < 0.95
    # importance resampling alone: the weights are bounded by the defensive prior share, the mean survives
    post = _post(setup, n=40000, n_moves=0)
    for d in ("back", "chinFront"):
        post.update(d, data.forces[data.directions.index(d)])
    e1 = post.estimate()
    post.resample()
    assert np.exp(post.log_iw).max() <= 1.0 / post.settings.defensive + 1e-9
    assert np.all(np.abs(e1["f_c"] - post.estimate()["f_c"]) < 0.25 * e1["sd_c"])


def test_early_rejection_and_threads_leave_the_chain_unchanged(setup):
    """Early rejection in the Metropolis-Hastings moves (proposals dropped once their partial log-likelihood, plus the
    dual bounds of the terms not solved yet, cannot reach the acceptance threshold) and solver threads are speed only:
    the candidates, wrenches and weights after updates with resample-move are those of the reference (every proposal
    solved in every tested direction, one thread), to the solver's rounding, with the same acceptance rate; early
    rejection skipped LPs, and the dual bounds skipped more."""
    _, data, _ = setup
    runs = {}
    for label, early, bound, threads in (("reference", False, False, 1), ("early", True, False, 1),
                                         ("early+bound", True, True, 1), ("early+bound+threads", True, True, 2)):
        post = _post(setup, n=3000, seed=7, resample_ess=0.3)
        post.early_reject = early
        post.dual_bound_reject = bound
        post.n_threads = threads
        for d in data.directions[:4]:
            post.update(d, 1.1 * data.forces[data.directions.index(d)])
        runs[label] = post
    ref = runs["reference"]
    assert ref.n_resamples >= 2 and 0.02 < ref.last_acceptance < 0.98
    for label in ("early", "early+bound", "early+bound+threads"):
        post = runs[label]
        assert post.n_resamples == ref.n_resamples
        assert post.last_acceptance == ref.last_acceptance
        np.testing.assert_allclose(post.F, ref.F, rtol=1e-12)
        np.testing.assert_allclose(post.W, ref.W, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(post.weights(), ref.weights(), rtol=1e-9, atol=1e-15)
        assert post.n_lps < ref.n_lps, (label, post.n_lps, ref.n_lps)
    assert runs["early+bound"].n_lps < runs["early"].n_lps, (runs["early+bound"].n_lps, runs["early"].n_lps)


def test_dual_bounds_bound_every_term_from_above(setup):
    """The LP-free bounds of the moves (JointPosterior._loglik_upper_bounds: weak duality with the cached bases' dual
    vectors) are at least the exact log-likelihood terms of random strength vectors around the candidates, and equal
    to them (the smallest bound is the optimum) for most where the wrench is below the measured force; a wrong bound
    (the term at the bound also where the bound exceeds the measured force, or the largest bound over the bases
    instead of the smallest) fails one of the two checks."""
    _, data, _ = setup
    post = _post(setup, n=2000, seed=3)
    for d in data.directions[:3]:
        post.update(d, 0.8 * data.forces[data.directions.index(d)])
    _check_upper_bounds(post, np.random.default_rng(0), tight=0.5)


def _check_upper_bounds(post, rng, tight: float):
    """The dual bounds of ``post``'s tested terms at 3,000 perturbed candidates: never below the exact
    log-likelihood terms, and informative (equal to them in more than ``tight`` of the terms whose wrench is below the
    measured force, which must be more than 0.2 of them). Returns the candidates, their wrenches and the columns."""
    cols = post._tested_cols()
    F = post.F[rng.integers(len(post.F), size=3000)] * np.exp(0.2 * rng.standard_normal((3000, post.model.m)))
    W = post._wrenches(F, cols)
    exact = post._loglik_cols(W, cols)
    bound = post._loglik_upper_bounds(F, cols)
    assert np.all(bound >= exact - 1e-9 * np.abs(exact)), float((bound - exact).min())
    below = W[:, cols] < np.array([t["w_meas"] for t in post.tests])
    assert below.mean() > 0.2
    assert np.mean(np.isclose(bound[below], exact[below], rtol=1e-4)) > tight
    return F, W, cols


@pytest.fixture(scope="module")
def emg_setup(p2m7_full_config):
    """p2m7's simulated 'Sim' set with surface EMG bounds (true activation +- 0.05) of TS-B and TS-E."""
    _, model, directions = p2m7_full_config
    fa = thesis_f_actual(model, ROOT / "data" / "thesis", "Sim", table="table_6_1_p2m7_sequential.csv")
    data = simulated_dataset(model, directions, "Sim", fa, emg_groups=("TS-B", "TS-E"))
    assert data.alpha_lb[:, :].max() > 0                      # some lower bounds above 0
    f0, _, _ = sq.scaled_baseline(model, data)
    return model, data, f0


def _emg_post(emg_setup, seed, n_tests=4, scale=1.1, over=0.0, **flags):
    """The posterior after ``n_tests`` tests with EMG bounds; ``over`` > 0: the recorded muscles' activations
    bounded to ``[a + band + over, 1]`` instead (more than the forces need: many candidates cannot produce them)."""
    model, data, f0 = emg_setup
    post = JointPosterior(model, data.directions, data.U, data.force_scale, f0,
                          JointSettings(n_candidates=2000, resample_ess=0.3), np.random.default_rng(seed))
    for k, v in flags.items():
        setattr(post, k, v)
    for d in data.directions[:n_tests]:
        k = data.directions.index(d)
        lb, ub = data.alpha_lb[k].copy(), data.alpha_ub[k].copy()
        if over:
            rec = ub < 1
            lb[rec], ub[rec] = np.minimum(ub[rec] + over, 1.0), 1.0
        post.update(d, scale * data.forces[k], activations=(lb, ub))
    return post


def test_dual_bounds_of_tests_with_emg_bounds_leave_the_chain_unchanged_and_bound_every_term(emg_setup):
    """Tests with activation bounds (EMG) get LP-free bounds too, from each test's own solver: the chain after
    resample-move equals the reference's (every LP solved) and the one without them, with fewer LPs. The bounds are
    at least the exact terms of random strength vectors, also where lower activation bounds make the dual bound
    negative (no solution: wrench 0), which the clip at 0 handles (without it, the check fails there), and where a
    cached infeasibility certificate sets the term to its value at 0."""
    runs = {label: _emg_post(emg_setup, 7, early_reject=e, dual_bound_reject=b, dual_bound_bounded=bb)
            for label, e, b, bb in (("reference", False, False, False), ("unbounded only", True, True, False),
                                    ("with emg bounds", True, True, True))}
    ref = runs["reference"]
    assert ref.n_resamples >= 2 and 0.02 < ref.last_acceptance < 0.98
    for label in ("unbounded only", "with emg bounds"):
        post = runs[label]
        assert post.n_resamples == ref.n_resamples and post.last_acceptance == ref.last_acceptance, label
        np.testing.assert_allclose(post.F, ref.F, rtol=1e-12)
        np.testing.assert_allclose(post.W, ref.W, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(post.weights(), ref.weights(), rtol=1e-9, atol=1e-15)
    assert runs["with emg bounds"].n_lps < runs["unbounded only"].n_lps < ref.n_lps, \
        [runs[k].n_lps for k in ("with emg bounds", "unbounded only", "reference")]
    rng = np.random.default_rng(0)
    for post in (runs["with emg bounds"], _emg_post(emg_setup, 7, over=0.3)):
        assert all(t["bounds"] is not None for t in post.tests)
        F, W, cols = _check_upper_bounds(post, rng, tight=0.3)
    raw = [(post._dual_bound_matrix(int(t["i"]), t["bounds"]).T @ F.T).min(axis=0) for t in post.tests]
    assert min(r.min() for r in raw) < 0 and (W[:, cols] == 0).any()          # the clip at 0 is exercised
    # and the cached infeasibility certificates (the term at 0 exactly where one proves no solution)
    C = [post._farkas_matrix(int(t["i"]), t["bounds"]) for t in post.tests]
    proven = np.column_stack([(F @ c < 0).any(axis=1) if c is not None else np.zeros(len(F), bool) for c in C])
    assert proven.any() and np.all(W[:, cols][proven] == 0)


def test_mc_se_is_the_iid_error_before_resampling_and_tracks_the_spread_after(setup):
    """Monte Carlo error of a posterior mean (JointPosterior.mc_se, the session's ± on P(deficit)): on the prior
    draws it is the iid formula sd / sqrt(N); after resample-move (clusters of descendants of one draw) it is
    within a factor 2 of the spread of the same estimate between independent candidate sets."""
    _, data, f0 = setup
    post = _post(setup, n=4000, seed=5)
    h = (post.F[:, 0] < f0[0]).astype(float)
    assert post.mc_se(h) == pytest.approx(h.std() / math.sqrt(len(h)), rel=1e-9)
    assert post.mc_clusters() == pytest.approx(len(h))
    post.ancestor = np.zeros_like(post.ancestor)      # every candidate a copy of one draw: no error estimate
    assert post.mc_clusters() == pytest.approx(1.0) and post.mc_se(h) == pytest.approx(0.0, abs=1e-12)
    est, se = [], []
    for seed in range(12):
        post = _post(setup, n=1500, seed=100 + seed, resample_ess=0.3)
        for d in ("back", "chinFront", "forehead"):
            post.update(d, 1.15 * data.forces[data.directions.index(d)])
        assert post.n_resamples > 0 and len(np.unique(post.ancestor)) < len(post.ancestor)
        h = (post.F[:, 0] < f0[0]).astype(float)
        est.append(float(post.weights() @ h))
        se.append(post.mc_se(h))
    ratio = float(np.std(est, ddof=1) / np.sqrt(np.mean(np.square(se))))
    assert 0.5 < ratio < 2.0, ratio


def test_information_gain_gaussian_case(setup):
    """For log w ~ N(mu, s^2) and Gaussian log-noise sd, I(f; y) = 0.5 log(1 + s^2 / sd^2)."""
    post = _post(setup, n=1000)
    rng = np.random.default_rng(3)
    wi = np.exp(rng.normal(3.0, 0.3, 200_000))
    w = np.full(len(wi), 1.0 / len(wi))
    sd = post.settings.noise_sd
    assert post._eig(wi, w) == pytest.approx(0.5 * math.log(1 + 0.09 / sd ** 2), abs=0.03)
    assert post._eig(np.full(1000, 5.0), np.full(1000, 1e-3)) == pytest.approx(0.0, abs=0.02)
    # a non-producible share adds the entropy of 'producible or not'
    wi2 = wi.copy()
    wi2[: len(wi) // 2] = 0.0
    assert post._eig(wi2, w) > 0.5 * post._eig(wi, w)


def test_joint_estimate_moves_to_truth_and_validates(setup):
    model, data, f0 = setup
    post = _post(setup)
    it = run_joint(post, _measure(data), "joint_eig", np.random.default_rng(2), f_true=data.f_true)
    err = it.groupby("iteration")["rel_error"].mean()
    assert err.iloc[-1] < err.iloc[0]
    H = it.groupby("iteration")["entropy"].mean()
    assert H.iloc[-1] < H.iloc[0] - 0.2
    est = post.estimate().set_index("muscle")
    # TC-E is identified by the posterior pushes: within 10% of f_a (Table 6.1 'Sim': 275 N)
    i = list(model.muscle_names).index("TC-E")
    assert abs(est.loc["TC-E", "f_c"] - data.f_true[i]) / data.f_true[i] < 0.10
    assert sorted(post.tested) == sorted(data.directions)
    with pytest.raises(ValueError, match="already been tested"):
        post.update("back", 100.0)
    post2 = _post(setup, n=2000)
    with pytest.raises(ValueError, match="positive"):
        post2.update("back", -1.0)
    with pytest.raises(ValueError, match="unknown direction"):
        post2.update("nowhere", 10.0)


def test_criteria_choose_informative_first_test(setup):
    """Both criteria rank the remaining directions; their first choice is among the directions whose predictive
    spread is largest, and the marginal-entropy table has one column per muscle."""
    model, data, f0 = setup
    post = _post(setup)
    c1, t1 = post.propose("joint_eig", np.random.default_rng(0))
    c2, t2 = post.propose("marginal_entropy", np.random.default_rng(0))
    assert set(t1["direction"]) == set(data.directions)
    assert list(t2.columns[1:-1]) == list(model.muscle_names)
    spread = pd.Series({d: np.std(np.log(post.W[post.W[:, i] > 0, i])) for i, d in enumerate(data.directions)})
    top = set(spread.sort_values(ascending=False).index[:3])
    assert c1 in top
    assert t1["score"].max() > 0 and t2["score"].max() > 0
    with pytest.raises(ValueError, match="unknown criterion"):
        post.propose("bogus", np.random.default_rng(0))


def test_deferred_untested_wrenches_leave_the_chain_unchanged(setup):
    """The untested directions' wrenches, deferred after a resample-move until read (JointPosterior.defer_untested),
    are speed only: through tempered updates (several resample-moves per test), a proposal read in between, and a
    snapshot / restore, candidates, wrenches, weights and proposals equal those of the reference that solves them
    after every move, to the solver's rounding; and the deferral skipped LPs."""
    _, data, _ = setup
    forces = {d: 1.4 * data.forces[data.directions.index(d)] for d in data.directions}
    runs = {}
    for label, defer in (("reference", False), ("deferred", True)):
        post = _post(setup, n=2000, seed=11, resample_ess=0.7, max_resamples=4)
        post.defer_untested = defer
        props = []
        for k, d in enumerate(data.directions[:5]):
            if k == 2:
                snap = post.snapshot()
                post.update(d, 0.7 * forces[d])       # undone: restore must bring back the deferred state too
                post.restore(snap)
            post.update(d, forces[d])
            if k in (1, 3):                            # the criterion reads every untested column
                props.append(post.propose("joint_eig", np.random.default_rng(0))[1]["score"].to_numpy())
        runs[label] = post, props
    (ref, ref_props), (post, props) = runs["reference"], runs["deferred"]
    assert ref.n_resamples > 5 and ref.n_resamples == post.n_resamples, ref.n_resamples   # > 1 per test: tempering
    np.testing.assert_allclose(post.F, ref.F, rtol=1e-12)
    np.testing.assert_allclose(post.weights(), ref.weights(), rtol=1e-9, atol=1e-15)
    lps_before_read = post.n_lps
    np.testing.assert_allclose(post.W, ref.W, rtol=1e-9, atol=1e-9)
    for a, b in zip(props, ref_props):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)
    assert lps_before_read < ref.n_lps, (lps_before_read, ref.n_lps)


def test_a_snapshot_survives_its_restore(setup):
    """restore() copies what it adopts: updates after a restore leave the snapshot as it was, so restoring it again
    gives the same state (the same next update) as the first time."""
    _, data, _ = setup
    post = _post(setup, n=500, seed=5)
    post.update(data.directions[0], data.forces[0])
    snap = post.snapshot()
    kept = {k: v.copy() for k, v in snap.items() if isinstance(v, np.ndarray)}
    results = []
    for _ in range(2):
        post.restore(snap)
        post.update(data.directions[1], 0.8 * data.forces[1])
        results.append((post.F.copy(), post.weights().copy(), post.W.copy()))
        for k, v in kept.items():
            np.testing.assert_array_equal(snap[k], v, err_msg=k)
    for a, b in zip(*results):
        np.testing.assert_array_equal(a, b)
