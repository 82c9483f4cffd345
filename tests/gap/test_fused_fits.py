"""The gap fits with the compiled all-direction solver pass (``gap.fit.FUSED_SOLVER``) against the per-direction
batched solver: forces and exact Jacobians of ``Simulator.forces_grad_phi`` for the base model and three effects
(one with candidate wrenches, one with activation lower bounds), to the solver's 1e-9."""

from __future__ import annotations

import numpy as np
import pytest

from neckstrength.gap.effects import EFFECTS, base_instance, compose
from neckstrength.gap.fit import Simulator
from neckstrength.wrench.batched import BasisCache


@pytest.mark.parametrize("name", [None, "cocontraction", "direction_tolerance", "asymmetry"])
def test_fused_forces_and_jacobian_match_reference(ctx_s3, name):
    ctx = ctx_s3
    if name is None:
        inst = base_instance(ctx)
    else:
        eff = EFFECTS[name](ctx)
        th = np.array([p.neutral + 0.5 * (p.hi - p.neutral) for p in eff.params()])
        inst = compose(ctx, [eff], [th])
    fast = Simulator(ctx, inst, BasisCache(max_bases=512, max_entries=100_000, fused=True))
    ref = Simulator(ctx, inst, BasisCache(max_bases=512, max_entries=100_000, fused=False))
    p = int(fast.pidx.max()) + 1
    phi0 = np.log(np.bincount(fast.pidx, weights=ctx.model.strengths, minlength=p)
                  / np.bincount(fast.pidx, minlength=p))
    rng = np.random.default_rng(36)
    for _ in range(4):
        phi = phi0 + rng.normal(0.0, 0.3, (3, p))
        f1, g1 = fast.forces_grad_phi(phi)
        f2, g2 = ref.forces_grad_phi(phi)
        assert np.allclose(f1, f2, rtol=1e-9, atol=1e-9)
        assert np.allclose(g1, g2, rtol=1e-6, atol=1e-6 * np.abs(g2).max())
        assert np.allclose(fast.forces(np.exp(phi)[:, fast.pidx]), ref.forces(np.exp(phi)[:, ref.pidx]),
                           rtol=1e-9, atol=1e-9)
    st = fast.cache.stats()
    assert st["fused_cache_hits"] + st["fused_simplex_solved"] > 0
    assert ref.cache.stats()["fused_cache_hits"] == 0


def test_jacobians_do_not_follow_the_optimal_vertex_returned(ctx_p2):
    # p2m7 has two pairs of parallel moment-arm columns (muscles 0, 1 and 5, 6): where the optimum uses a pair inside
    # its bounds the activations are not unique, and the fused pass and the per-direction solver (each from its own
    # cache) return different optimal vertices. The exact Jacobian does not follow them: dw/df_j = (lam . R_j) alpha_j
    # with the dual lam, and lam . R_j = 0 for every column that is inside its bounds at some optimal vertex
    from neckstrength.wrench import solve

    ctx = ctx_p2
    inst = base_instance(ctx)
    fast = Simulator(ctx, inst, BasisCache(max_bases=512, max_entries=100_000, fused=True))
    ref = Simulator(ctx, inst, BasisCache(max_bases=512, max_entries=100_000, fused=False))
    p = int(fast.pidx.max()) + 1
    phi0 = np.log(np.bincount(fast.pidx, weights=ctx.model.strengths, minlength=p)
                  / np.bincount(fast.pidx, minlength=p))
    phi = phi0 + np.random.default_rng(5).normal(0.0, 0.3, (60, p))
    fast.forces_grad_phi(phi[::-1])                   # the two caches filled in different orders
    f1, g1 = fast.forces_grad_phi(phi)
    f2, g2 = ref.forces_grad_phi(phi)
    Fa = inst.strengths(fast.muscles(phi))
    _, a1, _ = solve(fast.model, Fa, fast.U, fast.lb, fast.ub, cache=fast.cache)
    _, a2, _ = solve(ref.model, Fa, ref.U, ref.lb, ref.ub, cache=ref.cache)
    assert np.nanmax(np.abs(a1 - a2)) > 0.01          # different optimal activations somewhere
    assert np.allclose(f1, f2, rtol=1e-9, atol=1e-9)
    assert np.allclose(g1, g2, rtol=1e-9, atol=1e-9 * np.abs(g2).max())
