"""Chapter 6 (Algorithms 7-9): subset trick, entropy, selection with priorities, Table 6.1 'Sim', bin choice."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from neckstrength import sequential as sq
from neckstrength.estimation.datasets import simulated_dataset, thesis_f_actual
from neckstrength.wrench import solve

ROOT = Path(__file__).resolve().parents[2]
THESIS = ROOT / "data" / "thesis"
TABLE_6_1 = "table_6_1_p2m7_sequential.csv"
EXTENSION = {"back", "backLow", "backHigh"}   # posterior test points (Fig. 6.1)


@pytest.fixture(scope="module")
def setup(p2m7_full_config):
    _, model, directions = p2m7_full_config
    fa = thesis_f_actual(model, THESIS, "Sim", table=TABLE_6_1)   # Table 6.1 'Sim' f_a
    data = simulated_dataset(model, directions, "Sim", fa, ["TS-B", "TS-E"], 0.05)
    f0, a, _ = sq.scaled_baseline(model, data)
    return model, data, f0


def _sim(setup, n=20000, n_bins=(50,), keep_alpha=True, seed=1, settings=None):
    model, data, f0 = setup
    s = settings or sq.SequentialSettings(n_candidates=n, n_sim=40)
    F = sq.sample_prior(f0, s.prior_sd_rel, n, np.random.default_rng(seed))
    grids = [sq.StrengthGrid.around(f0, s.prior_sd_rel, nb, s.bin_range_sd) for nb in n_bins]
    return sq.SimulatedSet.build(model, data.directions, data.U, F, grids, s.n_wbins, keep_alpha=keep_alpha), s


def _measure(data):
    def measure(d):
        i = data.directions.index(d)
        return float(data.forces[i]), (data.alpha_lb[i], data.alpha_ub[i])
    return measure


@pytest.fixture(scope="module")
def small(setup):
    (sim,), s = _sim(setup)
    return sim, s


def test_prior_and_baseline(setup):
    model, data, f0 = setup
    # Sec. 6.5.1: f_0 = a f'_base, a = mean of the per-direction Eq. 5.3 scalars
    a_i = np.array([data.w_meas[k] / solve(model, model.strengths[None], data.U[k:k + 1])[0][0, 0]
                    for k in range(len(data.directions))])
    assert np.allclose(f0, a_i.mean() * model.strengths)
    F = sq.sample_prior(f0, 0.3, 200000, np.random.default_rng(0))
    assert (F > 0).all()
    assert np.allclose(F.mean(axis=0), f0, rtol=0.01)
    assert np.allclose(F.std(axis=0), 0.3 * f0, rtol=0.02)


def test_subset_trick_equals_sequential_updates(setup, small):
    """Posterior after t tests depends only on the set: explicit updates in 3 orders == the subset table."""
    model, data, _ = setup
    sim, s = small
    K = sim.K
    logliks = np.zeros((K, sim.m, sim.grid.n_bins))
    ref = sq.SequentialState(model, sim, data.force_scale, s)
    for i, d in enumerate(data.directions):
        f, b = _measure(data)(d)
        logliks[i] = ref.likelihood(d, f, b).loglik
    table = sq.subset_table(ref.log_prior, logliks, sim.grid)
    finals = []
    for order in (list(range(K)), list(range(K))[::-1], list(np.random.default_rng(3).permutation(K))):
        st = sq.SequentialState(model, sim, data.force_scale, s)
        mask = 0
        for i in order:
            d = data.directions[i]
            st.update(d, *_measure(data)(d))
            mask |= 1 << int(i)
            np.testing.assert_allclose(st.posterior(), table["pdf"][mask], atol=1e-12)
            E, V = sq.pdf_moments(st.posterior(), sim.grid)
            np.testing.assert_allclose(E, table["E"][mask], rtol=1e-10)
        finals.append(st.estimate()["f_c"].to_numpy())
    np.testing.assert_allclose(finals[0], finals[1], rtol=1e-10)
    np.testing.assert_allclose(finals[0], finals[2], rtol=1e-10)
    # order_entropies: prefix masks of an explicit order give that order's entropies
    orders, H = sq.order_entropies(table["H"], K, np.array([[2, 0, 1, 3, 4, 5, 6]]))
    st = sq.SequentialState(model, sim, data.force_scale, s)
    for t, i in enumerate(orders[0], start=1):
        st.update(data.directions[i], *_measure(data)(data.directions[i]))
        assert H[0, t] == pytest.approx(st.estimate()["entropy"].mean(), rel=1e-10)


@pytest.mark.parametrize("likelihood", ["sum", "mean"])
def test_entropy_decreases_in_expectation(setup, small, likelihood):
    model, data, _ = setup
    sim, s = small
    s = replace(s, likelihood=likelihood)
    st = sq.SequentialState(model, sim, data.force_scale, s)
    p = st.propose(np.random.default_rng(4))
    # Eq. 6.6 summed over muscles: every direction reduces the expected entropy from the prior
    assert (p.dS.sum(axis=1) > 0).all()
    # and over the actual measurements: the mean entropy over all 7! orders falls with every test
    K = sim.K
    logliks = np.stack([st.likelihood(d, *_measure(data)(d)).loglik for d in data.directions])
    table = sq.subset_table(st.log_prior, logliks, sim.grid)
    _, H = sq.order_entropies(table["H"], K)
    assert np.all(np.diff(H.mean(axis=0)) < 0)


def test_fast_expected_entropy_matches_exact(setup, small):
    """The binned-wrench Algorithm 9 equals the per-candidate one up to the wrench-grid resolution."""
    model, data, _ = setup
    sim, s = small
    st = sq.SequentialState(model, sim, data.force_scale, s)
    st.update("back", *_measure(data)("back"))
    fast = st.propose(np.random.default_rng(7))
    exact = st.propose(np.random.default_rng(7), exact=True)
    assert np.abs(fast.dS - exact.dS).max() < 0.03
    assert fast.choice == exact.choice


def test_gamma_selects_best_direction_for_prioritised_muscle(setup, small):
    """Eq. 6.8 with gamma zero except one muscle picks the direction with that muscle's largest Delta S."""
    model, data, _ = setup
    sim, s = small
    st = sq.SequentialState(model, sim, data.force_scale, s)
    names = list(model.muscle_names)
    free = st.propose(np.random.default_rng(11))
    choices = {}
    for j, n in enumerate(names):
        p = st.propose(np.random.default_rng(11), gamma={n: 1.0})
        np.testing.assert_allclose(p.dS, free.dS)          # same draws, same Eq. 6.6
        assert p.choice == p.directions[int(np.argmax(p.dS[:, j]))]
        choices[n] = p.choice
    assert choices["TC-E"] in EXTENSION                    # the trunk-skull extensor is tested by pushing backwards
    assert choices["TC-F"] not in EXTENSION
    assert len(set(choices.values())) > 1                  # priorities change the choice
    # Eq. 6.7 = Eq. 6.8 with gamma = 1
    assert sq.select_direction(free.dS) == sq.select_direction(free.dS, np.ones(len(names)))


