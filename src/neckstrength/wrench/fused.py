"""All directions of a max-wrench call in one compiled pass (the fast path for many small calls).

The gap diagnosis solves the max-wrench LP (:mod:`neckstrength.wrench.batched`) in thousands of small calls: a
few strength vectors (a fit's damping trials, a handful of problems) times 25-275 directions. The per-direction
:class:`~neckstrength.wrench.batched.DirectionSolver` is exact and fast for large blocks, but in a call of three
rows its Python bookkeeping (ranking, checks, learning, statistics) costs far more than the LPs; a profile of one
participant's diagnosis put 89 % of the time in the solver, most of it that bookkeeping.

:class:`FusedStore` keeps, for one constraint matrix ``R`` and every direction and bound vector seen (a *slot*),
up to ``capacity`` optimal bases as the same linear maps the batched solver caches (built by the same compiled
:func:`neckstrength.wrench.simplex.make_basis`: checks ``CW``, basic map ``T``, dual bound ``dvec``, inverse),
packed in arrays, and :func:`_fused_solve` answers every (row, direction) of a call in one compiled loop:

1. the basis with the smallest dual bound ``dvec . f`` (weak duality; equal to ``w*`` for an optimal basis) is
   checked (primal feasibility with the batched solver's tolerances, ``CW[:q] f >= 0``); a dual feasible basis that
   passes is optimal. (Checking the previous row's basis first was cheaper, but made a row's answer, where the
   optimum is not unique, depend on the row before it; see ``FusedStore``'s note on history);
2. else the slot's cached Farkas certificates (copied from the batched solver) may prove the row infeasible;
3. else the compiled dual simplex runs from that basis and its final basis is certified from scratch
   (:func:`neckstrength.wrench.simplex._certify`, the tests the batched solver applies) and learned;
4. what is left (a failed certificate, a suspected infeasibility, a direction without a first basis) goes back
   to the batched solver, and so to HiGHS.

Every answer is therefore a certified optimal basis, as in the batched solver: the forces agree with HiGHS to the
certificate's tolerances. Where the optimum is not unique the activations may be another optimal vertex than the
batched solver's (which one either path returns depends on the bases its cache holds). The gap fits' exact Jacobians
(:meth:`neckstrength.gap.fit.Simulator.forces_grad_phi`) do not follow the vertex: ``dw/df_j = (lam . R_j) alpha_j``
with the dual ``lam``, and a column that is inside its bounds at some optimal vertex has ``lam . R_j = 0``
(tests/gap/test_fused_fits.py). What remains is rounding: two optimal bases give the same force to about 1e-15, and
a fit's end point moves within its stopping tolerance with it, as it does with the batched solver.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from neckstrength.wrench import simplex as _sx

#: Result codes of :func:`_fused_solve` (per row and direction).
OK, ZERO, INFEASIBLE, FAILED, UNBOUNDED = 0, 1, 2, 3, 4

#: Bases kept per slot (direction and bound vector); the least recently hit is replaced.
CAPACITY = 16

#: Farkas certificates kept per slot.
FARKAS_CAPACITY = 8


@njit(cache=True, nogil=True, fastmath=_sx._FM)
def _check(CWs, q, f, m):
    for c in range(q):
        v = 0.0
        for j in range(m):
            v += CWs[c, j] * f[j]
        if not v >= 0.0:
            return False
    return True


@njit(cache=True, nogil=True, fastmath=_sx._FM)
def _answer(CWs, q, wbasic, Ts, SBs, SSs, f, lb, ub, want_alpha, alpha_out, n, m):
    """``w`` (and the activations) of a basis that passed its check, as ``simplex.check_rows``."""
    w = 0.0
    if wbasic:
        v = 0.0
        for j in range(m):
            v += CWs[q, j] * f[j]
        w = max(v, 0.0)
    if want_alpha:
        for j in range(m):
            bnd = ub[j] if SSs[j] == _sx.UPPER else lb[j]
            alpha_out[j] = bnd * f[j]
        for k in range(n):
            jb = SBs[k]
            if jb < m:
                x = 0.0
                for i in range(m):
                    x += Ts[k, i] * f[i]
                alpha_out[jb] = x
        for j in range(m):
            fj = f[j]
            a = alpha_out[j] / fj if fj > 0.0 else lb[j]
            alpha_out[j] = min(max(a, lb[j]), ub[j])
    return w


@njit(cache=True, nogil=True)
def _learn(s, basic, status, f, A3, LB, UB, ACOL1, FSCALE, WSCALE, RSCALE, B2, primal_tol, dual_tol, gap_rel,
           max_cond, nb, CW, qv, wb, T4, dvec, SB, SS, SBinv, hits, bcols_buf, brows_buf, col_buf):
    """Cache the basis (``basic``, ``status``) in slot ``s`` (replacing the least-hit one when full); returns its
    index or -1 (already cached, or rejected by ``make_basis``)."""
    n = basic.shape[0]
    mp1 = status.shape[0]
    m = mp1 - 1
    C = CW.shape[1]
    # already cached? (same basic set and statuses)
    for c in range(nb[s]):
        same = True
        for j in range(mp1):
            if SS[s, c, j] != status[j]:
                same = False
                break
        if same:
            cnt = 0
            for k in range(n):
                for kk in range(n):
                    if SB[s, c, kk] == basic[k]:
                        cnt += 1
                        break
            if cnt == n:
                return -1
    nbc = 0
    nbr = 0
    for k in range(n):
        if basic[k] < mp1:
            nbc += 1
        else:
            nbr += 1
    bcols = bcols_buf[:nbc]
    brows = brows_buf[:nbr]
    a = 0
    r = 0
    for k in range(n):
        if basic[k] < mp1:
            bcols[a] = basic[k]
            a += 1
        else:
            brows[r] = basic[k] - mp1
            r += 1
    bcols.sort()
    brows.sort()
    for j in range(mp1):
        col_buf[j] = status[j]
    n_cw = CW.shape[2]
    Binv_s = np.empty((n, n))
    T_s = np.empty((n, m))
    CW_s = np.empty((n_cw, m))
    dvec_s = np.empty(m)
    ok, q, w_basic = _sx.make_basis(A3[s], LB[s], UB[s], ACOL1[s], FSCALE, WSCALE[s], RSCALE[s], B2[s], bcols,
                                    brows, col_buf, f, primal_tol, dual_tol, gap_rel, max_cond, Binv_s, T_s, CW_s,
                                    dvec_s)
    if not ok:
        return -1
    if nb[s] < C:
        c = nb[s]
    else:
        c = 0
        for cc in range(1, C):
            if hits[s, cc] < hits[s, c]:
                c = cc
    SBinv[s, c] = Binv_s
    T4[s, c] = T_s
    CW[s, c, :q + 1] = CW_s[:q + 1]
    dvec[s, c] = dvec_s
    qv[s, c] = q
    wb[s, c] = w_basic
    for k in range(nbc):
        SB[s, c, k] = bcols[k]
    for k in range(nbr):
        SB[s, c, nbc + k] = brows[k] + mp1
    for j in range(mp1):
        SS[s, c, j] = col_buf[j]
    hits[s, c] = 1.0
    if c == nb[s]:
        nb[s] += 1
    return c


@njit(cache=True, nogil=True)
def _start_basis(s, f, A3, LB, UB, ACOL1, FSCALE, WSCALE, RSCALE, B2, primal_tol, dual_tol, gap_rel, max_cond,
                 nb, CW, qv, wb, T4, dvec, SB, SS, SBinv, hits, bcols_buf, brows_buf, col_buf):
    """The slack basis of ``DirectionSolver._start_basis`` (``w`` basic in the row of the largest ``|b|``, the
    other rows' logicals basic, each force at the bound its reduced cost asks for), cached in slot ``s``."""
    n = A3.shape[1]
    m = A3.shape[2] - 1
    r0 = 0
    big = -1.0
    for i in range(n):
        if abs(B2[s, i]) > big:
            big = abs(B2[s, i])
            r0 = i
    basic = np.empty(n, dtype=np.int64)
    status = np.empty(m + 1, dtype=np.int8)
    for j in range(m):
        status[j] = _sx.UPPER if A3[s, r0, j] / B2[s, r0] > 0 else _sx.LOWER
    status[m] = _sx.BASIC
    basic[0] = m
    k = 1
    for i in range(n):
        if i != r0:
            basic[k] = m + 1 + i
            k += 1
    return _learn(s, basic, status, f, A3, LB, UB, ACOL1, FSCALE, WSCALE, RSCALE, B2, primal_tol, dual_tol, gap_rel,
                  max_cond, nb, CW, qv, wb, T4, dvec, SB, SS, SBinv, hits, bcols_buf, brows_buf, col_buf)


@njit(cache=True, nogil=True, fastmath=_sx._FM)
def _fused_solve(F, slots, unbounded, A3, LB, UB, ACOL1, FSCALE, WSCALE, RSCALE, ABSB, B2, nb, CW, qv, wb, T4,
                 dvec, SB, SS, SBinv, hits, last, NFK, FK, max_iter, primal_tol, dual_tol, gap_rel, max_cond,
                 zero_rel, decay, want_alpha, out_w, out_code, out_alpha, counters):
    """Every row of ``F`` (N x m) for every call direction ``k`` (slot ``slots[k]``); see the module docstring.

    Writes ``out_w`` (N x K), ``out_code`` (N x K: ``OK``/``ZERO``/``INFEASIBLE``/``FAILED``/``UNBOUNDED``) and,
    with ``want_alpha``, ``out_alpha`` (N x K x m). ``counters``: cache hits, simplex solves, pivots, learned
    bases, Farkas hits, failures (added to)."""
    N, m = F.shape
    K = slots.shape[0]
    n = A3.shape[1]
    mp1 = m + 1
    nv = mp1 + n
    AT = np.empty((mp1, n))
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
    colv = np.empty(n)
    d = np.empty(mp1)
    sv = np.empty(mp1)
    basic = np.empty(n, dtype=np.int64)
    status = np.empty(mp1, dtype=np.int8)
    alpha_tmp = np.empty(m)
    bcols_buf = np.empty(n, dtype=np.int64)
    brows_buf = np.empty(n, dtype=np.int64)
    col_buf = np.empty(mp1, dtype=np.int64)
    fsum = np.empty(N)
    for i in range(N):
        t = 0.0
        for j in range(m):
            t += F[i, j]
        fsum[i] = t
    for k in range(K):
        s = slots[k]
        if unbounded[s]:
            for i in range(N):
                out_w[i, k] = np.inf
                out_code[i, k] = UNBOUNDED
            continue
        for c in range(nb[s]):
            hits[s, c] *= decay
        have_AT = False
        for i in range(N):
            f = F[i]
            # the cached basis with the smallest dual bound (the lowest index among equal bounds), whatever the
            # previous row took: a row's answer depends on the slot's bases, not on the order of the rows
            c = -1
            ok = False
            bv = np.inf
            for cc in range(nb[s]):
                v = 0.0
                for j in range(m):
                    v += dvec[s, cc, j] * f[j]
                if v < bv:
                    bv = v
                    c = cc
            if c >= 0:
                ok = _check(CW[s, c], qv[s, c], f, m)
            if ok:
                w = _answer(CW[s, c], qv[s, c], wb[s, c], T4[s, c], SB[s, c], SS[s, c], f, LB[s], UB[s],
                            want_alpha, alpha_tmp, n, m)
                hits[s, c] += 1.0
                last[s] = c
                counters[0] += 1
                code = OK
            else:
                code = FAILED
                for r in range(NFK[s]):
                    v = 0.0
                    for j in range(m):
                        v += FK[s, r, j] * f[j]
                    if v < 0.0:
                        code = INFEASIBLE
                        break
                if code == INFEASIBLE:
                    counters[4] += 1
                    out_w[i, k] = 0.0
                    out_code[i, k] = INFEASIBLE
                    if want_alpha:
                        for j in range(m):
                            out_alpha[i, k, j] = np.nan
                    continue
                if not have_AT:
                    for j in range(mp1):
                        for r in range(n):
                            AT[j, r] = A3[s, r, j]
                    have_AT = True
                if nb[s] == 0:
                    c = _start_basis(s, f, A3, LB, UB, ACOL1, FSCALE, WSCALE, RSCALE, B2, primal_tol, dual_tol,
                                     gap_rel, max_cond, nb, CW, qv, wb, T4, dvec, SB, SS, SBinv, hits, bcols_buf,
                                     brows_buf, col_buf)
                    it_max = max_iter + 20 * (n + 1) if max_iter > 0 else 0
                else:
                    it_max = max_iter
                if c >= 0 and it_max > 0:
                    for r in range(n):
                        basic[r] = SB[s, c, r]
                    for j in range(mp1):
                        status[j] = SS[s, c, j]
                    res, piv = _sx._dual_simplex(AT, LB[s], UB[s], ACOL1[s], WSCALE[s], RSCALE[s], f, basic, status,
                                                 SBinv[s, c], it_max, primal_tol, B, Binv, M, lo, hi, ptol,
                                                 isbasic, rhs, xB, y, rho, aq, colv)
                    if res == _sx.CERTIFIED:
                        good, w = _sx._certify(AT, LB[s], UB[s], ACOL1[s], WSCALE[s], RSCALE[s], ABSB[s], f, basic,
                                               status, primal_tol, dual_tol, gap_rel, max_cond, alpha_tmp,
                                               want_alpha, B, Binv, y, d, sv, rhs, xB)
                        if good:
                            code = OK
                            counters[1] += 1
                            counters[2] += piv
                            c2 = _learn(s, basic, status, f, A3, LB, UB, ACOL1, FSCALE, WSCALE, RSCALE, B2,
                                        primal_tol, dual_tol, gap_rel, max_cond, nb, CW, qv, wb, T4, dvec, SB, SS,
                                        SBinv, hits, bcols_buf, brows_buf, col_buf)
                            if c2 >= 0:
                                last[s] = c2
                                counters[3] += 1
                if code == FAILED:
                    counters[5] += 1
                    out_code[i, k] = FAILED
                    continue
            if w <= zero_rel * max(1.0, fsum[i]):
                w = 0.0
                code = ZERO
            out_w[i, k] = w
            out_code[i, k] = code
            if want_alpha:
                for j in range(m):
                    out_alpha[i, k, j] = alpha_tmp[j]


class FusedStore:
    """The compiled cache of one constraint matrix ``R`` (n x m): bases per slot (direction and bound vector)."""

    def __init__(self, R: np.ndarray, capacity: int = CAPACITY):
        self.R = np.ascontiguousarray(R, dtype=float)
        self.n, self.m = self.R.shape
        self.C = int(capacity)
        self._index: dict[bytes, int] = {}
        self.calls: dict[bytes, tuple] = {}       # recent calls' directions -> (b vectors, slots)
        self.S = 0
        self.counters = np.zeros(6, dtype=np.int64)
        self._alloc(8)

    def _alloc(self, cap: int) -> None:
        n, m, C = self.n, self.m, self.C
        shapes = {"A3": ((n, m + 1), float), "LB": ((m,), float), "UB": ((m,), float), "ACOL1": ((m + 1,), float),
                  "WSCALE": ((m,), float), "RSCALE": ((n, m), float), "ABSB": ((n,), float), "B2": ((n,), float),
                  "unbounded": ((), np.bool_), "nb": ((), np.int64), "CW": ((C, 2 * n + 3, m), float),
                  "qv": ((C,), np.int64), "wb": ((C,), np.bool_), "T4": ((C, n, m), float), "dvec": ((C, m), float),
                  "SB": ((C, n), np.int64), "SS": ((C, m + 1), np.int8), "SBinv": ((C, n, n), float),
                  "hits": ((C,), float), "last": ((), np.int64), "NFK": ((), np.int64),
                  "FK": ((FARKAS_CAPACITY, m), float)}
        old = getattr(self, "arrays", None)
        new = {}
        for name, (shape, dt) in shapes.items():
            a = np.zeros((cap,) + shape, dtype=dt)
            if name == "last":
                a[:] = -1
            if old is not None:
                a[:self.S] = old[name][:self.S]
            new[name] = a
        self.arrays = new
        self.cap = cap

    def slot(self, b: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> int:
        """The slot of direction ``b = J^T u`` with activation bounds ``lb``, ``ub`` (made on first use)."""
        key = b.tobytes() + lb.tobytes() + ub.tobytes()
        s = self._index.get(key)
        if s is not None:
            return s
        if self.S == self.cap:
            self._alloc(2 * self.cap)
        s = self.S
        self.S += 1
        self._index[key] = s
        a = self.arrays
        R, m = self.R, self.m
        A = np.hstack([R, -b[:, None]])
        A[np.abs(A) < 1e-15] = 0.0                      # as DirectionSolver and the HiGHS model
        a["A3"][s] = A
        a["LB"][s] = lb
        a["UB"][s] = ub
        a["ACOL1"][s] = np.abs(A).sum(axis=0)
        bmax = float(np.max(np.abs(b))) if np.any(b) else 1.0
        a["WSCALE"][s] = (np.max(np.abs(R), axis=0) * ub / bmax / m) if self.n else np.zeros(m)
        a["RSCALE"][s] = np.abs(R) * ub[None, :]
        a["ABSB"][s] = np.abs(b)
        a["B2"][s] = b
        a["unbounded"][s] = not np.any(b)
        return s

    def add_farkas(self, s: int, certificates) -> None:
        """Copy Farkas certificates (``c``: infeasible where ``f . c < 0``) of the batched solver into slot ``s``."""
        a = self.arrays
        have = int(a["NFK"][s])
        for cm in certificates[have:FARKAS_CAPACITY]:
            a["FK"][s, have] = cm
            have += 1
        a["NFK"][s] = have

    def adopt(self, s: int, bases, f: np.ndarray, most: int = 4) -> None:
        """Learn up to ``most`` of the batched solver's bases (``_Basis``: ``basic``, ``status``; most hit first)
        into slot ``s`` (verified again by ``make_basis`` at strengths ``f``)."""
        a = self.arrays
        n, m = self.n, self.m
        f = np.ascontiguousarray(f, dtype=float)
        for bb in sorted(bases, key=lambda bb: -bb.hits)[:most]:
            _learn(s, np.asarray(bb.basic, dtype=np.int64), np.asarray(bb.status, dtype=np.int8), f, a["A3"], a["LB"],
                   a["UB"], a["ACOL1"], np.full(m, 1.0 / m), a["WSCALE"], a["RSCALE"], a["B2"], *self._tols,
                   a["nb"], a["CW"], a["qv"], a["wb"], a["T4"], a["dvec"], a["SB"], a["SS"], a["SBinv"], a["hits"],
                   np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64), np.empty(m + 1, dtype=np.int64))

    def solve(self, F: np.ndarray, slots: np.ndarray, want_alpha: bool, max_iter: int, tols: tuple,
              zero_rel: float, decay: float):
        """:func:`_fused_solve` for ``F`` (N x m, contiguous float) and the call's ``slots``; returns
        ``(w, code, alpha)``."""
        N = F.shape[0]
        K = slots.shape[0]
        w = np.zeros((N, K))
        code = np.full((N, K), FAILED, dtype=np.int8)
        alpha = np.empty((N, K, self.m)) if want_alpha else np.empty((1, 1, self.m))
        a = self.arrays
        self._tols = tuple(tols)
        _fused_solve(F, slots, a["unbounded"], a["A3"], a["LB"], a["UB"], a["ACOL1"], np.full(self.m, 1.0 / self.m),
                     a["WSCALE"], a["RSCALE"], a["ABSB"], a["B2"], a["nb"], a["CW"], a["qv"], a["wb"], a["T4"],
                     a["dvec"], a["SB"], a["SS"], a["SBinv"], a["hits"], a["last"], a["NFK"], a["FK"], int(max_iter),
                     *tols, float(zero_rel), float(decay), bool(want_alpha), w, code, alpha, self.counters)
        return w, code, (alpha if want_alpha else None)
