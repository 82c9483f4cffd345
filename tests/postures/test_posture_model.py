"""Reduced models per posture, mixed-test data sets and the estimators on them (issue 20)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from neckstrength.abc.algorithm4 import _simulate
from neckstrength.abc.smc import SMCSettings, abc_smc
from neckstrength.config import build_directions, load_config
from neckstrength.estimation.datasets import model_directions_table
from neckstrength.io import DataValidationError
from neckstrength.model.full import load_full_model
from neckstrength.model.reduction import named_model, scale_strengths
from neckstrength.postures.compare import ComparisonSettings, compare_postures, summarize
from neckstrength.postures.datasets import posture_dataset, posture_grid, read_posture_measurements
from neckstrength.postures.model import build_posture_set, pair_label, split_label
from neckstrength.postures.sequential import PostureJointPosterior
from neckstrength.postures.tables import load_posture_tables
from neckstrength.sequential.joint import JointSettings
from neckstrength.wrench import solve

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def setup():
    cfg = load_config(ROOT / "config" / "config.ci.yaml")
    full = load_full_model(ROOT / "data" / "model", ROOT / "data" / "thesis", "derived")
    tables = load_posture_tables(ROOT / "data" / "model")
    d = build_directions({**cfg, "geometry": {**cfg["geometry"],
                                              "test_point_spec": str(ROOT / cfg["geometry"]["test_point_spec"])}})
    neutral = named_model(full, "p3m12", ROOT / "data" / "thesis", "anatomy")
    return full, tables, d, neutral, build_posture_set(full, neutral, tables)


def test_neutral_posture_is_the_named_model(setup):
    _, _, d, neutral, ps = setup
    _, U = model_directions_table(neutral, d)
    F = neutral.strengths * np.exp(0.2 * np.random.default_rng(0).standard_normal((20, neutral.m)))
    w0, _, _ = solve(neutral, F, U)
    w, _, _ = ps.wrenches(F, U, ["neutral"] * len(U))
    np.testing.assert_allclose(w, w0, rtol=1e-9)
    assert ps.models["neutral"] is neutral and np.all(ps.rho["neutral"] == 1.0)


def test_rho_reparametrisation_is_exact(setup):
    """Scaling a group's elements before the posture reduction = scaling the neutral group strength (x . rho)."""
    full, tables, d, neutral, ps = setup
    _, U = model_directions_table(neutral, d)
    g = list(neutral.muscle_names).index("multif")
    mask = neutral.S[:, g] > 0
    full_w = scale_strengths(full, mask, 0.4)
    ps_w = build_posture_set(full_w, named_model(full_w, "p3m12", ROOT / "data" / "thesis", "anatomy"), tables)
    x = neutral.strengths.copy()
    x[g] *= 0.4
    for p in ("ext20", "rotL30"):
        a, _, _ = ps.wrenches(x[None], U, [p] * len(U))
        b, _, _ = ps_w.wrenches(ps_w.strengths[None], U, [p] * len(U))
        np.testing.assert_allclose(a, b, rtol=1e-7)


def test_postures_change_the_max_wrench_and_the_deep_extensors_share(setup):
    _, _, d, neutral, ps = setup
    grid = posture_grid(ps, d)
    assert len(grid) == 7 * len(ps.postures)
    base = posture_dataset(ps, grid, "base", neutral.strengths)
    x = neutral.strengths.copy()
    x[list(neutral.muscle_names).index("multif")] *= 0.3
    weak = posture_dataset(ps, grid, "weak", x)
    drop = pd.Series(1 - weak.w_meas / base.w_meas, index=base.directions)
    # the deficit shows differently in different postures: that is what makes postures informative
    by_posture = drop.groupby([split_label(k)[0] for k in drop.index]).max()
    assert by_posture.max() - by_posture.min() > 0.01
    assert pair_label("neutral", "back") == "back" and split_label("ext20:back") == ("ext20", "back")


