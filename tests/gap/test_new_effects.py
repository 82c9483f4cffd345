"""The issue-32 candidate effects (submaximal_effort, posture_drift, anthropometric_scaling): the base model at
their neutral parameters, bounds, physics, and a fit that finds an injected effect in simulated data."""

from dataclasses import replace

import numpy as np
import pytest

from neckstrength.estimation.parameters import free_parameters
from neckstrength.gap.discriminate import fit_candidate
from neckstrength.gap.effects import EFFECTS, _jt_rows, base_instance, compose
from neckstrength.gap.fit import Simulator

NEW = ("submaximal_effort", "posture_drift", "anthropometric_scaling")


def _forces(ctx, inst, F=None):
    F = ctx.model.strengths[None] if F is None else F
    return Simulator(ctx, inst).forces(F)[0]


@pytest.mark.parametrize("name", NEW)
def test_neutral_is_the_base_model(ctx_s3, name):
    """``apply`` at the neutral parameters (the formula itself, not compose's shortcut) gives the base forces,
    and a small step away changes them."""
    e = EFFECTS[name](ctx_s3)
    assert e.applies()
    base = base_instance(ctx_s3)
    f0 = _forces(ctx_s3, base)
    np.testing.assert_allclose(_forces(ctx_s3, e.apply(base, e.neutral)), f0, rtol=1e-9)
    th = e.neutral + 0.5 * (e.upper - e.neutral)
    assert np.max(np.abs(_forces(ctx_s3, e.apply(base, th)) / f0 - 1)) > 0.01


@pytest.mark.parametrize("name", NEW)
def test_bounds_enforced(ctx_s3, name):
    e = EFFECTS[name](ctx_s3)
    with pytest.raises(ValueError, match="outside bounds"):
        compose(ctx_s3, [e], [e.upper + 0.01 * (e.upper - e.lower)])
    with pytest.raises(ValueError, match="outside bounds"):
        compose(ctx_s3, [e], [e.lower - 0.01 * (e.upper - e.lower)])
    # two-sided except posture_drift (the head gives way in the direction of the push only: 0 to the bound) and the
    # effort lobe's width (1, the broadest lobe, to the bound)
    one_sided = {"posture_drift": {"drift_deg"}, "submaximal_effort": {"lobe_power"}}.get(name, set())
    assert all((p.lo == p.neutral if p.name in one_sided else p.lo < p.neutral) and p.neutral < p.hi
               for p in e.params())


def test_effort_stays_within_its_range(ctx_s3):
    """Every corner of the parameter box (norm above the cap) keeps the effort within [min_effort, 1], and the
    forces scale by exactly the effort (no activation floor: the LP is homogeneous in the upper bounds)."""
    e = EFFECTS["submaximal_effort"](ctx_s3)
    base = base_instance(ctx_s3)
    f0 = _forces(ctx_s3, base)
    for corner in ([1, 1, 1, 1], [-1, 1, -1, 4], [1, -1, 0, 2.5]):
        th = np.r_[np.array(corner[:3], float) * e.upper[:3], corner[3]]
        eff = e.effort(base.N, th)
        assert eff.min() >= 0.6 - 1e-12 and eff.max() <= 1 + 1e-12
        np.testing.assert_allclose(_forces(ctx_s3, compose(ctx_s3, [e], [th])), eff * f0, rtol=1e-6)
    with pytest.raises(ValueError, match="min_effort"):
        EFFECTS["submaximal_effort"](ctx_s3, min_effort=1.2).params()


def test_effort_lobe_width(ctx_s3):
    """Width 1 is the dipole 1 - |b| - b.n (the shape before the width); a narrower lobe (width 3) lowers the effort
    only near the lobe's direction: the same minimum along b, more directions at full effort; the screen grid keeps
    the 13 dipole points (the width has no axis there: b = 0 is neutral at any width)."""
    e = EFFECTS["submaximal_effort"](ctx_s3)
    N = base_instance(ctx_s3).N
    Nh = N / np.linalg.norm(N, axis=1, keepdims=True)
    b = np.array([0.12, -0.05, 0.08])
    np.testing.assert_allclose(e.effort(N, np.r_[b, 1.0]), 1 - np.linalg.norm(b) - Nh @ b, atol=1e-12)
    wide, narrow = e.effort(N, np.r_[b, 1.0]), e.effort(N, np.r_[b, 3.0])
    assert np.all(narrow >= wide - 1e-12) and (narrow > wide + 0.01).sum() >= 5
    k = int(np.argmax(Nh @ b))
    assert narrow[k] < 0.9 and abs(narrow[k] - wide[k]) < 0.06
    grid = e.grid(5)
    assert len(grid) == 13 and all(t[3] == 1.0 for t in grid)
    with pytest.raises(ValueError, match="max_lobe_power"):
        EFFECTS["submaximal_effort"](ctx_s3, max_lobe_power=0.5).params()


