"""Independent re-evaluation of a profile's optimum with HiGHS (issue 31 item 1.2).

Each test's max-wrench LP (thesis Eq. 4.1 / 5.2) is built here from the block's moment arms ``R``, skull-frame
``J^T`` and the strengths, and solved by a fresh ``highspy.Highs`` instance, without :mod:`neckstrength.wrench`:

    max w   s.t.   R x - (J^T u) w = 0,   alpha_lb f_j rho_j <= x_j <= alpha_ub f_j rho_j,   w >= 0
"""

from __future__ import annotations

import highspy
import numpy as np

from neckstrength.identifiability.profile import Battery


def highs_max_wrench(R: np.ndarray, JT: np.ndarray, u: np.ndarray, x_lo: np.ndarray, x_hi: np.ndarray) -> float:
    """Max wrench of one LP with HiGHS (dense build, fresh instance); 0 if infeasible (bounds no activation meets),
    NaN for any other status than optimal."""
    n, m = R.shape
    b = JT @ u
    A = np.hstack([R, -b[:, None]])
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = m + 1, n
    lp.col_cost_ = np.r_[np.zeros(m), 1.0]
    lp.col_lower_ = np.r_[x_lo, 0.0]
    lp.col_upper_ = np.r_[x_hi, highspy.kHighsInf]
    lp.row_lower_ = np.zeros(n)
    lp.row_upper_ = np.zeros(n)
    lp.sense_ = highspy.ObjSense.kMaximize
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = np.arange(0, n * (m + 1) + 1, n, dtype=np.int32)
    lp.a_matrix_.index_ = np.tile(np.arange(n, dtype=np.int32), m + 1)
    lp.a_matrix_.value_ = A.T.ravel().astype(float)
    lp.a_matrix_.num_col_, lp.a_matrix_.num_row_ = m + 1, n
    h.passModel(lp)
    h.run()
    st = h.getModelStatus()
    if st == highspy.HighsModelStatus.kInfeasible:
        return 0.0                 # no wrench within the bounds (e.g. EMG bounds): as the batched solver reports it
    if st != highspy.HighsModelStatus.kOptimal:
        return float("nan")
    return float(h.getSolution().col_value[m])


def highs_wrenches(battery: Battery, f: np.ndarray) -> np.ndarray:
    """Max wrench of every test of ``battery`` at strengths ``f`` (m,), one fresh HiGHS LP per test."""
    f = np.asarray(f, float)
    w = np.full(battery.n_tests, np.nan)
    for blk in battery.blocks:
        m = blk.model.m
        lb = np.zeros((len(blk.idx), m)) if blk.alpha_lb is None else np.asarray(blk.alpha_lb, float)
        ub = np.ones((len(blk.idx), m)) if blk.alpha_ub is None else np.asarray(blk.alpha_ub, float)
        fr = f * blk.rho
        for i, k in enumerate(blk.idx):
            w[k] = highs_max_wrench(blk.model.moment_arms, blk.model.JT, blk.U[i], lb[i] * fr, ub[i] * fr)
    return w


def check_against_highs(battery: Battery, f: np.ndarray, rtol: float = 1e-6) -> float:
    """Largest relative difference between :meth:`Battery.wrenches` and the independent HiGHS LPs at ``f``;
    raises ``AssertionError`` naming the tests above ``rtol`` (a HiGHS failure counts as a disagreement)."""
    w_b, _ = battery.wrenches(np.asarray(f, float)[None, :])
    w_b = w_b[0]
    w_h = highs_wrenches(battery, f)
    rel = np.abs(w_b - w_h) / np.maximum(np.abs(w_h), 1e-12)
    rel = np.where(np.isfinite(rel), rel, np.inf)
    bad = np.flatnonzero(rel > rtol)
    if len(bad):
        raise AssertionError("batched solver and HiGHS disagree (relative > %g) in tests %s"
                             % (rtol, ", ".join(f"{battery.labels[k]} ({w_b[k]:.6g} vs {w_h[k]:.6g})" for k in bad)))
    return float(rel.max()) if len(rel) else 0.0
