"""Max-wrench LP (Eq. 4.1 / 5.2): agreement with scipy's linprog, edge cases."""

import numpy as np
import pytest
from scipy.optimize import linprog

from neckstrength.wrench.highs import max_wrench, max_wrench_batch
from neckstrength.wrench.problem import STATUS_CODES


def linprog_max_wrench(R, JT, f, u, lb, ub):
    n, m = R.shape
    A_eq = np.hstack([R * f[None, :], -(JT @ u)[:, None]])
    c = np.r_[np.zeros(m), -1.0]
    bounds = [(lb[i], ub[i]) for i in range(m)] + [(0, None)]
    res = linprog(c, A_eq=A_eq, b_eq=np.zeros(n), bounds=bounds, method="highs")
    return res


def random_instance(rng, n, m, d):
    R = rng.normal(scale=0.03, size=(n, m))
    R[rng.random((n, m)) < 0.3] = 0.0
    JT = rng.normal(scale=0.1, size=(n, d))
    f = rng.uniform(5, 300, size=m)
    u = rng.normal(size=d)
    u /= np.linalg.norm(u)
    return R, JT, f, u


@pytest.mark.parametrize("n,m,d", [(2, 7, 3), (3, 12, 3), (9, 24, 6), (21, 96, 6)])
def test_agrees_with_linprog(n, m, d):
    rng = np.random.default_rng(20261123 + m)
    checked = 0
    for _ in range(60):
        R, JT, f, u = random_instance(rng, n, m, d)
        lb = np.zeros(m)
        ub = np.ones(m)
        if rng.random() < 0.3:  # activation bounds as from EMG
            lb = rng.uniform(0, 0.05, size=m)
            ub = np.clip(lb + rng.uniform(0.3, 1.0, size=m), 0, 1)
        ours = max_wrench(R, JT, f, u, lb, ub)
        ref = linprog_max_wrench(R, JT, f, u, lb, ub)
        if ref.status == 2:  # infeasible
            assert ours.status == "infeasible"
            continue
        assert ref.status == 0
        w_ref = -ref.fun
        assert ours.w == pytest.approx(w_ref, rel=1e-7, abs=1e-9)
        if ours.status == "optimal":
            # the returned activations satisfy the torque balance and bounds
            tau = R @ (f * ours.alpha) - (JT @ u) * ours.w
            assert np.max(np.abs(tau)) < 1e-7 * max(1.0, ours.w)
            assert np.all(ours.alpha >= lb - 1e-9) and np.all(ours.alpha <= ub + 1e-9)
            checked += 1
    assert checked > 20


def test_unproducible_direction_returns_zero_with_flag():
    # one joint, one extensor muscle: a flexion demand cannot be produced
    R = np.array([[0.05]])
    JT = np.array([[1.0]])
    res = max_wrench(R, JT, np.array([100.0]), np.array([-1.0]))
    assert res.status == "zero" and res.w == 0.0
    res = max_wrench(R, JT, np.array([100.0]), np.array([1.0]))
    assert res.status == "optimal" and res.w == pytest.approx(5.0)


def test_infeasible_bounds_do_not_raise_in_batch():
    from neckstrength.model.reduction import ReducedModel
    R = np.array([[0.05, 0.05]])
    JT = np.array([[1.0]])
    model = ReducedModel("toy", "p1", "toy", ("j",), ("a", "b"), np.array([10.0, 10.0]), R, JT,
                         np.eye(2), ("Mz",))
    F = np.array([[10.0, 10.0], [20.0, 5.0]])
    U = np.array([[1.0], [-1.0]])
    # a lower bound on activation with a flexion demand cannot balance: infeasible
    w, alpha, status = max_wrench_batch(model, F, U, alpha_lb=np.array([0.1, 0.0]))
    assert STATUS_CODES[status[0, 0]] == "optimal"
    assert w[0, 0] == pytest.approx(0.05 * 10 + 0.05 * 10)
    assert STATUS_CODES[status[0, 1]] == "infeasible" and w[0, 1] == 0.0
    assert w[1, 0] == pytest.approx(0.05 * 20 + 0.05 * 5)


def test_homogeneous_in_strength():
    rng = np.random.default_rng(7)
    R, JT, f, u = random_instance(rng, 9, 24, 6)
    w1 = max_wrench(R, JT, f, u).w
    w2 = max_wrench(R, JT, 2.5 * f, u).w
    assert w2 == pytest.approx(2.5 * w1, rel=1e-9)


def test_rejects_bad_bounds():
    with pytest.raises(ValueError):
        max_wrench(np.ones((1, 1)), np.ones((1, 1)), np.ones(1), np.ones(1), alpha_lb=[0.5], alpha_ub=[0.2])
