"""Chapter 5 estimator (Algorithm 4): equations, end-to-end on simulated data, checkpoint/resume."""

from pathlib import Path

import numpy as np
import pytest

from neckstrength.abc.algorithm4 import (
    ABCSettings,
    candidate_grid,
    estimate_strengths,
    muscle_posterior,
    update_estimate,
)
from neckstrength.config import build_directions, full_model_from_config, load_config, model_from_config
from neckstrength.estimation.datasets import DatasetSettings, load_dataset, thesis_f_actual
from neckstrength.estimation.discrepancy import composite_score, data_discrepancy
from neckstrength.estimation.parameters import free_parameters
from neckstrength.estimation.scaling import bootstrap_prior

ROOT = Path(__file__).resolve().parents[2]
THESIS = ROOT / "data" / "thesis"


@pytest.fixture(scope="module")
def env():
    cfg = load_config(ROOT / "config" / "config.yaml")
    cfg["data"] = {k: str(ROOT / v) for k, v in cfg["data"].items()}
    cfg["geometry"]["test_point_spec"] = str(ROOT / cfg["geometry"]["test_point_spec"])
    return cfg, full_model_from_config(cfg), build_directions(cfg)


def test_eq_5_5_and_5_6():
    w_meas = np.array([100.0, 200.0])
    d = data_discrepancy(np.array([[100.0, 200.0], [110.0, 180.0]]), w_meas, 3.0)
    assert np.allclose(d[0], 1.0)
    assert d[1, 0] == pytest.approx(np.exp(-(3 * 0.1) ** 2)) and d[1, 1] == pytest.approx(np.exp(-(3 * 0.1) ** 2))
    assert composite_score(d)[1] == pytest.approx(np.exp(-0.09))


def test_eq_5_4_grid_is_every_combination():
    samples, P, theta = candidate_grid(np.array([100.0, 10.0, 1.0]), np.array([0.2, 0.1, 0.3]))
    assert samples.shape == (3, 3) and np.allclose(samples[:, 0], [80, 100, 120])
    assert theta.shape == (27, 3) and len({tuple(r) for r in theta}) == 27
    assert np.allclose(theta, samples[P, np.arange(3)])


def test_eq_5_7_to_5_12_posterior_and_update():
    P = np.array([[0, 1], [1, 1], [2, 0], [1, 2]], dtype=np.int8)
    weights = np.array([[1.0, 0.0], [3.0, 0.0], [0.0, 0.0], [1.0, 0.0]])
    pi = muscle_posterior(weights, P)
    assert np.allclose(pi[0], [0.2, 0.8, 0.0])
    assert np.allclose(pi[1], [1 / 3] * 3)          # never active: uniform, no information
    samples = np.array([[80.0, 8.0], [100.0, 10.0], [120.0, 12.0]])
    f, s = update_estimate(samples, pi, np.array([0.2, 0.2]), 0.01, 0.3)
    assert f[0] == pytest.approx(0.2 * 80 + 0.8 * 100) and f[1] == pytest.approx(10.0)
    assert s[0] == pytest.approx((1 - 0.8) * 0.2)     # middle most probable: K = 1 - Delta
    assert s[1] == pytest.approx(0.2)                 # uniform: Delta = 0, K = 1
    pi_edge = np.array([[0.6, 0.3, 0.1]])
    _, s2 = update_estimate(samples[:, :1], pi_edge, np.array([0.2]), 0.01, 0.3)
    assert s2[0] == pytest.approx(min(0.3, 0.2 * (1 + np.exp(-5 * 0.5 - 1))))


def test_tied_sides(env):
    _, full, _ = env
    m = model_from_config(full, env[0], "s3m24")
    idx, names = free_parameters(m, True)
    assert len(names) == 12 and idx[m.muscle_names.index("mf-R")] == idx[m.muscle_names.index("mf-L")]


def test_p2m7_simulated_norm_converges_and_fits(env, tmp_path):
    cfg, full, d = env
    m = model_from_config(full, cfg, "p2m7")
    data = load_dataset(m, d, "norm", DatasetSettings(), THESIS, cfg["data"]["measurements"],
                        cfg["data"]["activations"])
    assert np.allclose(data.f_true, thesis_f_actual(m, THESIS, "norm"))
    f0, a = bootstrap_prior(m, data, "back")
    ck = tmp_path / "ck.npz"
    r = estimate_strengths(m, data, ABCSettings(sigma0=0.3, max_iter=30), f0, a, checkpoint=ck, progress=None)
    assert r.converged and r.D_fc > 0.95
    # the deep extensors (TC-E) are identified within 10% (thesis Table 5.1: 284 vs 275)
    k = r.param_names.index("TC-E")
    assert abs(r.f_c[k] - data.f_true[k]) / data.f_true[k] < 0.10
    assert (r.scores["D_min"].diff().dropna() > -0.2).all()
    # resume: a second call with identical inputs starts from the checkpoint and gives the same answer
    r2 = estimate_strengths(m, data, ABCSettings(sigma0=0.3, max_iter=30), f0, a, checkpoint=ck, progress=None)
    assert np.allclose(r2.f_c, r.f_c) and r2.iterations == r.iterations


