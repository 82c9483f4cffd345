"""The HiGHS reference for the max-wrench LP: one LP at a time (:func:`max_wrench`) or a loop over
strength vectors with one warm-started HiGHS instance per direction (:func:`max_wrench_batch`).

Used as the reference in tests and benchmarks and by :func:`neckstrength.wrench.solve` with
``method='highs'``.
"""

from __future__ import annotations

import numpy as np

from neckstrength.model.reduction import ReducedModel
from neckstrength.wrench.problem import _CODE, MaxWrenchResult, _bounds, _DirectionLP


def max_wrench(R: np.ndarray, JT: np.ndarray, f: np.ndarray, u: np.ndarray,
               alpha_lb=None, alpha_ub=None) -> MaxWrenchResult:
    """Solve Eq. 4.1 / 5.2 for one strength vector ``f`` and unit wrench ``u``.

    ``R`` (n x m) moment arms, ``JT`` (n x d) transposed Jacobian, ``u`` (d,).
    """
    R = np.asarray(R, float)
    f = np.asarray(f, float)
    if np.any(f < 0):
        raise ValueError("strengths must be non-negative")
    b = np.asarray(JT, float) @ np.asarray(u, float)
    lb, ub = _bounds(R.shape[1], alpha_lb, alpha_ub)
    return _DirectionLP(R, b).solve(f, lb, ub)


def max_wrench_batch(model: ReducedModel, F: np.ndarray, U: np.ndarray,
                     alpha_lb: np.ndarray | None = None, alpha_ub: np.ndarray | None = None):
    """Max wrench for every strength vector in ``F`` (N x m) and direction in ``U`` (K x d).

    ``alpha_lb``/``alpha_ub``: None, (m,), or (K, m) per-direction bounds.
    Returns ``w`` (N x K), ``alpha`` (N x K x m) and integer ``status`` (N x K,
    see :data:`STATUS_CODES`). This reference implementation reuses one HiGHS
    instance per direction (the constraint matrix does not depend on ``F``).
    """
    F = np.atleast_2d(np.asarray(F, float))
    U = np.atleast_2d(np.asarray(U, float))
    N, m = F.shape
    K = U.shape[0]
    if m != model.m:
        raise ValueError(f"F has {m} columns, model {model.name} has {model.m} muscles")
    if U.shape[1] != model.JT.shape[1]:
        raise ValueError(f"U has {U.shape[1]} components, model task space has {model.JT.shape[1]}")
    lbs = np.broadcast_to(np.zeros(m) if alpha_lb is None else np.asarray(alpha_lb, float), (K, m))
    ubs = np.broadcast_to(np.ones(m) if alpha_ub is None else np.asarray(alpha_ub, float), (K, m))
    w = np.zeros((N, K))
    alpha = np.zeros((N, K, m))
    status = np.zeros((N, K), dtype=np.int8)
    for k in range(K):
        lb, ub = _bounds(m, lbs[k], ubs[k])
        lp = _DirectionLP(model.moment_arms, model.JT @ U[k])
        for i in range(N):
            r = lp.solve(F[i], lb, ub)
            w[i, k] = r.w
            alpha[i, k] = r.alpha
            status[i, k] = _CODE[r.status]
    return w, alpha, status
