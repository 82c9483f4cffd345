"""Identifiability profiles (issue 31 item 1): the optimiser, the HiGHS check, bounds, the noise-level rule."""

import os
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

from neckstrength.identifiability.check import check_against_highs, highs_max_wrench, highs_wrenches
from neckstrength.identifiability.noise import CHI2_1_95, lr_statistic, sigma_star
from neckstrength.identifiability.profile import (
    ProfileProblem,
    ProfileSettings,
    batched_lm,
    group_index,
    group_names,
    neutral_battery,
    profile_group,
    strengths_from_factors,
)

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def s3m24():
    from neckstrength.config import build_directions, full_model_from_config, load_config, model_from_config
    from neckstrength.estimation.datasets import model_directions_table, thesis_f_actual

    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        cfg = load_config(ROOT / "config" / "config.yaml")
        model = model_from_config(full_model_from_config(cfg), cfg, "s3m24")
        d, U = model_directions_table(model, build_directions(cfg))
        normal = thesis_f_actual(model, cfg["data"]["thesis_dir"], "norm")
    finally:
        os.chdir(cwd)
    return model, list(d["name"]), U, normal


def _problem(s3m24, factors, name="truth"):
    model, labels, U, normal = s3m24
    bat = neutral_battery(model, labels, U)
    f = strengths_from_factors(normal, group_index(model.muscle_names), factors)[0]
    w, st = bat.wrenches(f[None, :])
    assert np.all(st == 0)
    return ProfileProblem(name, bat, w[0], normal), f


def test_profile_at_truths_own_factor_is_zero(s3m24):
    """Every group off normal (within the box) and mf at 0.5: the profile at r = 0.5 must find a zero misfit from
    starts that are all off the truth; at r = 1.0 it must not (the 25 tests see a 50% mf deficit)."""
    model = s3m24[0]
    names = group_names(model.muscle_names)
    rng = np.random.default_rng(7)
    fac = np.exp(rng.normal(0, 0.2, len(names)))
    fac = np.clip(fac, 0.6, 1.6)
    fac[names.index("mf")] = 0.5
    prob, _ = _problem(s3m24, fac[None, :])
    s = ProfileSettings(grid=(0.5, 1.0), bounds=(("anatomical", 0.5, 2.0),), n_starts=3, continuation=True)
    df = profile_group(prob, "mf", s, np.random.default_rng(1), s.bounds[0])
    at = df.set_index("r")
    assert at.loc[0.5, "rms"] < 1e-4, at.loc[0.5, "rms"]
    assert at.loc[1.0, "rms"] > 10 * at.loc[0.5, "rms"] + 1e-3


def test_bounds_respected_and_reported(s3m24):
    names = group_names(s3m24[0].muscle_names)
    fac = np.ones(len(names))
    fac[names.index("mf")] = 0.25
    prob, _ = _problem(s3m24, fac[None, :], "weak-like")
    lo, hi = 0.5, 2.0
    s = ProfileSettings(grid=(0.6, 1.0, 1.2), bounds=(("anatomical", lo, hi),), n_starts=2)
    df = profile_group(prob, "mf", s, np.random.default_rng(3), s.bounds[0])
    for _, row in df.iterrows():
        for n in names:
            v = row[f"f_{n}"]
            if n == "mf":
                assert v == pytest.approx(row["r"])
                continue
            assert lo * (1 - 1e-12) <= v <= hi * (1 + 1e-12)
            assert (n in row["on_lower"].split()) == (v <= lo * (1 + 1e-6))
            assert (n in row["on_upper"].split()) == (v >= hi * (1 - 1e-6))
    # a profile away from the truth cannot fit exactly, and its value is the RMS of the stored optimum
    r1 = df.set_index("r").loc[1.0]
    f = strengths_from_factors(prob.normal, group_index(s3m24[0].muscle_names),
                               r1[[f"f_{n}" for n in names]].to_numpy(float)[None, :])
    w, _ = prob.battery.wrenches(f)
    rms = np.sqrt(np.mean(np.log(w[0] / prob.w_data) ** 2))
    assert rms == pytest.approx(r1["rms"], rel=1e-9)
    assert rms > 0.01


def test_highs_check_agrees_and_catches_a_wrong_solver(s3m24):
    model, labels, U, normal = s3m24
    bat = neutral_battery(model, labels, U)
    rng = np.random.default_rng(11)
    for _ in range(3):
        f = normal * np.exp(rng.normal(0, 0.3, model.m))
        assert check_against_highs(bat, f, 1e-6) <= 1e-6

    class Off(type(bat)):
        def wrenches(self, F):
            w, st = super().wrenches(F)
            w[:, 3] *= 1 + 1e-5
            return w, st

    off = Off(bat.labels, bat.blocks)
    with pytest.raises(AssertionError, match=labels[3]):
        check_against_highs(off, normal, 1e-6)


def test_highs_lp_on_a_hand_solved_case():
    # one joint, a flexor and an extensor: R = [1, -1], J^T = [1]; the max wrench along +1 is the flexor's strength
    R, JT = np.array([[1.0, -1.0]]), np.array([[1.0]])
    assert highs_max_wrench(R, JT, np.array([1.0]), np.zeros(2), np.array([30.0, 50.0])) == pytest.approx(30.0)
    assert highs_max_wrench(R, JT, np.array([-1.0]), np.zeros(2), np.array([30.0, 50.0])) == pytest.approx(50.0)
    # an activation lower bound on the antagonist costs its force
    assert highs_max_wrench(R, JT, np.array([1.0]), np.array([0.0, 10.0]), np.array([30.0, 50.0])) == \
        pytest.approx(20.0)
    # bounds no activation meets (the antagonist held above what the agonist can pull): no wrench, 0 as the
    # batched solver reports it (found at full size with EMG bounds)
    assert highs_max_wrench(R, JT, np.array([1.0]), np.array([0.0, 40.0]), np.array([30.0, 50.0])) == 0.0


def test_batched_lm_matches_scipy_on_a_bounded_problem():
    rng = np.random.default_rng(5)
    N, K, p = 6, 9, 4
    A = rng.normal(size=(N, K, p))
    y = rng.normal(size=(N, K)) * 2
    lo, hi = -0.5, 0.7

    def resid(X, ids):
        return np.einsum("nkp,np->nk", A[ids], X) + np.sin(X).sum(axis=1, keepdims=True) * 0.3 - y[ids]

    res = batched_lm(resid, np.zeros((N, p)), lo, hi, max_iter=200, fd_step=1e-7, tol=1e-14)
    for i in range(N):
        ref = least_squares(lambda x: resid(x[None, :], np.array([i]))[0], np.zeros(p), bounds=(lo, hi),
                            xtol=1e-14, ftol=1e-14, gtol=1e-14)
        assert res.cost[i] <= ref.cost * (1 + 1e-6) + 1e-12
        assert np.all((res.x[i] >= lo) & (res.x[i] <= hi))


def test_noise_level_rule():
    rms, n = 0.04, 25
    s = float(sigma_star(rms, n))
    assert s == pytest.approx(rms * np.sqrt(n / 3.84), rel=1e-3)
    assert lr_statistic(rms, n, s) == pytest.approx(CHI2_1_95)
    assert lr_statistic(rms, n, 0.9 * s) > CHI2_1_95 > lr_statistic(rms, n, 1.1 * s)
    assert float(sigma_star(rms, 4 * n)) == pytest.approx(2 * s)     # four times the tests: twice the noise
    with pytest.raises(ValueError):
        lr_statistic(rms, n, 0.0)
