"""The max-wrench linear program (thesis Eq. 4.1 / 5.2), solved with HiGHS.

    max_{alpha, w}  w
    s.t.            R diag(f) alpha - (J^T u) w = 0
                    alpha_lb <= alpha <= alpha_ub,   w >= 0

It is solved in muscle forces ``x = f * alpha`` (``R x - b w = 0``, ``alpha_lb f
<= x <= alpha_ub f``, ``b = J^T u``), so that the constraint matrix depends on
the model and the direction only and a change of strengths is a change of
bounds. A direction the model cannot produce returns ``w = 0`` with status
``'zero'``; infeasible activation bounds return ``w = 0`` with status
``'infeasible'``; neither raises, so a batch never stops half-way.
"""

from __future__ import annotations

from dataclasses import dataclass

import highspy
import numpy as np

from .model import ReducedModel

__all__ = ["MaxWrenchResult", "max_wrench", "max_wrench_batch", "STATUS_CODES", "bootstrap_scale"]

#: Status codes in batch output arrays.
STATUS_CODES = {0: "optimal", 1: "zero", 2: "infeasible", 3: "unbounded", 4: "error"}
_CODE = {v: k for k, v in STATUS_CODES.items()}


@dataclass(frozen=True)
class MaxWrenchResult:
    """``w``: maximum wrench magnitude along ``u``; ``alpha``: activations; ``status``."""

    w: float
    alpha: np.ndarray
    status: str

    @property
    def producible(self) -> bool:
        return self.status == "optimal"


class _DirectionLP:
    """One HiGHS instance for a fixed (R, b); strengths and bounds change per solve."""

    def __init__(self, R: np.ndarray, b: np.ndarray):
        n, m = R.shape
        self.n, self.m = n, m
        self.b = b
        self.h = highspy.Highs()
        self.h.setOptionValue("output_flag", False)
        self.h.setOptionValue("log_to_console", False)
        lp = highspy.HighsLp()
        lp.num_col_ = m + 1
        lp.num_row_ = n
        lp.col_cost_ = np.r_[np.zeros(m), 1.0]
        lp.col_lower_ = np.zeros(m + 1)
        lp.col_upper_ = np.r_[np.ones(m), highspy.kHighsInf]
        lp.row_lower_ = np.zeros(n)
        lp.row_upper_ = np.zeros(n)
        lp.sense_ = highspy.ObjSense.kMaximize
        A = np.hstack([R, -b[:, None]])
        A[np.abs(A) < 1e-15] = 0.0
        starts, index, value = [0], [], []
        for j in range(m + 1):
            nz = np.nonzero(A[:, j])[0]
            index.extend(nz.tolist())
            value.extend(A[nz, j].tolist())
            starts.append(len(index))
        lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
        lp.a_matrix_.start_ = np.array(starts, dtype=np.int32)
        lp.a_matrix_.index_ = np.array(index, dtype=np.int32)
        lp.a_matrix_.value_ = np.array(value, dtype=float)
        lp.a_matrix_.num_col_ = m + 1
        lp.a_matrix_.num_row_ = n
        self.h.passModel(lp)
        self.scale = float(np.abs(R).sum())
        self.idx = np.arange(m, dtype=np.int32)

    def solve(self, f: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> MaxWrenchResult:
        m = self.m
        if not np.any(self.b):
            return MaxWrenchResult(float("inf"), np.full(m, np.nan), "unbounded")
        xl = lb * f
        xu = ub * f
        self.h.changeColsBounds(m, self.idx, xl, xu)
        self.h.run()
        st = self.h.getModelStatus()
        if st == highspy.HighsModelStatus.kInfeasible:
            return MaxWrenchResult(0.0, np.full(m, np.nan), "infeasible")
        if st == highspy.HighsModelStatus.kUnbounded:
            return MaxWrenchResult(float("inf"), np.full(m, np.nan), "unbounded")
        if st != highspy.HighsModelStatus.kOptimal:
            # e.g. kUnboundedOrInfeasible: decide with a feasibility check of w = 0
            return MaxWrenchResult(0.0, np.full(m, np.nan), "error")
        x = np.asarray(self.h.getSolution().col_value)
        w = float(x[m])
        with np.errstate(divide="ignore", invalid="ignore"):
            alpha = np.where(f > 0, x[:m] / np.where(f > 0, f, 1.0), lb)
        alpha = np.clip(alpha, lb, ub)
        if w <= 1e-12 * max(1.0, float(np.dot(np.abs(f), np.ones(m)))):
            return MaxWrenchResult(0.0, alpha, "zero")
        return MaxWrenchResult(w, alpha, "optimal")


def _bounds(m: int, lb, ub) -> tuple[np.ndarray, np.ndarray]:
    lb = np.zeros(m) if lb is None else np.broadcast_to(np.asarray(lb, float), (m,)).copy()
    ub = np.ones(m) if ub is None else np.broadcast_to(np.asarray(ub, float), (m,)).copy()
    if np.any(lb < 0) or np.any(ub > 1) or np.any(lb > ub):
        raise ValueError("activation bounds must satisfy 0 <= alpha_lb <= alpha_ub <= 1")
    return lb, ub


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


def bootstrap_scale(model: ReducedModel, f_base: np.ndarray, u: np.ndarray, w_meas: float) -> float:
    """Scalar ``a`` of Eq. 5.3: ``argmin_a |w_meas - M(a f_base, u)|`` with ``a >= 0``.

    ``M`` is positively homogeneous in ``f`` (scaling all strengths scales the
    feasible set), so ``a = w_meas / M(f_base, u)`` exactly; no search needed.
    """
    r = max_wrench(model.moment_arms, model.JT, f_base, u)
    if not r.producible:
        raise ValueError(f"model {model.name} cannot produce the bootstrap direction (status {r.status})")
    return float(w_meas / r.w)


def solve_max_wrench(model: ReducedModel, F: np.ndarray, U: np.ndarray, alpha_lb=None, alpha_ub=None,
                     method: str = "auto", return_alpha: bool = True, chunk_size: int = 65536, cache=None,
                     n_threads: int = 1):
    """Entry point used by every pipeline stage; same return convention as :func:`max_wrench_batch`.

    ``method``: 'batched' (:mod:`neckstrength.batched`, exact, cached optimal bases), 'highs' (one HiGHS
    solve per LP) or 'auto' (batched when available). ``cache``: a :class:`neckstrength.batched.BasisCache` to keep bases across
    calls (e.g. across ABC iterations). With ``return_alpha=False`` the activations are not computed
    and ``None`` is returned in their place.
    """
    if method == "auto":
        try:
            from .batched import max_wrench_batched  # noqa: F401
            method = "batched"
        except ImportError:
            method = "highs"
    if method == "batched":
        from .batched import max_wrench_batched

        return max_wrench_batched(model, F, U, alpha_lb, alpha_ub, chunk_size=chunk_size, cache=cache,
                                  return_alpha=return_alpha, n_threads=n_threads)
    if method != "highs":
        raise ValueError(f"unknown method {method!r}")
    w, alpha, status = max_wrench_batch(model, F, U, alpha_lb, alpha_ub)
    return w, (alpha if return_alpha else None), status
