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
3. else the compiled dual simplex runs from that basis (without rebuilding the inverse at its end) and its final
   basis is learned: ``make_basis`` inverts it afresh and checks dual feasibility and conditioning (the tests of the
   batched solver's ``_add_basis``), and the row is answered where the new basis's checks pass, the test of a cache
   hit; where they do not (a basis already cached or rejected, an updated inverse that was off), the certificate
   from scratch decides (:func:`neckstrength.wrench.simplex._certify`, the tests the batched solver applies). This
   does the factorisation work once per miss (it was done three times: at the simplex's end, in the certificate
   and in ``make_basis``);
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

#: Bases kept per slot (direction and bound vector); the least recently hit is replaced. With the pool (a slot's
#: bases take memory as they are learned) 32 costs little: calibrated S003 1.04x less CPU than 16, the same results to
#: 1e-6 (docs/benchmarks.md#gap-fused-learn-once).
CAPACITY = 32

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
           max_cond, nb, CW, qv, wb, T4, dvec, SB, SS, SBinv, hits, pidx, npool, ws, bcols_buf, brows_buf, col_buf):
    """Cache the basis (``basic``, ``status``) in slot ``s`` (replacing the least-hit one when full); returns its
    index or -1 (already cached, or rejected by ``make_basis``).

    The maps go to the pool entry ``pidx[s, c]`` (``CW``, ``T4``, ``SBinv``); a new basis of a slot that is not full
    takes the next free entry ``npool[0]``, which the caller guarantees to exist (:meth:`FusedStore._reserve`).
    ``ws``: the work arrays of :func:`_work` (the map buffers and ``make_basis_ws``'s)."""
    n = basic.shape[0]
    mp1 = status.shape[0]
    m = mp1 - 1
    C = qv.shape[1]
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
    Binv_s, T_s, CW_s, dvec_s, Bw, Mw, yw, dw, sw = ws
    ok, q, w_basic = _sx.make_basis_ws(A3[s], LB[s], UB[s], ACOL1[s], FSCALE, WSCALE[s], RSCALE[s], B2[s], bcols,
                                       brows, col_buf, f, primal_tol, dual_tol, gap_rel, max_cond, Binv_s, T_s, CW_s,
                                       dvec_s, Bw, Mw, yw, dw, sw)
    if not ok:
        return -1
    if nb[s] < C:
        c = nb[s]
        p = npool[0]
        npool[0] += 1
        pidx[s, c] = p
    else:
        c = 0
        for cc in range(1, C):
            if hits[s, cc] < hits[s, c]:
                c = cc
        p = pidx[s, c]
    SBinv[p] = Binv_s
    T4[p] = T_s
    CW[p, :q + 1] = CW_s[:q + 1]
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
def _work(n, m):
    """The work arrays of :func:`_learn`: ``Binv``, ``T``, ``CW`` and ``dvec`` buffers, then ``make_basis_ws``'s."""
    return (np.empty((n, n)), np.empty((n, m)), np.empty((2 * n + 3, m)), np.empty(m), np.empty((n, n)),
            np.empty((n, n)), np.empty(n), np.empty(m + 1), np.empty(m))


@njit(cache=True, nogil=True)
def _start_basis(s, f, A3, LB, UB, ACOL1, FSCALE, WSCALE, RSCALE, B2, primal_tol, dual_tol, gap_rel, max_cond,
                 nb, CW, qv, wb, T4, dvec, SB, SS, SBinv, hits, pidx, npool, ws, bcols_buf, brows_buf, col_buf):
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
                  max_cond, nb, CW, qv, wb, T4, dvec, SB, SS, SBinv, hits, pidx, npool, ws, bcols_buf, brows_buf,
                  col_buf)


