"""The compiled all-direction pass (neckstrength.wrench.fused, ``BasisCache(fused=True)``) against HiGHS.

The gap diagnosis calls the solver thousands of times with a few strength vectors and every direction; the fused
pass answers such calls from its compiled cache and dual simplex. Its answers are compared with the HiGHS
reference (``max_wrench_batch``, via ``assert_agrees`` of ``test_batched.py``: ``w`` to 1e-9, equal statuses,
feasible activations), on a subsample also with scipy's ``linprog`` (an independent HiGHS front end on the
activation form of Eq. 4.1), and, one level up, the gap fits' forces and exact Jacobians with the per-direction
solver's.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_batched import CODE, assert_agrees, candidates, get_model, linprog_reference, pair_index, unit

from neckstrength.wrench import batched
from neckstrength.wrench.batched import BasisCache, max_wrench_batched


def _walk(rng, model, calls, rows, step=0.05):
    """Strength vectors as a fit visits them: ``calls`` batches of ``rows`` that drift in log strength."""
    pidx = pair_index(model) if model.n > 3 and model.m < 96 else np.arange(model.m)
    g = int(pidx.max()) + 1
    phi = rng.normal(0.0, 0.3, (rows, g))
    out = []
    for _ in range(calls):
        phi = phi + rng.normal(0.0, step, phi.shape)
        out.append(np.ascontiguousarray(model.strengths * np.exp(phi)[:, pidx]))
    return out


@pytest.mark.parametrize("name", ["p2m7", "s3m24", "s7"])
def test_small_calls_agree_with_highs(name):
    rng = np.random.default_rng(32)
    model, U_real, _ = get_model(name, 5)
    U = np.vstack([U_real, unit(rng, 3, U_real.shape[1])])
    cache = BasisCache(fused=True)
    calls = {"p2m7": 40, "s3m24": 25, "s7": 6}[name]
    total = 0
    for F in _walk(rng, model, calls, 3) + [candidates(rng, model.strengths, 40, kind) for kind in ("coarse", "zeros")]:
        assert_agrees(model, F, U, cache=cache)
        total += F.size // model.m * U.shape[0]
    st = cache.stats()
    # the fused pass answered (nearly) all of them: cached bases and its own certified simplex solves
    assert st["fused_cache_hits"] + st["fused_simplex_solved"] + st["fused_farkas_hits"] >= 0.95 * total
    assert st["fused_cache_hits"] > 0 and st["fused_simplex_solved"] > 0


def test_bounds_infeasible_zero_and_unbounded_directions():
    """EMG-like lower bounds (some infeasible), directions without muscles, and b = 0 (unbounded)."""
    rng = np.random.default_rng(33)
    model, U, _ = get_model("s3m24", 6)
    K, m = U.shape[0], model.m
    lb = np.zeros((K, m))
    lb[rng.random((K, m)) < 0.5] = 0.1
    lb[: K // 3] = rng.uniform(0.2, 0.6, size=(K // 3, m))
    ub = np.ones((K, m))
    cache = BasisCache(fused=True)
    seen = set()
    for F in _walk(rng, model, 10, 4):
        F[:, rng.random(m) < 0.1] = 0.0
        seen |= set(np.unique(assert_agrees(model, F, U, lb, ub, cache=cache)).tolist())
    assert {CODE["optimal"], CODE["infeasible"]} <= seen
    b = model.JT @ U[0]
    helps = model.moment_arms.T @ b > 0
    F = candidates(rng, model.strengths, 6, "grid3")
    F[:, helps] = 0.0
    assert np.all(assert_agrees(model, F, U[:1], cache=cache) == CODE["zero"])
    # a unit wrench with J^T u = 0 is unbounded, as in the reference
    null = np.linalg.svd(model.JT)[2][-1] if model.JT.shape[1] > model.JT.shape[0] else None
    if null is not None:
        w, _, status = max_wrench_batched(model, F, null[None, :], cache=cache)
        assert np.all(status == CODE["unbounded"]) and np.all(np.isinf(w))


def test_fallback_to_the_per_direction_solver(monkeypatch):
    """Without simplex pivots every miss of the fused pass goes back to the per-direction solver (HiGHS), whose
    bases the pass then takes over: the answers are the same and later calls hit the fused cache."""
    monkeypatch.setattr(batched, "SIMPLEX_MAX_ITER", 0)
    rng = np.random.default_rng(34)
    model, U, _ = get_model("s3m24", 7)
    cache = BasisCache(fused=True)
    walk = _walk(rng, model, 12, 3, step=0.01)
    for F in walk:
        assert_agrees(model, F, U, cache=cache)
    st = cache.stats()
    assert st["fused_failed"] > 0 and st["highs_calls"] > 0 and st["fused_cache_hits"] > 0
    assert st["fused_simplex_solved"] == 0


def test_independent_solver_subsample():
    """A subsample of the fused answers against scipy's linprog (activation form), not via highspy's model."""
    rng = np.random.default_rng(35)
    model, U, _ = get_model("s3m24", 8)
    cache = BasisCache(fused=True)
    for F in _walk(rng, model, 5, 3):
        w, _, status = max_wrench_batched(model, F, U, cache=cache)
    lb, ub = np.zeros(model.m), np.ones(model.m)
    for i, k in zip(rng.integers(0, F.shape[0], 20), rng.integers(0, U.shape[0], 20)):
        w_ref, st_ref = linprog_reference(model, F[i], U[k], lb, ub)
        assert status[i, k] == st_ref
        assert abs(w[i, k] - w_ref) <= 1e-7 * max(abs(w_ref), 1.0)      # linprog's own tolerance is 1e-9 relative


def test_bases_live_in_a_pool_that_grows_with_the_bases_held():
    """The large maps of the cached bases (checks, basic map, inverse) are taken from a pool shared by the store's
    slots as bases are learned, so a store holds about as many as it learned, not ``capacity`` per slot; every slot's
    bases own distinct pool entries, and a capacity reached in some slots replaces bases in place."""
    from neckstrength.wrench.fused import FusedStore

    rng = np.random.default_rng(34)
    model, U_real, _ = get_model("s3m24", 5)
    U = np.vstack([U_real, unit(rng, 100, U_real.shape[1])])
    cache = BasisCache(fused=True)
    for F in _walk(rng, model, 30, 3, step=0.15):          # the real directions: their slots fill up
        assert_agrees(model, F, U_real, cache=cache)
    for F in _walk(rng, model, 2, 3):                       # and 100 more directions, visited twice
        assert_agrees(model, F, U, cache=cache)
    (st,) = cache._stores.values()
    assert isinstance(st, FusedStore)
    a = st.arrays
    nb = a["nb"][:st.S]
    used = np.concatenate([a["pidx"][s, :nb[s]] for s in range(st.S)])
    assert len(np.unique(used)) == len(used) == int(st.npool[0]) == nb.sum() <= st.pool_size
    assert nb.max() == st.C and nb.min() < st.C / 2               # some slots full (replacing), others not
    assert nb.sum() < st.S * st.C / 2 and st.pool_size < st.S * st.C   # not capacity for every slot
