"""The max-wrench linear program (thesis Eq. 4.1 / 5.2): problem definition.

    max_{alpha, w}  w
    s.t.            R diag(f) alpha - (J^T u) w = 0
                    alpha_lb <= alpha <= alpha_ub,   w >= 0

It is solved in muscle forces ``x = f * alpha`` (``R x - b w = 0``, ``alpha_lb f
<= x <= alpha_ub f``, ``b = J^T u``), so that the constraint matrix depends on
the model and the direction only and a change of strengths is a change of
bounds. A direction the model cannot produce returns ``w = 0`` with status
``'zero'``; infeasible activation bounds return ``w = 0`` with status
``'infeasible'``; neither raises, so a batch never stops half-way.

:class:`_DirectionLP` is one direction's LP in HiGHS, the reference every solver is checked against.
"""

from __future__ import annotations

from dataclasses import dataclass

import highspy
import numpy as np

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


def set_colwise_matrix(lp: "highspy.HighsLp", A: np.ndarray) -> None:
    """``lp``'s constraint matrix from the dense ``A`` (rows x columns), column-wise sparse, entries below 1e-15 in
    magnitude dropped (the max-wrench LP and the gap diagnosis's window LPs build theirs this way)."""
    A = np.array(A, dtype=float)
    A[np.abs(A) < 1e-15] = 0.0
    starts, index, value = [0], [], []
    for j in range(A.shape[1]):
        nz = np.nonzero(A[:, j])[0]
        index.extend(nz.tolist())
        value.extend(A[nz, j].tolist())
        starts.append(len(index))
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = np.array(starts, dtype=np.int32)
    lp.a_matrix_.index_ = np.array(index, dtype=np.int32)
    lp.a_matrix_.value_ = np.array(value, dtype=float)
    lp.a_matrix_.num_col_ = A.shape[1]
    lp.a_matrix_.num_row_ = A.shape[0]


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
        set_colwise_matrix(lp, np.hstack([R, -b[:, None]]))
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