def test_table_6_1_simulated_run(setup):
    """Table 6.1 'Sim': D(f_c) high (thesis 0.97) and TC-E close to f_a (thesis 290 vs 275)."""
    model, data, f0 = setup
    (sim,), s = _sim(setup, n=60000, keep_alpha=False, seed=5)
    st = sq.SequentialState(model, sim, data.force_scale, s)
    props, it = sq.run_sequence(st, _measure(data), np.random.default_rng(2))
    assert sorted(st.tested) == sorted(data.directions) and len(props) == 7
    est = st.estimate().set_index("muscle")
    D, fit = sq.fit_point_estimate(model, data, est["f_c"].to_numpy(), s.epsilon)
    assert D > 0.95
    assert abs(est.loc["TC-E", "f_c"] / 275.0 - 1) < 0.08
    assert abs(est.loc["CS-F", "f_c"] / 112.0 - 1) < 0.15
    # the pattern of Table 6.1: TC-E confident, TS-E not (thesis v_c 14 vs 255 N^2)
    assert est.loc["TS-E", "v_c"] > 5 * est.loc["TC-E", "v_c"]
    # the first test pushes backwards (TC-E dominates the expected entropy reduction)
    assert props[0].choice in EXTENSION


def test_bin_choice_does_not_drive_the_result(setup):
    """Same candidates and draws on 25 / 50 / 100 bins: estimates and Algorithm 9's scores agree."""
    model, data, _ = setup
    sims, s = _sim(setup, n=30000, n_bins=(25, 50, 100), keep_alpha=False, seed=9)
    est, scores = {}, {}
    for sim in sims:
        st = sq.SequentialState(model, sim, data.force_scale, replace(s, n_bins=sim.grid.n_bins))
        scores[sim.grid.n_bins] = st.propose(np.random.default_rng(1)).table()["score"].to_numpy()
        for d in data.directions:
            st.update(d, *_measure(data)(d))
        est[sim.grid.n_bins] = st.estimate()
    f50, f100, f25 = (est[k]["f_c"].to_numpy() for k in (50, 100, 25))
    assert np.abs(f100 / f50 - 1).max() < 0.02
    assert np.abs(f25 / f50 - 1).max() < 0.05
    sd50, sd100 = np.sqrt(est[50]["v_c"].to_numpy()), np.sqrt(est[100]["v_c"].to_numpy())
    assert np.abs(sd100 / sd50 - 1).max() < 0.15
    for k in (25, 100):
        assert np.corrcoef(scores[k], scores[50])[0, 1] > 0.95


def test_state_undo_save_load(tmp_path, setup, small):
    model, data, _ = setup
    sim, s = small
    st = sq.SequentialState(model, sim, data.force_scale, s, seed=123)
    p0 = st.posterior()
    st.update("back", *_measure(data)("back"))
    p1 = st.posterior()
    st.update("forehead", data.forces[0], {"TS-B": 0.5})   # an activation entered as {muscle: value} +- band
    with pytest.raises(ValueError):
        st.update("back", 100.0)                            # each direction once
    st.save(tmp_path / "state.json")
    back = sq.SequentialState.load(tmp_path / "state.json", model, sim, data.force_scale)
    np.testing.assert_allclose(back.posterior(), st.posterior(), atol=1e-12)
    assert back.tested == ["back", "forehead"] and back.seed == 123
    assert st.undo() == "forehead"
    np.testing.assert_allclose(st.posterior(), p1, atol=1e-12)
    st.undo()
    np.testing.assert_allclose(st.posterior(), p0, atol=1e-12)
    sim.save(tmp_path / "sim.npz")
    again = sq.SimulatedSet.load(tmp_path / "sim.npz")
    assert sq.sim_key(again) == sq.sim_key(sim)
    np.testing.assert_array_equal(again.A, sim.A)


def test_stop_criteria():
    E = np.array([[100.0, 50], [80, 55], [90, 52], [91, 51], [90.5, 51]])
    assert sq.stop_iteration(E, 0.05) == 2          # from t = 2 on within 5% of the final
    assert sq.stop_iteration(E, 0.001) == 4
    assert sq.stop_by_expected_gain([1.0, 0.5, 0.3, 0.15, 0.1], 0.2) == 3
    assert sq.stop_by_expected_gain([1.0, 0.9], 0.2) == 2
