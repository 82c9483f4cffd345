"""Simulation-based calibration machinery (neckstrength.calibration.sbc)."""

import numpy as np
import pandas as pd
import pytest

from neckstrength.abc.algorithm4 import ABCSettings
from neckstrength.abc.smc import SMCSettings
from neckstrength.calibration.sbc import (
    SBCSettings,
    coverage_summary,
    draw_participant,
    run_sbc,
    weighted_pit,
    weighted_quantiles,
)
from neckstrength.estimation.datasets import model_directions_table
from neckstrength.sequential.joint import JointSettings
from neckstrength.wrench import solve


def test_weighted_pit_and_quantiles_on_known_samples():
    s = np.array([[1.0], [2.0], [3.0], [4.0]])
    w = np.array([0.1, 0.2, 0.3, 0.4])
    assert weighted_pit(s, w, np.array([2.5]))[0] == pytest.approx(0.3)
    assert weighted_pit(s, w, np.array([3.0]))[0] == pytest.approx(0.3 + 0.15)   # a tie counts half
    assert weighted_pit(s, w, np.array([0.0]))[0] == 0.0
    q = weighted_quantiles(s, w, [0.05, 0.5, 0.95])
    assert q[0, 0] == pytest.approx(1.0) and q[2, 0] == pytest.approx(4.0) and 2.0 < q[1, 0] < 4.0


def _conjugate_rows(sd_factor, n_rep=1500, n_post=400, seed=3):
    """theta ~ N(0, 1), y ~ N(theta, 1): posterior N(y / 2, 1/2). ``sd_factor`` != 1 mis-states its width."""
    from neckstrength.calibration.sbc import LEVELS, pit_rows

    class M:
        name = "toy"
        muscle_names = ["a"]

    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n_rep):
        th = rng.standard_normal(1)
        y = th + rng.standard_normal(1)
        post = (y / 2 + sd_factor * np.sqrt(0.5) * rng.standard_normal((n_post, 1)))
        w = np.ones(n_post)
        u = weighted_pit(post, w, th)
        Q = weighted_quantiles(post, w, [q for L in LEVELS for q in (0.5 - L / 2, 0.5 + L / 2)])
        rows += pit_rows(M, th, u, {L: Q[2 * k] for k, L in enumerate(LEVELS)},
                         {L: Q[2 * k + 1] for k, L in enumerate(LEVELS)}, post.mean(axis=0),
                         {"method": "smc", "model": "toy", "participant": i, "t": np.nan, "n_sim": n_post})
    df = pd.DataFrame(rows)
    df["truth"] = df["truth"] + 10.0   # keep the relative-error column finite (shifts nothing else)
    df["mean"] = df["mean"] + 10.0
    df["lower90"] += 10.0
    df["upper90"] += 10.0
    return df


def test_sbc_summary_recognises_a_calibrated_and_an_overconfident_posterior():
    ok = coverage_summary(_conjugate_rows(1.0)).iloc[0]
    assert 0.86 <= ok["coverage90"] <= 0.94 and 0.45 <= ok["coverage50"] <= 0.55
    assert ok["calibrated90"] and ok["pit_ks_p"] > 0.001
    narrow = coverage_summary(_conjugate_rows(0.4)).iloc[0]
    assert narrow["coverage90"] < 0.6 and not narrow["calibrated90"] and narrow["pit_ks_p"] < 1e-6


def test_sbc_settings_reject_unknown_methods():
    with pytest.raises(ValueError, match="unknown SBC method"):
        SBCSettings(methods=("alg4", "mcmc"))


def test_draw_participant_simulates_the_truth(p2m7_full_config):
    cfg, model, directions = p2m7_full_config
    f_ref = model.strengths
    truth, data = draw_participant(model, directions, f_ref, "lognormal", 0.3, 0.0, np.random.default_rng(1))
    _, U = model_directions_table(model, directions)
    w, _, _ = solve(model, truth[None, :], U, return_alpha=False)
    np.testing.assert_allclose(data.w_meas, w[0])
    assert not np.allclose(truth, f_ref)
    _, noisy = draw_participant(model, directions, f_ref, "lognormal", 0.3, 0.05, np.random.default_rng(1))
    r = np.log(noisy.w_meas / w[0])
    assert 0 < np.abs(r).max() < 0.3 and np.all(np.isfinite(r))


def test_run_sbc_small_p2m7_rows_and_heuristic_label(p2m7_full_config):
    cfg, model, directions = p2m7_full_config
    f_ref = model.strengths
    s = SBCSettings(n_participants=2, methods=("alg4", "smc", "joint"), checkpoints=(5, 10))
    df = run_sbc(model, directions, f_ref, s, ABCSettings(sigma0=0.3, max_iter=5), SMCSettings(n_particles=100,
                 budget=400), JointSettings(n_candidates=500, noise_rel=0.05),
                 lambda m, i: np.random.default_rng([7, len(m), i]))
    m = model.m
    assert len(df[df["method"] == "alg4"]) == 2 * m and len(df[df["method"] == "smc"]) == 2 * m
    j = df[df["method"] == "joint"]
    assert sorted(j["t"].unique()) == [5, 7]          # 10 is capped at the 7 p2m7 directions
    assert (df["lower90"] <= df["lower50"] + 1e-9).all() and (df["upper50"] <= df["upper90"] + 1e-9).all()
    assert ((df["truth"] >= df["lower90"]) & (df["truth"] <= df["upper90"]) == df["covered90"]).all()
    a = df[df["method"] == "alg4"]
    np.testing.assert_array_equal(a["covered_reported"], (a["truth"] >= a["mean"] * (1 - a["sigma_c"]))
                                  & (a["truth"] <= a["mean"] * (1 + a["sigma_c"])))
    summ = coverage_summary(df)
    assert "alg4 sigma_c (heuristic)" in set(summ["label"])
    # same participants for a chunk started at index 1 (the run can be split)
    one = run_sbc(model, directions, f_ref, SBCSettings(n_participants=1, methods=("smc",)), ABCSettings(),
                  SMCSettings(n_particles=100, budget=400), JointSettings(n_candidates=500),
                  lambda m, i: np.random.default_rng([7, len(m), i]), first=1)
    np.testing.assert_allclose(one["truth"], df[(df["method"] == "smc") & (df["participant"] == 1)]["truth"])
    np.testing.assert_allclose(one["mean"], df[(df["method"] == "smc") & (df["participant"] == 1)]["mean"])