def test_weak_deep_extensors_identified_p2m7(env):
    cfg, full, d = env
    m = model_from_config(full, cfg, "p2m7")
    data = load_dataset(m, d, "weak", DatasetSettings(), THESIS, cfg["data"]["measurements"],
                        cfg["data"]["activations"])
    f0, a = bootstrap_prior(m, data, "back")
    r = estimate_strengths(m, data, ABCSettings(sigma0=0.3, max_iter=30), f0, a, progress=None)
    k = r.param_names.index("TC-E")
    assert abs(r.f_c[k] - 69) / 69 < 0.3 and r.sigma_c[k] < 0.05


def test_abc_smc_improves_fit_and_respects_budget(env):
    from neckstrength.abc.smc import SMCSettings, abc_smc

    cfg, full, d = env
    m = model_from_config(full, cfg, "p2m7")
    data = load_dataset(m, d, "norm", DatasetSettings(simulated_emg=False), THESIS, cfg["data"]["measurements"],
                        cfg["data"]["activations"])
    f0, _ = bootstrap_prior(m, data, "back")
    r = abc_smc(m, data, f0, SMCSettings(n_particles=300, budget=6000), np.random.default_rng(3))
    assert r.n_simulations <= 6000
    assert np.isclose(r.weights.sum(), 1.0) and (r.weights >= 0).all()
    g = r.generations
    assert len(g) >= 3 and g["median_distance"].iloc[-1] < g["median_distance"].iloc[0]
    # the deep extensors (TC-E) are well identified by the free sampler too
    k = list(m.muscle_names).index("TC-E")
    assert abs(r.mean()[k] - 275) / 275 < 0.15


class _Kill(Exception):
    pass


def _compare(r, u):
    """Every output of a resumed run equals the uninterrupted run's (scores: apart from the seconds)."""
    assert r.D_fc == u.D_fc and r.iterations == u.iterations and r.converged == u.converged
    assert np.array_equal(r.f_c, u.f_c) and np.array_equal(r.sigma_c, u.sigma_c)
    for name in ("history", "dk_hist", "d_final", "fit", "candidates"):
        a, b = getattr(r, name), getattr(u, name)
        assert a.to_csv(index=False) == b.to_csv(index=False), name
    assert (r.scores.drop(columns="seconds").to_csv(index=False)
            == u.scores.drop(columns="seconds").to_csv(index=False))


def test_resumed_run_is_identical_to_an_uninterrupted_one(env, tmp_path):
    """Killed after iteration k (k = 1, 2 and the last), the resumed run writes the same d_by_direction, D_fc,
    candidates and history as a run that was never interrupted."""
    cfg, full, d = env
    m = model_from_config(full, cfg, "p2m7")
    data = load_dataset(m, d, "norm", DatasetSettings(), THESIS, cfg["data"]["measurements"],
                        cfg["data"]["activations"])
    f0, a = bootstrap_prior(m, data, "back")
    s = ABCSettings(sigma0=0.3, max_iter=3, eps_D=0.999, store_candidates=500)
    u = estimate_strengths(m, data, s, f0, a, rng=np.random.default_rng(11), progress=None)
    assert u.iterations == 3 and not u.converged
    for k in (1, 2, 3):
        ck = tmp_path / f"ck{k}.npz"

        def kill_after(line, k=k):             # the progress line of iteration k+1 comes before its checkpoint
            if f"iteration {k + 1}/" in line:
                raise _Kill

        if k < 3:
            with pytest.raises(_Kill):
                estimate_strengths(m, data, s, f0, a, rng=np.random.default_rng(11), checkpoint=ck,
                                   progress=kill_after)
        else:                                  # killed after the last checkpoint, before the outputs
            estimate_strengths(m, data, s, f0, a, rng=np.random.default_rng(11), checkpoint=ck, progress=None)
        assert int(np.load(ck)["iteration"]) == k
        seen = []
        r = estimate_strengths(m, data, s, f0, a, rng=np.random.default_rng(11), checkpoint=ck,
                               progress=seen.append)
        assert f"resuming after iteration {k}" in seen[0]
        _compare(r, u)