def test_posture_drift_reaches_the_tables(ctx_p2):
    """p2m7 (pitch only) drifted by 20 deg (``apply`` itself: the bound is 15): every test is exactly in the flex20
    or ext20 table's posture, by the sign of the pitch torque it demands (the posture models of
    :mod:`neckstrength.postures.model`, another code path: J^T from the tables, not rebuilt)."""
    from neckstrength.postures.model import build_posture_set

    e = EFFECTS["posture_drift"](ctx_p2)
    base = base_instance(ctx_p2)
    ang = e.drift_angles(base, 20.0)
    assert set(np.abs(ang[:, 0])) == {20.0} and not ang[:, 1:].any()
    which = ["ext20" if a > 0 else "flex20" for a in ang[:, 0]]
    ps = build_posture_set(ctx_p2.full, ctx_p2.model, dict(ctx_p2.postures), ["neutral", "flex20", "ext20"])
    F = ctx_p2.model.strengths[None]
    w, _, _ = ps.wrenches(F, ctx_p2.model.task_direction(base.U6[:, 0]), which)
    f_tab = w[0] / ctx_p2.directions["force_scale"].to_numpy(float)
    np.testing.assert_allclose(_forces(ctx_p2, e.apply(base, np.array([20.0]))), f_tab, rtol=1e-5)
    assert 0.01 < np.max(np.abs(f_tab / _forces(ctx_p2, base) - 1))
    assert EFFECTS["posture_drift"](replace(ctx_p2, postures=None)).applies() is False


def test_uniform_scaling_changes_nothing(ctx_s3):
    """Why anthropometric_scaling has one parameter: the head (test points) and the neck (joint centres, moment
    arms) scaled by one common factor predict the same forces."""
    base = base_instance(ctx_s3)
    k = 1.12
    joint = ~np.isnan(base.row_centre[:, 0])
    centre = base.row_centre.copy()
    centre[joint] *= k
    JT = base.JT.copy()
    JT[joint] = _jt_rows(centre[joint], base.row_axis[joint], base.planar)
    P = base.P * k
    N = base.N / np.linalg.norm(base.N, axis=1, keepdims=True)
    W = np.hstack([np.cross(P, N), N])
    s = np.linalg.norm(W, axis=1)
    scaled = replace(base, R=base.R * k, JT=JT, row_centre=centre, P=P, U6=(W / s[:, None])[:, None, :],
                     fmul=(1 / s)[:, None])
    np.testing.assert_allclose(_forces(ctx_s3, scaled), _forces(ctx_s3, base), rtol=1e-7)


@pytest.mark.parametrize("name", NEW)
def test_fit_finds_an_injected_effect(ctx_s3, name):
    """Forces simulated with the effect at its far grid point (the last; for two parameters the corner that changes
    the baseline forces most: strengths off baseline, 1% noise; seed 32): fitting
    the strengths at every grid point, the injected one fits best and the base model (neutral) clearly worse."""
    rng = np.random.default_rng(32)
    e = EFFECTS[name](ctx_s3)
    pidx, _ = free_parameters(ctx_s3.model, ctx_s3.tie_sides)
    p = int(pidx.max()) + 1
    phi = np.array([np.log(ctx_s3.model.strengths[pidx == q].mean()) for q in range(p)]) + rng.normal(0, 0.2, p)
    grid = e.grid(5)
    truth = grid[-1]
    if e.n_params > 1:
        change = [np.abs(np.log(_forces(ctx_s3, compose(ctx_s3, [e], [g])) / _forces(ctx_s3, base_instance(ctx_s3))))
                  .max() for g in grid[1:]]
        truth = grid[1 + int(np.argmax(change))]
    sim = Simulator(ctx_s3, compose(ctx_s3, [e], [truth]))
    T = sim.forces(sim.muscles(phi[None]))[0] * np.exp(rng.normal(0, 0.01, ctx_s3.K))
    loss = [fit_candidate(ctx_s3, T, "none" if e.is_neutral(g) else name, {name: list(g)})[1] for g in grid]
    best = int(np.argmin(loss))
    np.testing.assert_allclose(grid[best], truth)
    assert loss[0] > 2 * loss[best]


def test_head_scale_alone_is_point_scale(ctx_s3):
    """anthropometric_scaling's head part (s = 0) moves the test points as point_scale does: the same forces; with
    the neck part the forces differ from every point_scale's."""
    a, ps = EFFECTS["anthropometric_scaling"](ctx_s3), EFFECTS["point_scale"](ctx_s3)
    head = _forces(ctx_s3, compose(ctx_s3, [a], [np.array([0.0, 0.1])]))
    np.testing.assert_allclose(head, _forces(ctx_s3, compose(ctx_s3, [ps], [np.array([0.1])])), rtol=1e-9)
    both = _forces(ctx_s3, compose(ctx_s3, [a], [np.array([-0.1, 0.1])]))
    best = min(np.abs(np.log(both / _forces(ctx_s3, compose(ctx_s3, [ps], [g])))).max() for g in ps.grid(31))
    assert best > 0.02
