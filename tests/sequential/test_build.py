"""SimulatedSet.build (one solve per candidate and direction, direction by direction) against the previous
two-pass construction (all wrenches first, then the activations re-solved chunk by chunk) on s3m24 prior draws."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from neckstrength import sequential as sq
from neckstrength.seeds import seed_sequence
from neckstrength.wrench import BasisCache, solve
from neckstrength.wrench.problem import STATUS_CODES

ROOT = Path(__file__).resolve().parents[2]
OPT = {v: k for k, v in STATUS_CODES.items()}["optimal"]


@pytest.fixture(scope="module")
def s3m24():
    from neckstrength.config import build_directions, full_model_from_config, load_config, model_from_config
    from neckstrength.estimation.datasets import model_directions_table

    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        cfg = load_config(ROOT / "config" / "config.yaml")
        model = model_from_config(full_model_from_config(cfg), cfg, "s3m24")
        d, U = model_directions_table(model, build_directions(cfg))
    finally:
        os.chdir(cwd)
    return model, list(d["name"]), np.asarray(U, float)


def two_pass(model, U, F, grid, n_wbins, chunk):
    """The previous SimulatedSet.build: wrenches of all candidates, then the activations (re-solved)."""
    N, m = F.shape
    K = U.shape[0]
    cache = BasisCache(simplex=False)           # HiGHS for every cache miss: no compiled code on this side
    w, _, st = solve(model, F, U, cache=cache, return_alpha=False)
    w = np.where(st == OPT, w, 0.0)
    wedges = np.zeros((K, n_wbins + 1))
    wbin = np.zeros((N, K), dtype=np.int16)
    for i in range(K):
        pos = w[:, i] > 0
        lo, hi = w[pos, i].min() * (1 - 1e-9), w[pos, i].max() * (1 + 1e-9)
        wedges[i] = np.geomspace(lo, hi, n_wbins + 1)
        v = np.clip(np.searchsorted(wedges[i], w[:, i], side="right"), 1, n_wbins)
        v[~pos] = 0
        wbin[:, i] = v
    fb = grid.index(F)
    A = np.zeros((K, n_wbins + 1, m, grid.n_bins))
    alpha = np.zeros((N, K, m))
    for s in range(0, N, chunk):
        e = min(N, s + chunk)
        _, a, st = solve(model, F[s:e], U, cache=cache, return_alpha=True)
        a = np.where((st == OPT)[..., None], np.nan_to_num(a, nan=0.0), 0.0)
        alpha[s:e] = a
        for i in range(K):
            for j in range(m):
                np.add.at(A[i], (wbin[s:e, i], j, fb[s:e, j]), a[:, i, j])
    return w, wedges, wbin, A.astype(np.float32), alpha


def test_build_equals_two_pass_construction(s3m24):
    model, names, U = s3m24
    f0 = model.strengths
    F = sq.sample_prior(f0, 0.3, 1500, np.random.default_rng(seed_sequence(20261123, "tests/build")))
    grid = sq.StrengthGrid.around(f0, 0.3, 50, 4.0)
    sim, = sq.SimulatedSet.build(model, names, U, F, [grid], 512, keep_alpha=True, chunk=700)
    w, wedges, wbin, A, alpha = two_pass(model, U, F, grid, 512, chunk=700)
    assert np.all(w > 0)
    np.testing.assert_allclose(sim.w, w, rtol=1e-12, atol=0)
    np.testing.assert_allclose(sim.wedges, wedges, rtol=1e-12, atol=0)
    np.testing.assert_array_equal(sim.wbin, wbin)
    np.testing.assert_array_equal(sim.wcount, np.stack([np.bincount(wbin[:, i], minlength=513)
                                                        for i in range(U.shape[0])]))
    # activations: unique except on degenerate LPs (a zero reduced cost: a face of optima, w the same);
    # elsewhere equal to the single precision of keep_alpha's array, and on the degenerate ones optimal
    diff = np.abs(sim.alpha - alpha).max(axis=2) > 1e-6
    assert diff.mean() < 0.01
    k, i = np.nonzero(diff)
    x = F[k] * sim.alpha[k, i].astype(float)                      # muscle forces of the other optimum
    b = (model.JT @ U[i].T).T                                     # (rows, n)
    torque = x @ model.moment_arms.T
    scale = (F[k] @ np.abs(model.moment_arms).T).max(axis=1)      # torque scale of each LP
    assert k.size and np.all(np.abs(torque - w[k, i, None] * b) <= 1e-6 * scale[:, None])
    assert np.all((sim.alpha >= 0) & (sim.alpha <= 1))
    # the tables: Eq. 6.5's sums of the activations kept (double precision sums, single precision storage)
    fb = grid.index(F)
    A2 = np.zeros((U.shape[0], 513, model.m, grid.n_bins))
    for i in range(U.shape[0]):
        for j in range(model.m):
            np.add.at(A2[i], (wbin[:, i], j, fb[:, j]), sim.alpha[:, i, j].astype(float))
    np.testing.assert_allclose(sim.A, A2, rtol=1e-5, atol=1e-5)
    # and against the previous construction: the degenerate LPs move little weight between table cells
    assert np.abs(sim.A.astype(float) - A).sum() / np.abs(A).sum() < 0.01