def test_posture_column_in_measurements(tmp_path, setup):
    p = tmp_path / "m.csv"
    p.write_text("direction,posture,S001\nback,neutral,100\nback,ext20,80\nfront,flex20,50\n")
    m = read_posture_measurements(p, ["back", "front"], ["neutral", "ext20", "flex20"])
    assert list(m.index) == ["back", "ext20:back", "flex20:front"]
    q = tmp_path / "old.csv"
    q.write_text("direction,S001\nback,100\n")
    assert list(read_posture_measurements(q, ["back"], ["neutral"])["posture"]) == ["neutral"]
    p.write_text("direction,posture,S001\nback,neutral,100\nback,upside_down,80\n")
    with pytest.raises(DataValidationError, match="posture"):
        read_posture_measurements(p, ["back"], ["neutral", "ext20"])


def test_abc_smc_and_algorithm4_take_mixed_tests(setup):
    _, _, d, neutral, ps = setup
    grid = posture_grid(ps, d)
    data = posture_dataset(ps, grid, "mix", neutral.strengths)
    res = abc_smc(ps, data, neutral.strengths, SMCSettings(n_particles=100, budget=400),
                  np.random.default_rng(1))
    assert res.particles.shape[1] == neutral.m and res.n_simulations >= 400
    w, _, _ = _simulate(ps, neutral.strengths[None], data, 1024, False)
    np.testing.assert_allclose(w[0], data.w_meas, rtol=1e-9)
    with pytest.raises(ValueError, match="PostureSet"):
        abc_smc(neutral, data, neutral.strengths, SMCSettings(n_particles=50, budget=100), np.random.default_rng(1))


def test_joint_estimator_over_pairs_and_change_cost(setup):
    _, _, d, neutral, ps = setup
    grid = posture_grid(ps, d)
    U = grid[[c for c in grid.columns if c.startswith("u") and c[1:].isdigit()]].to_numpy(float)
    data = posture_dataset(ps, grid, "mix", neutral.strengths)
    st = JointSettings(n_candidates=1500, n_moves=0)

    def run(cost):
        post = PostureJointPosterior(ps, list(grid["label"]), U, grid["force_scale"].to_numpy(float),
                                     list(grid["posture"]), neutral.strengths, st, np.random.default_rng(3),
                                     change_cost=cost)
        out = []
        for _ in range(4):
            label, tab = post.propose("joint_eig", np.random.default_rng(4))
            if cost == 0:
                assert label == tab.loc[tab["gain"].idxmax(), "direction"]
            post.update(label, data.forces[data.directions.index(label)])
            out.append(post.current_posture)
        return out

    free = run(0.0)
    assert any(p != "neutral" for p in free)            # postures are worth it when free
    assert run(1e6) == ["neutral"] * 4                   # never when each change costs more than any gain


def test_comparison_runs_and_reports_every_group(setup):
    _, _, d, neutral, ps = setup
    s = ComparisonSettings(n_deficit=1, n_normal=0, t_values=(3, 9))
    g, picks = compare_postures(ps, d, ["multif"], JointSettings(n_candidates=800, n_moves=0), s,
                                np.random.SeedSequence(5))
    summ, ident = summarize(g, picks, s)
    assert set(summ["group"]) == {n for n in neutral.muscle_names}
    # p3m12 has 7 neutral tests: the t = 9 row of the neutral arm uses all 7
    assert summ[(summ["arm"] == "neutral") & (summ["t"] == 9)]["n_tests"].max() == 7
    assert summ[(summ["arm"] == "postures") & (summ["t"] == 9)]["n_tests"].max() == 9
    assert set(ident["condition"]) == {"deficit"}


def test_duplicate_posture_test_is_an_error_naming_the_row(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text("direction,posture,S001\nback,ext20,100\nback,ext20,80\n")
    with pytest.raises(DataValidationError, match="row 2"):
        read_posture_measurements(p, ["back"], ["neutral", "ext20"])
