"""Compiled warm-started bounded dual simplex for the max-wrench LP (see ``docs/batched_solver.md``).

The LP of :mod:`neckstrength.wrench.batched` in muscle forces, with one row logical per
equality row (``r = A z`` fixed at 0, used by rank-deficient bases)::

    max w   s.t.   A z - r = 0,   A = [R, -b],   lb_j f_j <= x_j <= ub_j f_j,   0 <= w,   r = 0.

Every cached basis is dual feasible for every ``f`` (its reduced costs do not depend on ``f``),
so it is a valid start for a *dual* simplex on any candidate: :func:`solve_rows` runs, for each
candidate, a bounded dual simplex (largest primal infeasibility leaves, textbook ratio test with
ties broken by the largest pivot, explicit basis inverse updated in product form and rebuilt
every ``REFACTOR`` pivots) from the basis given for that row, and then **certifies** the final
basis from scratch with the same tests :meth:`DirectionSolver._add_basis` and the cache checks
apply: a fresh inverse of the basis matrix (1-norm condition number below ``MAX_COND``),
recomputed reduced costs with the optimal signs to ``DUAL_TOL``, every basic variable within its
bounds to ``PRIMAL_TOL`` times the size of the terms, and the duality-gap rule ``GAP_REL``.
Only certified rows are answered; the others (iteration limit, singular or ill-conditioned
basis, primal infeasibility, a failed certificate) are reported as failed and go to HiGHS.

Compiled with numba (``cache=True``: the machine code is stored next to this file, so each
process after the first loads it instead of compiling; ``nogil=True``: directions run in
parallel threads; ``fastmath`` limited to reassociation and fused multiply-add, see ``_FM``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Floating-point flags: reassociation (vectorised dot products) and fused multiply-add only; no
#: assumption about infinities or NaNs (``w`` has an infinite upper bound). The certificate's
#: tolerances are orders of magnitude above the rounding differences this allows.
_FM = {"reassoc", "contract", "nsz"}

#: Rebuild the basis inverse from scratch after this many product-form updates.
REFACTOR = 16

#: Result codes of :func:`solve_rows`.
CERTIFIED, FAILED, INFEASIBLE_SUSPECT = 0, 1, 2

#: Result of :func:`_dual_simplex` with ``confirm=False``: no bound violated with an updated (not fresh) inverse.
UPDATED = 3

#: Status codes of the basis arrays (as ``highspy.HighsBasisStatus``: kLower, kBasic, kUpper).
LOWER, BASIC, UPPER = 0, 1, 2


@njit(cache=True, nogil=True, fastmath=_FM)
def _invert(B, out, M):
    """In-place Gauss-Jordan inverse of ``B`` into ``out`` with partial (row) pivoting; False if
    (numerically) singular. ``M``: workspace (its first row holds the row interchanges)."""
    n = B.shape[0]
    out[:, :] = B
    for c in range(n):
        p = c
        big = abs(out[c, c])
        for r in range(c + 1, n):
            if abs(out[r, c]) > big:
                big = abs(out[r, c])
                p = r
        if big == 0.0 or not np.isfinite(big):
            return False
        M[0, c] = p
        if p != c:
            for j in range(n):
                t = out[c, j]
                out[c, j] = out[p, j]
                out[p, j] = t
        inv = 1.0 / out[c, c]
        out[c, c] = 1.0
        for j in range(n):
            out[c, j] *= inv
        for r in range(n):
            if r != c:
                g = out[r, c]
                if g != 0.0:
                    out[r, c] = 0.0
                    for j in range(n):
                        out[r, j] -= g * out[c, j]
    for c in range(n - 1, -1, -1):       # undo the row interchanges as column interchanges
        p = int(M[0, c])
        if p != c:
            for i in range(n):
                t = out[i, c]
                out[i, c] = out[i, p]
                out[i, p] = t
    return True


@njit(cache=True, nogil=True, fastmath=_FM)
def _column(AT, j, out):
    """Column ``j`` of ``[A, -I]`` (``AT = A.T``)."""
    mp1, n = AT.shape
    if j < mp1:
        for i in range(n):
            out[i] = AT[j, i]
    else:
        for i in range(n):
            out[i] = 0.0
        out[j - mp1] = -1.0


@njit(cache=True, nogil=True)     # no fastmath: make_basis must round as the numpy reference does
def _conditioned(B, Binv, n, max_cond):
    """Whether the 1-norm condition estimate ||B||_1 ||B^-1||_1 is finite and at most ``max_cond``."""
    nB = 0.0
    nI = 0.0
    for k in range(n):
        s1 = 0.0
        s2 = 0.0
        for i in range(n):
            s1 += abs(B[i, k])
            s2 += abs(Binv[i, k])
        nB = max(nB, s1)
        nI = max(nI, s2)
    return np.isfinite(nI) and nB * nI <= max_cond


@njit(cache=True, nogil=True, fastmath=_FM)
def _basis_matrix(AT, basic, B):
    mp1, n = AT.shape
    for k in range(n):
        j = basic[k]
        if j < mp1:
            for i in range(n):
                B[i, k] = AT[j, i]
        else:
            for i in range(n):
                B[i, k] = 0.0
            B[j - mp1, k] = -1.0


@njit(cache=True, nogil=True, fastmath=_FM)
def _tf(AT, Binv, status, s, f, k):
    """``|T_k| f = sum_j |sum_i Binv_ki A_ij| s_j f_j`` over the nonbasic columns (the size of the terms of
    basic variable ``k``, for its tolerance)."""
    mp1, n = AT.shape
    tf = 0.0
    for j in range(mp1 - 1):
        if status[j] != BASIC and s[j] != 0.0:
            t = 0.0
            for i in range(n):
                t += Binv[k, i] * AT[j, i]
            tf += abs(t) * s[j] * f[j]
    return tf


@njit(cache=True, nogil=True, fastmath=_FM)
def _certify(AT, lb, ub, Acol1, wscale, Rscale, absb, f, basic, status, primal_tol, dual_tol, gap_rel,
             max_cond, alpha_out, want_alpha, B, Binv, y, d, s, rhs, xB):
    """Optimality certificate of a basis for ``f``, from scratch. Returns (ok, w).

    ``Binv``: the inverse of the basis matrix, computed afresh (not updated) by the caller.

    The tests of ``DirectionSolver._add_basis`` (dual feasibility, condition number) and of the
    cached checks (primal feasibility with the tolerance relative to the terms of ``T f``, the
    duality-gap rule), evaluated directly for this ``f``.
    """
    mp1, n = AT.shape
    m = mp1 - 1
    _basis_matrix(AT, basic, B)
    if not _conditioned(B, Binv, n, max_cond):
        return False, 0.0
    # dual: B^T y = c_B (maximisation, c = e_w); reduced costs d = c - y A
    for i in range(n):
        y[i] = 0.0
    for k in range(n):
        if basic[k] == m:
            for i in range(n):
                y[i] = Binv[k, i]
    ymax = 0.0
    for i in range(n):
        ymax = max(ymax, abs(y[i]))
    fsum = 0.0
    for j in range(m):
        fsum += f[j]
    fmean = fsum / m
    for j in range(m):           # nonbasic x_j = s_j f_j
        s[j] = 0.0
    gapf = 0.0
    for j in range(mp1):
        if status[j] == BASIC:
            d[j] = 0.0
            continue
        t = 0.0
        for i in range(n):
            t += y[i] * AT[j, i]
        dj = (1.0 if j == m else 0.0) - t
        d[j] = dj
        tol = dual_tol * (ymax * Acol1[j] + (1.0 if j == m else 0.0))
        if j == m:
            if status[j] == UPPER or dj > tol:
                return False, 0.0
            continue
        fixed = lb[j] * f[j] == ub[j] * f[j]
        if status[j] == UPPER:
            s[j] = ub[j]
            if dj < -tol and not fixed:
                return False, 0.0
        else:
            s[j] = lb[j]
            if dj > tol and not fixed:
                return False, 0.0
        # weak-duality gap of a (tolerated) wrong-sign reduced cost: max(d lb, d ub) f - d s f
        if not fixed:
            g = max(dj * lb[j], dj * ub[j]) - dj * s[j]
            if g > 0.0:
                gapf += g * f[j]
    # primal: basic values T f, T = -Binv A_N diag(s)
    for i in range(n):
        rhs[i] = 0.0
    for j in range(m):
        if status[j] != BASIC and s[j] != 0.0:
            v = s[j] * f[j]
            for i in range(n):
                rhs[i] -= AT[j, i] * v
    w = 0.0
    w_basic = False
    ok = True
    for k in range(n):
        v = 0.0
        for i in range(n):
            v += Binv[k, i] * rhs[i]
        xB[k] = v
        # each test's tolerance grows with tf = |T_k| f >= 0, so the test is first made without that term:
        # where it passes, it passes with it too (the same decision); tf is computed only where it fails
        jb = basic[k]
        if jb < m:
            tol = primal_tol * (f[jb] + fmean)
            if v - lb[jb] * f[jb] + tol < 0.0 or ub[jb] * f[jb] - v + tol < 0.0:
                tol = primal_tol * (_tf(AT, Binv, status, s, f, k) + f[jb] + fmean)
                if v - lb[jb] * f[jb] + tol < 0.0 or ub[jb] * f[jb] - v + tol < 0.0:
                    ok = False
        elif jb == m:
            ws = 0.0
            for j in range(m):
                ws += wscale[j] * f[j]
            if v + primal_tol * ws < 0.0 and v + primal_tol * (_tf(AT, Binv, status, s, f, k) + ws) < 0.0:
                ok = False
            w = v
            w_basic = True
        else:
            i = jb - mp1
            rs = 0.0
            ws = 0.0
            for j in range(m):
                rs += Rscale[i, j] * f[j]
                ws += wscale[j] * f[j]
            if abs(v) > primal_tol * (rs + absb[i] * ws) and \
                    abs(v) > primal_tol * (_tf(AT, Binv, status, s, f, k) + rs + absb[i] * ws):
                ok = False
        if not ok:
            return False, 0.0
    if gapf > 0.0 and not gap_rel * w - gapf >= 0.0:
        return False, 0.0
    if not w_basic:
        w = 0.0
    w = max(w, 0.0)
    if want_alpha:
        for j in range(m):
            x = s[j] * f[j]
            alpha_out[j] = x
        for k in range(n):
            if basic[k] < m:
                alpha_out[basic[k]] = xB[k]
        for j in range(m):
            if f[j] > 0.0:
                a = alpha_out[j] / f[j]
            else:
                a = lb[j]
            alpha_out[j] = min(max(a, lb[j]), ub[j])
    return True, w


@njit(cache=True, nogil=True, fastmath=_FM)
def _dual_simplex(AT, lb, ub, Acol1, wscale, Rscale, f, basic, status, Binv0, max_iter, primal_tol,
                  B, Binv, M, lo, hi, ptol, isbasic, rhs, xB, y, rho, aq, col, confirm=True):
    """Bounded dual simplex from a dual feasible basis; updates ``basic``/``status`` in place.

    ``Binv0``: the (fresh) inverse of the starting basis matrix. Returns (code, pivots):
    ``CERTIFIED`` when no basic variable violates its bounds with a freshly computed inverse
    in ``Binv`` (the caller certifies), ``INFEASIBLE_SUSPECT`` when the ratio test finds no entering variable,
    ``FAILED`` on a singular basis or the iteration limit. With ``confirm=False``, ``UPDATED`` where no bound is
    violated with the updated inverse (not rebuilt; ``Binv`` is then not fresh and the caller must verify the
    basis from scratch, as :mod:`neckstrength.wrench.fused` does with ``make_basis``).
    """
    mp1, n = AT.shape
    m = mp1 - 1
    nv = mp1 + n
    Binv[:, :] = Binv0
    for j in range(nv):
        lo[j] = 0.0
        hi[j] = 0.0
    for j in range(m):
        lo[j] = lb[j] * f[j]
        hi[j] = ub[j] * f[j]
    hi[m] = np.inf
    # loop tolerances: half the smallest certification tolerance of each kind of variable
    fsum = 0.0
    ws = 0.0
    for j in range(m):
        fsum += f[j]
        ws += wscale[j] * f[j]
    for j in range(m):
        ptol[j] = 0.5 * primal_tol * fsum / m
    ptol[m] = 0.5 * primal_tol * ws
    for i in range(n):
        rs = 0.0
        for j in range(m):
            rs += Rscale[i, j] * f[j]
        ptol[mp1 + i] = 0.5 * primal_tol * rs
    for j in range(nv):
        isbasic[j] = False
    for k in range(n):
        isbasic[basic[k]] = True
    since = 0
    it = 0
    full = True
    while True:
        # basic solution: from scratch at the start and after every refactorisation, else updated
        # by the pivot (below); optimality is always confirmed from scratch with a fresh inverse
        if full:
            for i in range(n):
                rhs[i] = 0.0
            for j in range(m):
                if not isbasic[j]:
                    v = hi[j] if status[j] == UPPER else lo[j]
                    if v != 0.0:
                        for i in range(n):
                            rhs[i] -= AT[j, i] * v
            for k in range(n):
                v = 0.0
                for i in range(n):
                    v += Binv[k, i] * rhs[i]
                xB[k] = v
            full = False
        r = -1
        worst = 0.0
        for k in range(n):
            v = xB[k]
            jb = basic[k]
            viol = 0.0
            if v < lo[jb] - ptol[jb]:
                viol = lo[jb] - v
            elif v > hi[jb] + ptol[jb]:
                viol = v - hi[jb]
            if viol > worst:
                worst = viol
                r = k
        if r < 0:
            if since == 0:
                return CERTIFIED, it
            if not confirm:
                return UPDATED, it
            # optimal with an updated inverse: confirm with a fresh one
            _basis_matrix(AT, basic, B)
            if not _invert(B, Binv, M):
                return FAILED, it
            since = 0
            full = True
            continue
        if it == max_iter:
            return FAILED, it
        jr = basic[r]
        sgn = 1.0 if xB[r] < lo[jr] else -1.0
        # duals (minimisation of -w): y = B^-T c_B with c_w = -1
        for i in range(n):
            y[i] = 0.0
            rho[i] = Binv[r, i]
        for k in range(n):
            if basic[k] == m:
                for i in range(n):
                    y[i] = -Binv[k, i]
        rmax = 0.0
        for i in range(n):
            rmax = max(rmax, abs(rho[i]))
        # ratio test over the nonbasic, non-fixed variables
        q = -1
        best = np.inf
        bestpiv = 0.0
        for j in range(mp1):
            if isbasic[j] or hi[j] == lo[j]:
                continue
            a = 0.0
            t = 0.0
            for i in range(n):
                a += rho[i] * AT[j, i]
                t += y[i] * AT[j, i]
            at = sgn * a
            if abs(at) <= 1e-9 * rmax * Acol1[j]:
                continue
            dj = (-1.0 if j == m else 0.0) - t          # reduced cost, minimisation
            if status[j] == UPPER:
                if at <= 0.0:
                    continue
                ratio = max(-dj, 0.0) / at
            else:
                if at >= 0.0:
                    continue
                ratio = max(dj, 0.0) / -at
            if ratio < best * (1.0 - 1e-12) or (ratio <= best * (1.0 + 1e-12) and abs(at) > bestpiv):
                best = min(best, ratio)
                q = j
                bestpiv = abs(at)
        if q < 0:
            return INFEASIBLE_SUSPECT, it
        # pivot: q enters at row r, the leaving variable goes to its violated bound
        xq = hi[q] if status[q] == UPPER else lo[q]        # the entering variable's current value
        target = lo[jr] if sgn > 0 else hi[jr]
        if jr < mp1:
            status[jr] = LOWER if sgn > 0 else UPPER
        isbasic[jr] = False
        isbasic[q] = True
        status[q] = BASIC
        basic[r] = q
        since += 1
        it += 1
        if since >= REFACTOR:
            _basis_matrix(AT, basic, B)
            if not _invert(B, Binv, M):
                return FAILED, it
            since = 0
            full = True
        else:
            _column(AT, q, col)
            for k in range(n):
                v = 0.0
                for i in range(n):
                    v += Binv[k, i] * col[i]
                aq[k] = v
            piv = aq[r]
            if abs(piv) < 1e-14:
                return FAILED, it
            # primal step: x_q moves by theta, the other basic variables by -theta aq
            theta = (xB[r] - target) / piv
            for k in range(n):
                xB[k] -= theta * aq[k]
            xB[r] = xq + theta
            for i in range(n):
                Binv[r, i] /= piv
            for k in range(n):
                if k != r and aq[k] != 0.0:
                    g = aq[k]
                    for i in range(n):
                        Binv[k, i] -= g * Binv[r, i]


@njit(cache=True, nogil=True, fastmath=_FM)
def solve_rows(A, lb, ub, Acol1, wscale, Rscale, absb, F, rows, start, SB, SS, SBinv, max_iter, primal_tol, dual_tol,
               gap_rel, max_cond, want_alpha, out_w, out_code, out_basic, out_status, out_alpha, out_pivots):
    """Dual simplex + certificate for ``F[rows[t]]`` from cached basis ``start[t]`` (``SB``/``SS``,
    inverse ``SBinv``).

    Writes ``out_w[t]``, ``out_code[t]`` (``CERTIFIED``/``FAILED``/``INFEASIBLE_SUSPECT``), the
    final basis (``out_basic[t]``, ``out_status[t]``), ``out_pivots[t]`` and, with ``want_alpha``,
    the activations ``out_alpha[t]``.
    """
    n, mp1 = A.shape
    nv = mp1 + n
    AT = np.ascontiguousarray(A.T)      # columns of A contiguous for the inner loops
    B = np.empty((n, n))
    Binv = np.empty((n, n))
    M = np.empty((n, n))
    lo = np.empty(nv)
    hi = np.empty(nv)
    ptol = np.empty(nv)
    isbasic = np.empty(nv, dtype=np.bool_)
    rhs = np.empty(n)
    xB = np.empty(n)
    y = np.empty(n)
    rho = np.empty(n)
    aq = np.empty(n)
    col = np.empty(n)
    d = np.empty(mp1)
    s = np.empty(mp1)
    basic = np.empty(n, dtype=SB.dtype)
    status = np.empty(mp1, dtype=SS.dtype)
    for t in range(rows.shape[0]):
        f = F[rows[t]]
        basic[:] = SB[start[t]]
        status[:] = SS[start[t]]
        code, piv = _dual_simplex(AT, lb, ub, Acol1, wscale, Rscale, f, basic, status, SBinv[start[t]], max_iter,
                                  primal_tol,
                                  B, Binv, M, lo, hi, ptol, isbasic, rhs, xB, y, rho, aq, col)
        out_pivots[t] = piv
        if code == CERTIFIED:
            ok, w = _certify(AT, lb, ub, Acol1, wscale, Rscale, absb, f, basic, status, primal_tol, dual_tol,
                             gap_rel, max_cond, out_alpha[t], want_alpha, B, Binv, y, d, s, rhs, xB)
            if ok:
                out_w[t] = w
            else:
                code = FAILED
        out_code[t] = code
        for k in range(n):
            out_basic[t, k] = basic[k]
        for j in range(mp1):
            out_status[t, j] = status[j]


@njit(cache=True, nogil=True, fastmath=_FM)
def check_rows(F, rows, label, CW3, qv, wbasic, T3, rowk, bnd, lb, ub, want_alpha, out_ok, out_w, out_alpha):
    """The cached-basis test of ``DirectionSolver._try`` for many rows at once, each against its own basis.

    Row ``rows[t]`` of ``F`` is checked against basis ``label[t]``: ``CW3[b, :qv[b]] @ f >= 0``
    (primal feasibility with the tolerances folded in); where it holds, ``out_w[t] = max(CW3[b, qv[b]] @ f,
    0)`` (0 if ``w`` is not basic) and, with ``want_alpha``, the activations of the basic solution as
    ``DirectionSolver._alpha`` computes them (``x = P f``; ``x_j / f_j``, ``lb_j`` where ``f_j = 0``,
    clipped to the bounds): ``x_j = T3[b, k] . f`` where column ``j`` is the ``k``-th basic variable
    (``rowk[b, j] = k``), else ``x_j = bnd[b, j] f_j`` (``bnd``: the column's bound at this basis).
    """
    m = F.shape[1]
    for t in range(rows.shape[0]):
        r = rows[t]
        b = label[t]
        q = qv[b]
        ok = True
        for c in range(q):
            v = 0.0
            for j in range(m):
                v += CW3[b, c, j] * F[r, j]
            if not v >= 0.0:
                ok = False
                break
        out_ok[t] = ok
        if not ok:
            continue
        if wbasic[b]:
            v = 0.0
            for j in range(m):
                v += CW3[b, q, j] * F[r, j]
            out_w[t] = max(v, 0.0)
        else:
            out_w[t] = 0.0
        if want_alpha:
            for j in range(m):
                fj = F[r, j]
                k = rowk[b, j]
                if k >= 0:
                    x = 0.0
                    for i in range(m):
                        x += T3[b, k, i] * F[r, i]
                else:
                    x = bnd[b, j] * fj
                if fj > 0.0:
                    a = x / fj
                else:
                    a = lb[j]
                out_alpha[t, j] = min(max(a, lb[j]), ub[j])


@njit(cache=True, nogil=True)     # no fastmath: the same roundings as the numpy reference (e.g. no fused d_j s_j)
def make_basis(A, lb, ub, Acol1, fscale, wscale, Rscale, b, bcols, brows, col, f, primal_tol, dual_tol, gap_rel,
               max_cond, Binv, T, CW, dvec):
    """The verification and linear maps of ``DirectionSolver._make_basis`` in compiled code.

    ``bcols``/``brows``: sorted basic columns and row logicals; ``col`` (m + 1): per-column bound status,
    adjusted in place (variables fixed at this ``f`` move to the bound that keeps the basis dual feasible).
    Writes ``Binv`` (inverse of the basis matrix, columns in the order ``bcols``, ``brows``), ``T`` (basic
    variables = ``T f``), the checks ``CW[:q]`` (feasible iff ``CW[:q] @ f >= 0``), ``CW[q]`` (``f -> w``)
    and ``dvec`` (the dual bound ``w*(f) <= dvec . f``). Returns ``(ok, q, w_basic)``; ``ok`` is False for a
    singular or ill-conditioned basis or one that is not dual feasible (``dual_tol`` relative to
    ``|y|_inf |A_j|_1``).
    """
    n = A.shape[0]
    return make_basis_ws(A, lb, ub, Acol1, fscale, wscale, Rscale, b, bcols, brows, col, f, primal_tol, dual_tol,
                         gap_rel, max_cond, Binv, T, CW, dvec, np.empty((n, n)), np.empty((n, n)), np.empty(n),
                         np.empty(A.shape[1]), np.empty(A.shape[1] - 1))


@njit(cache=True, nogil=True)     # no fastmath, as make_basis
def make_basis_ws(A, lb, ub, Acol1, fscale, wscale, Rscale, b, bcols, brows, col, f, primal_tol, dual_tol, gap_rel,
                  max_cond, Binv, T, CW, dvec, B, M, y, d, s):
    """:func:`make_basis` with its work arrays given (``B``, ``M``: n x n; ``y``: n; ``d``: m + 1; ``s``: m), for
    callers that learn many bases (:mod:`neckstrength.wrench.fused`); the same arithmetic, so the same maps."""
    n, mp1 = A.shape
    m = mp1 - 1
    nb = bcols.shape[0]
    for k in range(n):
        for i in range(n):
            B[i, k] = 0.0
    for k in range(nb):
        for i in range(n):
            B[i, k] = A[i, bcols[k]]
    for k in range(brows.shape[0]):
        B[brows[k], nb + k] = -1.0
    if not _invert(B, Binv, M):
        return False, 0, False
    if not _conditioned(B, Binv, n, max_cond):
        return False, 0, False
    for i in range(n):
        y[i] = 0.0
    for k in range(nb):
        if bcols[k] == m:
            for i in range(n):
                y[i] += Binv[k, i]
    ymax = 0.0
    for i in range(n):
        ymax = max(ymax, abs(y[i]))
    for j in range(mp1):
        t = 0.0
        for i in range(n):
            t += y[i] * A[i, j]
        d[j] = (1.0 if j == m else 0.0) - t
    for j in range(mp1):
        if col[j] == BASIC:
            continue
        fixed = j < m and lb[j] * f[j] == ub[j] * f[j]
        if fixed:
            if d[j] > 0:
                col[j] = UPPER
            elif d[j] < 0:
                col[j] = LOWER
        tol = dual_tol * (ymax * Acol1[j] + (1.0 if j == m else 0.0))
        if (col[j] == LOWER and d[j] > tol) or (col[j] == UPPER and d[j] < -tol):
            return False, 0, False
    if col[m] == UPPER:
        return False, 0, False
    for j in range(m):
        s[j] = 0.0 if col[j] == BASIC else (ub[j] if col[j] == UPPER else lb[j])
    # T[k, j] = sum_i Binv[k, i] * -(A[i, j] s_j), summed over i in order (the numpy reference's rounding); the
    # loop over j innermost so that it vectorises
    for k in range(n):
        for j in range(m):
            T[k, j] = 0.0
        for i in range(n):
            g = Binv[k, i]
            for j in range(m):
                T[k, j] += g * -(A[i, j] * s[j])
        for j in range(m):
            if not np.isfinite(T[k, j]):
                return False, 0, False
    q = 0
    for side in range(2):                               # lb_j f_j <= x_j <= ub_j f_j, lower rows first
        for k in range(nb):
            J = bcols[k]
            if J >= m:
                continue
            for j in range(m):
                e = 1.0 if j == J else 0.0
                tolx = primal_tol * (abs(T[k, j]) + e + fscale[j])
                if side == 0:
                    CW[q, j] = T[k, j] - lb[J] * e + tolx
                else:
                    CW[q, j] = ub[J] * e - T[k, j] + tolx
            q += 1
    kw = -1
    nw = 0
    for k in range(nb):
        if bcols[k] == m:
            kw = k
            nw += 1
    w_basic = nw == 1
    if w_basic:                                         # w >= 0
        for j in range(m):
            CW[q, j] = T[kw, j] + primal_tol * (abs(T[kw, j]) + wscale[j])
        q += 1
    anygap = False
    for j in range(m):
        dvec[j] = max(d[j] * lb[j], d[j] * ub[j])
        g = 0.0 if col[j] == BASIC else dvec[j] - d[j] * s[j]
        if g > 0:
            anygap = True
    if anygap:
        for j in range(m):
            g = 0.0 if col[j] == BASIC else dvec[j] - d[j] * s[j]
            CW[q, j] = gap_rel * (T[kw, j] if w_basic else 0.0) - g
        q += 1
    for side in range(2):                               # basic row activities are 0
        for k in range(brows.shape[0]):
            r = brows[k]
            for j in range(m):
                t = T[nb + k, j]
                tolr = primal_tol * (abs(t) + Rscale[r, j] + abs(b[r]) * wscale[j])
                CW[q, j] = (t if side == 0 else -t) + tolr
            q += 1
    for j in range(m):
        CW[q, j] = T[kw, j] if w_basic else 0.0
    return True, q, w_basic