@njit(cache=True, nogil=True, fastmath=_sx._FM)
def _fused_solve(F, slots, unbounded, A3, LB, UB, ACOL1, FSCALE, WSCALE, RSCALE, ABSB, B2, nb, CW, qv, wb, T4,
                 dvec, SB, SS, SBinv, hits, pidx, npool, last, NFK, FK, max_iter, primal_tol, dual_tol, gap_rel,
                 max_cond, zero_rel, decay, want_alpha, out_w, out_code, out_alpha, counters):
    """Every row of ``F`` (N x m) for every call direction ``k`` (slot ``slots[k]``); see the module docstring.

    Writes ``out_w`` (N x K), ``out_code`` (N x K: ``OK``/``ZERO``/``INFEASIBLE``/``FAILED``/``UNBOUNDED``) and,
    with ``want_alpha``, ``out_alpha`` (N x K x m). ``counters``: cache hits, simplex solves, pivots, learned
    bases, Farkas hits, failures (added to). ``CW``, ``T4``, ``SBinv``: the store's pool (slot ``s``'s basis ``c`` at
    entry ``pidx[s, c]``; ``npool[0]`` entries in use, room for the bases this call can learn)."""
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
    ws = _work(n, m)
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
                ok = _check(CW[pidx[s, c]], qv[s, c], f, m)
            if ok:
                p = pidx[s, c]
                w = _answer(CW[p], qv[s, c], wb[s, c], T4[p], SB[s, c], SS[s, c], f, LB[s], UB[s],
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
                                     gap_rel, max_cond, nb, CW, qv, wb, T4, dvec, SB, SS, SBinv, hits, pidx, npool,
                                     ws, bcols_buf, brows_buf, col_buf)
                    it_max = max_iter + 20 * (n + 1) if max_iter > 0 else 0
                else:
                    it_max = max_iter
                if c >= 0 and it_max > 0:
                    for r in range(n):
                        basic[r] = SB[s, c, r]
                    for j in range(mp1):
                        status[j] = SS[s, c, j]
                    res, piv = _sx._dual_simplex(AT, LB[s], UB[s], ACOL1[s], WSCALE[s], RSCALE[s], f, basic, status,
                                                 SBinv[pidx[s, c]], it_max, primal_tol, B, Binv, M, lo, hi, ptol,
                                                 isbasic, rhs, xB, y, rho, aq, colv, False)
                    if res == _sx.CERTIFIED or res == _sx.UPDATED:
                        # learn the final basis (make_basis: a fresh inverse, dual feasibility, conditioning, the
                        # maps) and certify it for f with its checks, the test of a cache hit; where that does not
                        # pass (already cached, rejected, or the updated inverse was off), the certificate from
                        # scratch decides
                        c2 = _learn(s, basic, status, f, A3, LB, UB, ACOL1, FSCALE, WSCALE, RSCALE, B2,
                                    primal_tol, dual_tol, gap_rel, max_cond, nb, CW, qv, wb, T4, dvec, SB, SS,
                                    SBinv, hits, pidx, npool, ws, bcols_buf, brows_buf, col_buf)
                        good = False
                        if c2 >= 0:
                            p = pidx[s, c2]
                            last[s] = c2
                            counters[3] += 1
                            if _check(CW[p], qv[s, c2], f, m):
                                good = True
                                w = _answer(CW[p], qv[s, c2], wb[s, c2], T4[p], SB[s, c2], SS[s, c2], f, LB[s],
                                            UB[s], want_alpha, alpha_tmp, n, m)
                        if not good:
                            fresh = res == _sx.CERTIFIED
                            if not fresh:
                                _sx._basis_matrix(AT, basic, B)
                                fresh = _sx._invert(B, Binv, M)
                            if fresh:
                                good, w = _sx._certify(AT, LB[s], UB[s], ACOL1[s], WSCALE[s], RSCALE[s], ABSB[s], f,
                                                       basic, status, primal_tol, dual_tol, gap_rel, max_cond,
                                                       alpha_tmp, want_alpha, B, Binv, y, d, sv, rhs, xB)
                        if good:
                            code = OK
                            counters[1] += 1
                            counters[2] += piv
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
    """The compiled cache of one constraint matrix ``R`` (n x m): bases per slot (direction and bound vector).

    A slot's bookkeeping (statuses, basic sets, dual bounds, hits: about 2 kB at 16 bases) is kept per slot; the
    large maps of each basis (checks ``CW``, basic map ``T``, inverse: about 6.4 kB for s3m24) live in a pool shared
    by the store's slots and are taken as bases are learned (``pidx``: a slot's pool entries), so memory grows with
    the bases held, not with ``capacity`` times the slots (half of one participant's slots hold one to three)."""

    def __init__(self, R: np.ndarray, capacity: int = CAPACITY):
        self.R = np.ascontiguousarray(R, dtype=float)
        self.n, self.m = self.R.shape
        self.C = int(capacity)
        self._index: dict[bytes, int] = {}
        self.calls: dict[bytes, tuple] = {}       # recent calls' directions -> (b vectors, slots)
        self.S = 0
        self.counters = np.zeros(6, dtype=np.int64)
        self.npool = np.zeros(1, dtype=np.int64)  # pool entries in use
        self.pool: dict[str, np.ndarray] = {}
        self._alloc(8)
        self._grow_pool(4 * self.C)

    def _alloc(self, cap: int) -> None:
        n, m, C = self.n, self.m, self.C
        shapes = {"A3": ((n, m + 1), float), "LB": ((m,), float), "UB": ((m,), float), "ACOL1": ((m + 1,), float),
                  "WSCALE": ((m,), float), "RSCALE": ((n, m), float), "ABSB": ((n,), float), "B2": ((n,), float),
                  "unbounded": ((), np.bool_), "nb": ((), np.int64), "qv": ((C,), np.int64), "wb": ((C,), np.bool_),
                  "dvec": ((C, m), float), "SB": ((C, n), np.int64), "SS": ((C, m + 1), np.int8),
                  "hits": ((C,), float), "pidx": ((C,), np.int64), "last": ((), np.int64), "NFK": ((), np.int64),
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

    def _grow_pool(self, size: int) -> None:
        n, m = self.n, self.m
        shapes = {"CW": (2 * n + 3, m), "T4": (n, m), "SBinv": (n, n)}
        used = int(self.npool[0])
        for name, shape in shapes.items():
            a = np.empty((size,) + shape)
            if used:
                a[:used] = self.pool[name][:used]
            self.pool[name] = a
        self.pool_size = size

    def _reserve(self, slots: np.ndarray, most: int) -> None:
        """Make room in the pool for every basis the slots ``slots`` can still take in a call that learns at most
        ``most`` per slot (``capacity`` less the bases each holds, at most ``most``), so that the compiled pass never
        runs out of entries."""
        need = int(np.minimum(self.C - self.arrays["nb"][slots], most).sum())     # a slot listed twice: counted twice
        if int(self.npool[0]) + need > self.pool_size:
            self._grow_pool(max(self.pool_size + self.pool_size // 2, int(self.npool[0]) + need))

    def _maps(self) -> tuple:
        a, p = self.arrays, self.pool
        return (a["nb"], p["CW"], a["qv"], a["wb"], p["T4"], a["dvec"], a["SB"], a["SS"], p["SBinv"], a["hits"],
                a["pidx"], self.npool)

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
        self._reserve(np.array([s]), most)
        ws = _work(n, m)
        for bb in sorted(bases, key=lambda bb: -bb.hits)[:most]:
            _learn(s, np.asarray(bb.basic, dtype=np.int64), np.asarray(bb.status, dtype=np.int8), f, a["A3"], a["LB"],
                   a["UB"], a["ACOL1"], np.full(m, 1.0 / m), a["WSCALE"], a["RSCALE"], a["B2"], *self._tols,
                   *self._maps(), ws, np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64),
                   np.empty(m + 1, dtype=np.int64))

    def solve(self, F: np.ndarray, slots: np.ndarray, want_alpha: bool, max_iter: int, tols: tuple,
              zero_rel: float, decay: float):
        """:func:`_fused_solve` for ``F`` (N x m, contiguous float) and the call's ``slots``; returns
        ``(w, code, alpha)``."""
        N = F.shape[0]
        K = slots.shape[0]
        w = np.zeros((N, K))
        code = np.full((N, K), FAILED, dtype=np.int8)
        alpha = np.empty((N, K, self.m)) if want_alpha else np.empty((1, 1, self.m))
        self._reserve(slots, N + 1)          # a first basis and one per row
        a = self.arrays
        self._tols = tuple(tols)
        _fused_solve(F, slots, a["unbounded"], a["A3"], a["LB"], a["UB"], a["ACOL1"], np.full(self.m, 1.0 / self.m),
                     a["WSCALE"], a["RSCALE"], a["ABSB"], a["B2"], *self._maps()[:10], a["pidx"], self.npool,
                     a["last"], a["NFK"], a["FK"], int(max_iter), *tols, float(zero_rel), float(decay),
                     bool(want_alpha), w, code, alpha, self.counters)
        return w, code, (alpha if want_alpha else None)
