"""Exact batched max-wrench solver: optimal-basis caching (see ``docs/batched_solver.md``).

The max-wrench LP (thesis Eq. 4.1 / 5.2), written in muscle forces ``x = f * alpha``
as in :mod:`neckstrength.wrench`::

    max w   s.t.   R x - b w = 0,   alpha_lb * f <= x <= alpha_ub * f,   w >= 0,   b = J^T u

has a constraint matrix ``A = [R, -b]`` that does not depend on the strengths
``f``; only the bounds do. A simplex basis (the basic set plus the bound at
which every nonbasic variable sits) has reduced costs ``c - A^T y`` with
``B^T y = c_B``: they involve ``A`` and ``c`` only, so a basis that is dual
feasible for one ``f`` is dual feasible for every ``f``. It is optimal for every
``f`` for which its basic solution is primal feasible, and that solution is a
fixed linear map of ``f`` (nonbasic ``x_j`` sit at ``alpha_lb_j f_j`` or
``alpha_ub_j f_j``; the basic variables solve the equality). So, per direction
and activation-bound vector, :class:`DirectionSolver` keeps the optimal bases it
has seen as matrices. The dual solution of every cached basis bounds ``w*(f)``
from above (weak duality), linearly in ``f`` and with equality where the basis
is optimal, so one matrix product ranks the cached bases for a whole batch; each
candidate is then checked (primal feasibility, to a tight tolerance relative to
the size of the terms) against its best-ranked basis only. Candidates that fit
no cached basis go to HiGHS (the :class:`neckstrength.wrench.problem._DirectionLP`
that :func:`~neckstrength.wrench.highs.max_wrench_batch` uses), whose optimal basis
is verified (dual feasibility recomputed here) and added to the cache.
Infeasible activation lower bounds are cached in the same way as Farkas
certificates (linear in ``f`` too).

Candidates that no cached basis fits are first given to a compiled dual
simplex (:mod:`neckstrength.wrench.simplex`), warm-started from the basis the
ranking chose (dual feasible for every ``f``); its final basis is certified
from scratch with the same tests before the row is answered, and frequent new
bases are learned into the cache. HiGHS remains the fallback.

Public API: :func:`max_wrench_batched` (same return convention as
:func:`neckstrength.wrench.highs.max_wrench_batch`), :func:`max_wrench_batched_arrays`
(plain arrays), :class:`BasisCache` (keep it across calls with nearby
candidates), :class:`DirectionSolver` (one direction and bound vector).
"""

from __future__ import annotations

import collections
import contextlib
import hashlib
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import highspy
import numpy as np

from neckstrength.model.reduction import ReducedModel
from neckstrength.wrench.problem import STATUS_CODES, _bounds, _DirectionLP
from neckstrength.seeds import HASH_SEED, derive_rng

try:  # the compiled dual simplex (numba); without it every cache miss goes to HiGHS
    from neckstrength.wrench import simplex as _simplex
except ImportError:  # pragma: no cover - numba is a dependency
    _simplex = None

_CODE = {v: k for k, v in STATUS_CODES.items()}


_OPT, _ZERO, _INF, _UNB = (_CODE[s] for s in ("optimal", "zero", "infeasible", "unbounded"))


#: A cached basis is accepted for ``f`` when each basic variable is within its
#: bounds up to ``PRIMAL_TOL`` times the size of the terms that make it up
#: (``|T_k| . f``) plus the variable's own scale (``f_j``, mean ``f``).
PRIMAL_TOL = 1e-11


#: A HiGHS basis is cached only if its reduced costs (recomputed here) have the
#: optimal sign up to ``DUAL_TOL`` relative to ``|y|_inf |A_j|_1``.
DUAL_TOL = 1e-10


#: A basis whose reduced costs have the wrong sign (within ``DUAL_TOL``) is accepted
#: for ``f`` only if its duality-gap bound is below ``GAP_REL * w``.
GAP_REL = 1e-12


#: A cached Farkas certificate declares ``f`` infeasible only with this relative margin.
FARKAS_MARGIN = 1e-6


#: Bases whose matrix has a larger 1-norm condition number are not cached.
MAX_COND = 1e10


#: Relative slack when comparing dual bounds (only prunes work; exactness rests on the checks).
TIE_REL = 1e-8


#: First block size of :meth:`DirectionSolver.solve` (doubling after each block) ...
BLOCK_START = 1024


#: ... unless the previous call sent fewer than this share of its rows to HiGHS.
WARM_MISS_RATE = 1e-3


#: Lean mode (see :meth:`DirectionSolver._solve_block`): with at least ``LEAN_MIN_BASES`` cached
#: bases and more than ``LEAN_MISS_RATE`` of the previous block's rows sent to HiGHS, only every
#: ``LEAN_EVERY``-th HiGHS basis is cached.
LEAN_MIN_BASES = 256


LEAN_MISS_RATE = 0.3


LEAN_EVERY = 8


#: Stage 1 of :meth:`DirectionSolver.solve` ranks by the most-hit bases that took this share
#: of the recent hits (at least ``TOP_MIN`` bases); rows they miss are ranked by all bases.
TOP_SHARE = 0.95


TOP_MIN = 8


#: Dual simplex (:mod:`neckstrength.wrench.simplex`) on the rows no cached basis fits: at most
#: this many pivots per row before the row goes to HiGHS, or ``SIMPLEX_ITER_PER_COLUMN`` per muscle
#: column if that is more (models with many columns need more pivots from a far basis). 0: no simplex.
SIMPLEX_MAX_ITER = 60
SIMPLEX_ITER_PER_COLUMN = 4


#: With the dual simplex on, stage 1 ranks by at most this many most-hit bases (a warm start from
#: a slightly worse basis costs a pivot or two, ranking by every cached basis costs more).
SIMPLEX_TOP_MAX = 96


#: With the dual simplex on, the double-precision ranking by all bases (stage 2) and the tie
#: checks run only while at most this many bases are cached (they resolve the ties of structured
#: candidates such as the 3-point grid for less than a simplex solve costs).
SIMPLEX_STAGE2_MAX = 256


#: ... and only for blocks of more than this many rows (0: every block). In a small block (a fit's
#: iteration: a few problems per direction) their Python overhead can exceed the simplex solves they
#: save: 64 took about 13 % less CPU on the grid fits of four gap effects (one measurement, machine
#: shared). Left at 0, the setting that the end-to-end timings and CI were measured with.
SIMPLEX_STAGE2_MIN_ROWS = 0


#: The simplex rows of a block are solved in (at least 8) parts of at least this many rows.
SIMPLEX_PART = 512


#: Bases the dual simplex found are learned into the cache: the ``SIMPLEX_LEARN_PER_BLOCK`` most
#: frequent of each block, and any basis that at least ``max(SIMPLEX_LEARN_MIN_ROWS, rows /
#: SIMPLEX_LEARN_SHARE)`` of the simplex's rows of the block ended in (building a cached basis costs
#: about as much as a hundred simplex solves, so only bases that will be hit often are worth it).
SIMPLEX_LEARN_PER_BLOCK = 2


SIMPLEX_LEARN_MIN_ROWS = 16


SIMPLEX_LEARN_SHARE = 256


#: The compiled dual simplex gets the packed arrays (basic sets, statuses, inverses) of its rows' start bases only
#: (False: of every cached basis, rebuilt whenever the cache changed, as before; the same answers: each row reads
#: its own start basis only).
SIMPLEX_PACK_STARTS = True


#: The ``'zero'`` rule of :class:`~neckstrength.wrench.problem._DirectionLP`: ``w <= ZERO_REL max(1, sum f)``.
ZERO_REL = 1e-12

#: Calls with at most this many rows do their small bookkeeping (grouping the simplex's new bases, the checks'
#: slot lookups, the hit counts) in Python: numpy's per-call overhead dominates there (most of a gap
#: diagnosis's calls have about 15 rows). The same results either way.
SMALL_ROWS = 64


_LOWER = int(highspy.HighsBasisStatus.kLower)


_BASIC = int(highspy.HighsBasisStatus.kBasic)


_UPPER = int(highspy.HighsBasisStatus.kUpper)


#: HiGHS is called from one thread at a time (``n_threads > 1`` parallelises the matrix work only).
_HIGHS_LOCK = threading.Lock()


_HASH_WEIGHTS = derive_rng(HASH_SEED, "wrench/hash_weights").integers(1, 2**62, size=4096, dtype=np.int64) | 1


_BLAS: dict = {}


def single_threaded_blas():
    """Context: numpy's BLAS on one thread (via threadpoolctl when it is installed).

    The products here are many and small to medium sized; a multi-threaded BLAS
    spends more time synchronising (and spinning) than computing. Parallelism
    comes from ``n_threads`` instead.
    """
    if "ctl" not in _BLAS:
        try:
            from threadpoolctl import ThreadpoolController

            _BLAS["ctl"] = ThreadpoolController()
        except Exception:  # noqa: BLE001 - optional
            _BLAS["ctl"] = None
    ctl = _BLAS["ctl"]
    return ctl.limit(limits=1, user_api="blas") if ctl is not None else contextlib.nullcontext()


_single_threaded_blas = single_threaded_blas


class _Basis:
    """One cached optimal basis as linear maps of ``f``.

    ``CW`` ((q + 1) x m): rows ``0..q-1`` are the primal-feasibility checks with
    the tolerance folded in (feasible iff ``CW[:q] @ f >= 0``), row ``q`` is the
    map ``f -> w``. ``dvec`` (m): the basis's dual solution as an upper bound
    ``w*(f) <= dvec . f``, valid for every ``f`` (weak duality) and tight where
    the basis is optimal. ``P`` (m x m): ``x = P @ f`` (forces), built lazily.
    """

    __slots__ = ("key", "CW", "q", "w_basic", "dvec", "status", "basic", "T", "P", "hits", "total", "Binv", "pad")

    def __init__(self, key, CW, q, w_basic, dvec, status, basic, T):
        self.key = key
        self.CW = CW
        self.q = q
        self.w_basic = w_basic
        self.dvec = dvec
        self.status = status      # per structural column (m+1): _LOWER / _UPPER / _BASIC
        self.basic = basic        # basic variable indices (structural < m+1, row logicals m+1+i)
        self.T = T                # basic variables = T @ f
        self.P = None
        self.pad = None           # slot in the packed arrays of the compiled checks (DirectionSolver._slot)
        self.hits = 1.0           # recent hits (decayed per call); the HiGHS solve that found it
        self.total = 0            # all hits


@dataclass
class DirectionStats:
    """Counters of one :class:`DirectionSolver` (cumulative over calls)."""

    solved: int = 0          # candidates answered
    cache_hits: int = 0      # answered by a cached basis
    farkas_hits: int = 0     # declared infeasible by a cached certificate
    highs_calls: int = 0     # HiGHS fallbacks
    highs_known: int = 0     # ... whose optimal basis was already cached (failed the tolerance check)
    polished: int = 0        # ... whose answer was recomputed from the (verified) basis
    bases: int = 0           # bases currently cached
    rejected_bases: int = 0  # HiGHS bases not cached (not verifiably dual feasible)
    evicted_bases: int = 0
    simplex_solved: int = 0  # answered by the compiled dual simplex (certified basis)
    simplex_failed: int = 0  # ... sent on to HiGHS (iteration limit, failed certificate, infeasible)
    simplex_pivots: int = 0  # pivots of the certified dual simplex solves
    learned_bases: int = 0   # bases the dual simplex found that were added to the cache
    bootstrap_calls: int = 0  # HiGHS calls (in highs_calls) that only found a first basis for the simplex
    start_bases: int = 0     # first rows solved by the simplex from the slack basis instead of HiGHS
    simplex_farkas: int = 0  # infeasible rows proven by a certificate from the simplex's final basis (in farkas_hits)


class DirectionSolver:
    """Cached optimal bases of the max-wrench LP for one ``(R, b, alpha_lb, alpha_ub)``.

    Use :meth:`solve` with any number of strength vectors; bases found by HiGHS
    are kept for later calls (the cache is the point: candidates near each other
    share a handful of bases). ``max_bases``: bases kept (least recently hit
    dropped first); ``decay``: factor applied to the hit counts at every call.
    """

    def __init__(self, R: np.ndarray, b: np.ndarray, lb=None, ub=None,
                 max_bases: int = 2048, decay: float = 0.5, simplex: bool = True):
        R = np.asarray(R, float)
        b = np.asarray(b, float)
        if R.ndim != 2 or b.shape != (R.shape[0],):
            raise ValueError(f"b has shape {b.shape}, R {R.shape}")
        self.n, self.m = R.shape
        self.R, self.b = R, b
        self.lb, self.ub = _bounds(self.m, lb, ub)
        A = np.hstack([R, -b[:, None]])
        A[np.abs(A) < 1e-15] = 0.0        # as the HiGHS model of _DirectionLP
        self.A = A
        self.unbounded = not np.any(b)    # as _DirectionLP.solve
        self.max_bases = int(max_bases)
        self.decay = float(decay)
        self.bases: list[_Basis] = []
        self._keys: dict[tuple, _Basis] = {}
        self.farkas: list[np.ndarray] = []   # each (m,): infeasible if f @ c < 0
        self._farkas_keys: set[bytes] = set()
        self._lp: _DirectionLP | None = None
        self.stats = DirectionStats()
        self._D: np.ndarray | None = None    # (m, len(bases)) dual bound vectors, in self.bases order
        self._D32: np.ndarray | None = None
        self._miss_rate = 1.0                # share of the rows of the last call sent to HiGHS
        self._block_miss_rate = 0.0          # ... of the last block
        # scales for the tolerances (all linear in f, so they fold into the check matrices)
        m = self.m
        self._fscale = np.full(m, 1.0 / m)                        # mean f
        bmax = float(np.max(np.abs(b))) if np.any(b) else 1.0
        self._wscale = (np.max(np.abs(R), axis=0) * self.ub / bmax / m) if self.n else np.zeros(m)
        self._Rscale = np.abs(R) * self.ub[None, :]                # torque scale of each row
        self._Acol1 = np.abs(A).sum(axis=0)
        self._absb = np.abs(b)
        # compiled dual simplex for the rows no cached basis fits (``simplex=False``: HiGHS only)
        self.simplex = bool(simplex) and _simplex is not None
        self._packed = None                  # (SB, SS): basic sets and statuses of self.bases
        self._slots = None                   # packed arrays of the compiled checks (_slot)
        self._nslots = 0
        self._slot_gen = 0
        self._learned_raw: set[bytes] = set()

    # ------------------------------------------------------------------ HiGHS side
    @property
    def lp(self) -> _DirectionLP:
        if self._lp is None:
            self._lp = _DirectionLP(self.R, self.b)
        return self._lp

    def _highs(self, f: np.ndarray, learn: bool = True):
        """One HiGHS solve; returns the result and the cached basis / certificate (or None).

        ``learn=False``: do not read and cache the basis (lean mode, ``LEAN_*`` constants).
        """
        self.stats.highs_calls += 1
        with _HIGHS_LOCK:
            lp = self.lp
            res = lp.solve(f, self.lb, self.ub)
            if res.status == "error":
                # HiGHS's answer may depend on its warm-start history; a fresh instance (as
                # max_wrench uses) settles it, and replaces the warm one
                self._lp = lp = _DirectionLP(self.R, self.b)
                res = lp.solve(f, self.lb, self.ub)
            hb = None
            if learn and res.status in ("optimal", "zero"):
                st, bv = lp.h.getBasicVariables()
                hb = (st, np.array(bv), np.array(lp.h.getSolution().col_value))
            ray = lp.h.getDualRay() if learn and res.status == "infeasible" else None
        new = None
        try:
            if hb is not None:
                new = self._add_basis(*hb, f)
            elif ray is not None:
                new = self._add_farkas(ray, f)
        except Exception:  # noqa: BLE001 - caching is an optimisation; the HiGHS answer stands
            new = None
        return res, new

    def _add_basis(self, st, bv: np.ndarray, xv: np.ndarray, f: np.ndarray):
        """Verify a HiGHS optimal basis and cache it as linear maps; returns the _Basis or None.

        ``bv``: ``Highs.getBasicVariables()`` (column index, or ``-1 - row`` for a basic row
        logical, as for rank-deficient ``R``); ``xv``: the column values, which place every
        nonbasic variable at its lower or upper bound.
        """
        n, m = self.n, self.m
        if st != highspy.HighsStatus.kOk or bv.shape != (n,) or xv.shape != (m + 1,) or \
                np.any(bv >= m + 1) or np.any(bv < -n):
            self.stats.rejected_bases += 1
            return None
        bcols = np.sort(bv[bv >= 0])
        brows = np.sort(-1 - bv[bv < 0])
        if np.unique(bcols).size != bcols.size or np.unique(brows).size != brows.size:
            self.stats.rejected_bases += 1
            return None
        col = np.full(m + 1, _LOWER, dtype=np.int64)
        lo = np.r_[self.lb * f, 0.0]
        hi = np.r_[self.ub * f, np.inf]
        col[np.abs(xv - hi) < np.abs(xv - lo)] = _UPPER
        col[bcols] = _BASIC
        return self._make_basis(bcols, brows, col, f)

    def _bootstrap_simplex(self, F, w, status, alpha, src, open_) -> bool:
        """Answer row 0 of ``F`` with the compiled simplex from the slack basis and cache its optimal
        basis (the slack basis itself is dropped again). False if that did not give a basis."""
        sb = self._start_basis(F[0])
        if sb is None:
            return False
        # from the slack basis every row logical but one has to leave: allow more pivots than a warm start
        # (none when SIMPLEX_MAX_ITER is 0, which switches the simplex off in tests)
        failed, _ = self._simplex_rows(F, np.array([0], dtype=np.int64), np.array([0], dtype=np.int64), [sb], w,
                                       status, alpha, src, open_,
                                       max_iter=self._max_iter() and self._max_iter() + 20 * (self.n + 1))
        if len(self.bases) > 1 or failed.size:
            self.bases.remove(sb)
            self._keys.pop(sb.key, None)
            self._D = None
            self._packed = None
            self.stats.bases = len(self.bases)
        if failed.size == 0:
            self.stats.start_bases += 1
        return bool(self.bases)

    def _start_basis(self, f: np.ndarray):
        """A dual feasible basis without HiGHS, for the dual simplex to start from: ``w`` basic in the
        row ``r0`` of the largest ``|b|``, the other rows' logicals basic. Its duals are ``y = -e_r0 /
        b_r0``, so the reduced cost of muscle force ``j`` is ``R_r0j / b_r0`` whatever ``f``: each
        nonbasic force sits at the bound that sign asks for (upper if positive). Cached like any other
        basis (:meth:`_make_basis` verifies it; it is rarely optimal itself, but the simplex starts
        from it). Returns the basis or None (then HiGHS bootstraps as before)."""
        n, m = self.n, self.m
        if n == 0 or self.unbounded:
            return None
        r0 = int(np.argmax(np.abs(self.b)))
        d = self.A[r0, :m] / self.b[r0]
        col = np.where(d > 0, _UPPER, _LOWER).astype(np.int64)
        col = np.r_[col, _BASIC]
        brows = np.array([i for i in range(n) if i != r0], dtype=np.int64)
        try:
            bb = self._make_basis(np.array([m], dtype=np.int64), brows, col, np.asarray(f, float))
        except Exception:  # noqa: BLE001 - an optimisation; HiGHS bootstraps instead
            bb = None
        return bb

    def _make_basis(self, bcols: np.ndarray, brows: np.ndarray, col: np.ndarray, f: np.ndarray):
        """Verify a basis (sorted basic columns and row logicals, per-column bound status ``col``)
        and cache it as linear maps; returns the _Basis (or the cached equal one) or None.

        The numerics (:func:`neckstrength.wrench.simplex.make_basis`, compiled) are, in order: the
        inverse of the basis matrix (1-norm condition number below ``MAX_COND``); the dual solution and
        reduced costs, with the optimal signs up to ``DUAL_TOL`` relative to ``|y|_inf |A_j|_1`` (a
        variable fixed at this ``f`` moves to the bound that keeps the basis dual feasible for every
        ``f``); the basic solution as a linear map ``T f``; the primal checks with their tolerances
        (``PRIMAL_TOL`` times the size of the terms), the weak-duality gap rule (``GAP_REL``) and the
        dual bound ``dvec``.
        """
        n, m = self.n, self.m
        bcols = np.ascontiguousarray(bcols, dtype=np.int64)
        brows = np.ascontiguousarray(brows, dtype=np.int64)
        if bcols.size + brows.size != n:
            self.stats.rejected_bases += 1
            return None
        col = np.array(col, dtype=np.int64)
        Binv = np.empty((n, n))
        T = np.empty((n, m))
        CW = np.empty((2 * n + 3, m))
        dvec = np.empty(m)
        if _simplex is not None:
            ok, q, w_basic = _simplex.make_basis(self.A, self.lb, self.ub, self._Acol1, self._fscale, self._wscale,
                                                 self._Rscale, self.b, bcols, brows, col, np.asarray(f, float),
                                                 PRIMAL_TOL, DUAL_TOL, GAP_REL, MAX_COND, Binv, T, CW, dvec)
        else:
            ok, q, w_basic = self._make_basis_numpy(bcols, brows, col, f, Binv, T, CW, dvec)
        if not ok:
            self.stats.rejected_bases += 1
            return None
        key = (bcols.tobytes(), brows.tobytes(), col.astype(np.int8).tobytes())
        if key in self._keys:
            self._last_new = False
            self.stats.highs_known += 1
            return self._keys[key]
        self._last_new = True
        CW = CW[:q + 1].copy()
        basis = _Basis(key, CW, q, bool(w_basic), dvec, col, np.concatenate([bcols, m + 1 + brows]), T)
        basis.Binv = Binv                               # columns in the order of basis.basic
        self._keys[key] = basis
        self.bases.append(basis)
        self._D = None
        if len(self.bases) > self.max_bases:
            self.bases.sort(key=lambda bb: -bb.hits)
            for old in self.bases[self.max_bases:]:
                self._keys.pop(old.key, None)
                self.stats.evicted_bases += 1
            del self.bases[self.max_bases:]
            self._D = None
            if basis not in self.bases:
                self.stats.bases = len(self.bases)
                return None
        self.stats.bases = len(self.bases)
        return basis

    def _make_basis_numpy(self, bcols, brows, col, f, Binv, T, CW, dvec):
        """:func:`neckstrength.wrench.simplex.make_basis` in numpy (without numba; the tests' reference)."""
        n, m = self.n, self.m
        A = self.A
        nb = len(bcols)
        B = np.zeros((n, n))
        B[:, :nb] = A[:, bcols]
        B[brows, nb + np.arange(len(brows))] = -1.0     # row activity r = A z: [A, -I] (z, r) = 0
        # numpy (not scipy) linear algebra: scipy ships its own OpenBLAS, whose threads fight
        # numpy's for the cores right after the big matrix products
        try:
            Bi = np.linalg.inv(B)
        except np.linalg.LinAlgError:
            return False, 0, False
        if not np.all(np.isfinite(Bi)) or np.abs(B).sum(0).max() * np.abs(Bi).sum(0).max() > MAX_COND:
            return False, 0, False
        Binv[:] = Bi
        cB = np.zeros(n)
        cB[:nb] = (bcols == m).astype(float)
        y = Bi.T @ cB
        c = np.zeros(m + 1)
        c[m] = 1.0
        d = c - y @ A                                     # reduced costs (maximisation)
        # reduced costs of columns that y hardly touches are pure rounding: scale by |y|_inf |A_j|_1
        tol = DUAL_TOL * (np.max(np.abs(y)) * self._Acol1 + c)
        nonbasic = col != _BASIC
        fixed = np.r_[self.lb * f == self.ub * f, False]
        # a variable fixed at this f (f_j = 0 or lb_j = ub_j) may sit at either bound;
        # choose the bound that keeps the basis dual feasible for every f (``col`` is changed in place)
        col[nonbasic & fixed & (d > 0)] = _UPPER
        col[nonbasic & fixed & (d < 0)] = _LOWER
        bad = nonbasic & (((col == _LOWER) & (d > tol)) | ((col == _UPPER) & (d < -tol)))
        if col[m] == _UPPER or np.any(bad):
            return False, 0, False
        # basic solution as a linear map of f: nonbasic x_j = s_j f_j, basic variables = T f
        s = np.where(col[:m] == _UPPER, self.ub, self.lb)
        s[col[:m] == _BASIC] = 0.0
        T[:] = Bi @ -(A[:, :m] * s[None, :])
        if not np.all(np.isfinite(T)):
            return False, 0, False
        absT = np.abs(T)
        kx = np.flatnonzero(bcols < m)                  # basic muscle forces: lb_j f_j <= x_j <= ub_j f_j
        J = bcols[kx]
        E = np.zeros((kx.size, m))
        E[np.arange(kx.size), J] = 1.0
        tolx = PRIMAL_TOL * (absT[kx] + E + self._fscale)
        parts = [T[kx] - self.lb[J, None] * E + tolx, self.ub[J, None] * E - T[kx] + tolx]
        kw = np.flatnonzero(bcols == m)
        w_basic = kw.size == 1
        tw = T[kw[0]] if w_basic else np.zeros(m)
        if w_basic:                                     # w >= 0
            parts.append((tw + PRIMAL_TOL * (absT[kw[0]] + self._wscale))[None, :])
        # weak duality: w*(f) <= sum_j max(d_j lb_j f_j, d_j ub_j f_j) for any y with d_w <= 0;
        # a reduced cost of the wrong sign (within DUAL_TOL) at a nonbasic bound makes the basis
        # suboptimal by at most gap . f: accept f only where that is below GAP_REL * w
        dx = d[:m]
        dvec[:] = np.maximum(dx * self.lb, dx * self.ub)
        gap = np.where(col[:m] == _BASIC, 0.0, dvec - dx * s)
        if np.any(gap > 0):
            parts.append((GAP_REL * tw - gap)[None, :])
        if brows.size:                                  # basic row activities must be 0
            t = T[nb:]
            tolr = PRIMAL_TOL * (np.abs(t) + self._Rscale[brows] + np.abs(self.b[brows, None]) * self._wscale)
            parts += [t + tolr, -t + tolr]
        C = np.vstack(parts)
        q = C.shape[0]
        CW[:q] = C
        CW[q] = tw
        return True, q, w_basic

    def _add_farkas(self, dual_ray, f: np.ndarray):
        """Cache HiGHS's dual ray as an infeasibility test linear in f; returns it or None."""
        _, has, ray = dual_ray
        if not has:
            return None
        y = np.asarray(ray, float)
        if y.shape != (self.n,) or not np.all(np.isfinite(y)):
            return None
        m = self.m
        for sgn in (1.0, -1.0):
            a = sgn * (y @ self.A)                      # y^T A_j
            if a[m] > 0:                                # w >= 0 unbounded above: no certificate
                continue
            aj = a[:m]
            c = np.where(aj > 0, aj * self.ub, aj * self.lb)    # max_{box} y^T A z = c . f
            cm = c + FARKAS_MARGIN * np.abs(aj) * self.ub        # margin relative to |y^T A| f
            if f @ cm < 0:
                kb = cm.tobytes()
                if kb not in self._farkas_keys:
                    self._farkas_keys.add(kb)
                    self.farkas.append(cm)
                return cm
        return None

    # ------------------------------------------------------------------ batch side
    def _dual_matrix(self) -> np.ndarray:
        if self._D is None or self._D.shape[1] != len(self.bases):
            self._D = (np.ascontiguousarray(np.array([bb.dvec for bb in self.bases]).T) if self.bases
                       else np.zeros((self.m, 0)))
            self._D32 = None
            self._packed = None
        return self._D

    def _packed_bases(self, used: list[_Basis]):
        """Basic sets (nb x n, int64) and statuses (nb x (m+1), int8) of ``used`` for the simplex."""
        if self._packed is None or self._packed[0].shape[0] != len(used):
            SB = np.array([bb.basic for bb in used], dtype=np.int64).reshape(len(used), self.n)
            SS = np.array([bb.status for bb in used], dtype=np.int8).reshape(len(used), self.m + 1)
            SBinv = np.array([bb.Binv for bb in used], dtype=float).reshape(len(used), self.n, self.n)
            self._packed = (SB, SS, SBinv)
        return self._packed

    def _max_iter(self) -> int:
        """Pivots per simplex row (module constants read at call time, so tests can switch them)."""
        return SIMPLEX_MAX_ITER and max(SIMPLEX_MAX_ITER, SIMPLEX_ITER_PER_COLUMN * self.m)

    def _simplex_rows(self, F, rows, start, used, w, status, alpha, src, open_, max_iter: int | None = None):
        """Compiled dual simplex for ``rows`` warm-started from ``used[start]``; certified rows are
        answered (``src = -3``) and their new bases learned. Returns the rows left for HiGHS and
        the newly cached bases. ``max_iter``: pivots per row (default :meth:`_max_iter`)."""
        n, m = self.n, self.m
        R = rows.size
        if SIMPLEX_PACK_STARTS and len(used) > 1:
            # the arrays of the rows' start bases only (a call's misses start from a few of the cached bases)
            u, start = np.unique(start, return_inverse=True)
            sub = [used[i] for i in u.tolist()]
            SB = np.array([bb.basic for bb in sub], dtype=np.int64).reshape(len(sub), n)
            SS = np.array([bb.status for bb in sub], dtype=np.int8).reshape(len(sub), m + 1)
            SBinv = np.array([bb.Binv for bb in sub], dtype=float).reshape(len(sub), n, n)
        else:
            SB, SS, SBinv = self._packed_bases(used)
        want = alpha is not None
        out_w = np.zeros(R)
        out_code = np.empty(R, dtype=np.int8)
        out_basic = np.empty((R, n), dtype=np.int64)
        out_status = np.empty((R, m + 1), dtype=np.int8)
        out_alpha = np.empty((R if want else 1, m))
        out_piv = np.empty(R, dtype=np.int64)
        _simplex.solve_rows(self.A, self.lb, self.ub, self._Acol1, self._wscale, self._Rscale, self._absb, F,
                            rows.astype(np.int64), start.astype(np.int64), SB, SS, SBinv,
                            self._max_iter() if max_iter is None else int(max_iter), PRIMAL_TOL,
                            DUAL_TOL, GAP_REL, MAX_COND, want, out_w, out_code, out_basic, out_status,
                            out_alpha if want else np.empty((R, m)), out_piv)
        cert = out_code == _simplex.CERTIFIED
        sus = np.flatnonzero(out_code == _simplex.INFEASIBLE_SUSPECT)
        proven = np.zeros(R, bool)
        if sus.size:
            # the ratio test found no entering variable: a row of the final basis inverse is a Farkas ray
            # candidate; a row is answered only where a certificate (cached, or one of these verified by
            # _add_farkas) proves it infeasible, the others go on to HiGHS as before
            proven[sus] = self._prove_infeasible(F, rows[sus], out_basic[sus])
            g = rows[proven]
            status[g] = _INF
            src[g] = -2
            open_[g] = False
            if want:
                alpha[g] = np.nan
            self.stats.farkas_hits += int(g.size)
            self.stats.simplex_farkas += int(g.size)
        g = rows[cert]
        w[g] = out_w[cert]
        status[g] = _OPT
        src[g] = -3
        open_[g] = False
        if want:
            alpha[g] = out_alpha[cert]
        nc = int(cert.sum())
        self.stats.simplex_solved += nc
        self.stats.simplex_failed += R - nc
        self.stats.simplex_pivots += int(out_piv[cert].sum())
        new = self._learn(out_basic[cert], out_status[cert], F[g]) if nc else []
        return rows[~cert & ~proven], new

    def _prove_infeasible(self, F: np.ndarray, rows: np.ndarray, basic: np.ndarray) -> np.ndarray:
        """Which of ``rows`` a Farkas certificate proves infeasible: the cached ones first, then the rows of
        the inverse of each row's final simplex basis (``basic``), each verified and cached by
        :meth:`_add_farkas` (the test is exact: ``f @ c < 0`` with its margin)."""
        n, m = self.n, self.m
        out = np.zeros(rows.size, bool)
        for t, i in enumerate(rows):
            f = F[i]
            if any(float(f @ cm) < 0 for cm in self.farkas):
                out[t] = True
                continue
            B = np.zeros((n, n))
            for k, j in enumerate(basic[t]):
                if j <= m:
                    B[:, k] = self.A[:, j]
                else:
                    B[j - m - 1, k] = -1.0
            try:
                Binv = np.linalg.inv(B)
            except np.linalg.LinAlgError:
                continue
            for r in range(n):
                if not np.all(np.isfinite(Binv[r])):
                    continue
                cm = self._add_farkas((None, True, Binv[r]), f)
                if cm is not None and float(f @ cm) < 0:
                    out[t] = True
                    break
        return out

    def _learn(self, basic: np.ndarray, stat: np.ndarray, F: np.ndarray) -> None:
        """Cache the most frequent new bases among the simplex's certified final bases; returns them."""
        n = self.n
        keyarr = np.concatenate([np.sort(basic, axis=1), stat.astype(np.int64)], axis=1)
        # group equal bases by a hash of the row (a collision only changes which bases are tried;
        # every basis is built from an actual row and verified)
        h = keyarr @ _HASH_WEIGHTS[:keyarr.shape[1]]
        if h.size > SMALL_ROWS:
            _, first, counts = np.unique(h, return_index=True, return_counts=True)
            order = np.argsort(-counts, kind="stable")
        else:
            # the same groups and order without numpy's per-call overhead (most calls have a few rows):
            # hashes ascending, each with its first row and count; then by count, stable
            grp: dict[int, list[int]] = {}
            for i, v in enumerate(h.tolist()):
                g = grp.get(v)
                if g is None:
                    grp[v] = [i, 1]
                else:
                    g[1] += 1
            first, counts = zip(*(grp[v] for v in sorted(grp)))
            order = sorted(range(len(counts)), key=lambda u: -counts[u])
        learned = 0
        new = []
        min_rows = max(SIMPLEX_LEARN_MIN_ROWS, basic.shape[0] / SIMPLEX_LEARN_SHARE)
        for u in order:
            if learned >= SIMPLEX_LEARN_PER_BLOCK and counts[u] < min_rows:
                break
            row = keyarr[first[u]]
            raw = row.tobytes()
            if raw in self._learned_raw:
                continue
            self._learned_raw.add(raw)
            if len(self._learned_raw) > 8 * self.max_bases:
                self._learned_raw.clear()
            bset = row[:n]
            bcols = bset[bset <= self.m]
            brows = bset[bset > self.m] - (self.m + 1)
            col = row[n:].astype(np.int64)
            try:
                bb = self._make_basis(bcols, brows, col, F[first[u]])
            except Exception:  # noqa: BLE001 - caching is an optimisation
                bb = None
            if bb is not None and self._last_new:
                bb.hits = float(counts[u])
                new.append(bb)
                learned += 1
                self.stats.learned_bases += 1
        return [bb for bb in new if bb.key in self._keys]      # not evicted meanwhile

    def _dual_matrix32(self) -> np.ndarray:
        D = self._dual_matrix()
        if self._D32 is None:
            self._D32 = D.astype(np.float32)
        return self._D32

    def solve(self, F: np.ndarray, return_alpha: bool = False, fmax: float | None = None,
              F32: np.ndarray | None = None):
        """Solve for every row of ``F`` (N x m, strengths >= 0).

        Returns ``w`` (N), integer ``status`` (N, :data:`STATUS_CODES`) and, if
        ``return_alpha``, ``alpha`` (N x m), else None. ``fmax`` (``F.max()``) and
        ``F32`` (``F`` in single precision, for the ranking) if the caller has them.

        1. Every cached basis's dual solution bounds ``w*(f)`` from above by
           ``dvec . f`` (weak duality), with equality for the optimal basis: one
           matrix product ``F @ D`` ranks the cached bases for every row (first
           in single precision by the most-hit bases, then in double precision
           by all of them for the rows that failed), and each row's primal
           check is run for its best-ranked basis only.
        2. Rows that fail (ties between bases, or no optimal basis cached) are
           checked against the other bases whose bound ties with the best.
        3. Cached Farkas certificates mark infeasible rows.
        4. The rest go to HiGHS one at a time; each new basis is then checked
           against the still-open rows where its bound does not exceed theirs.
        """
        F = np.atleast_2d(np.asarray(F, dtype=float))
        if F.ndim != 2 or F.shape[1] != self.m:
            raise ValueError(f"F has shape {F.shape}, expected (N, {self.m})")
        if not np.all(np.isfinite(F)) or np.any(F < 0):
            raise ValueError("strengths must be finite and non-negative")
        with _single_threaded_blas():
            return self._solve(F, return_alpha, fmax, F32)

    def _solve(self, F, return_alpha=False, fmax=None, F32=None):
        F = np.ascontiguousarray(F, dtype=float)
        N, m = F.shape
        w = np.zeros(N)
        status = np.zeros(N, dtype=np.int8)
        alpha = np.empty((N, m)) if return_alpha else None
        self.stats.solved += N
        if N == 0:
            return w, status, alpha
        if self.unbounded:
            w[:] = np.inf
            status[:] = _UNB
            if return_alpha:
                alpha[:] = np.nan
            return w, status, alpha
        for bb in self.bases:
            bb.hits *= self.decay
        self.bases.sort(key=lambda bb: -bb.hits)
        self._D = None
        fmax = float(F.max()) if fmax is None else float(fmax)
        F32 = F.astype(np.float32) if F32 is None else F32
        # blocks of growing size: the first rows discover the bases cheaply (each new basis
        # is checked against the open rows of its block), the later ones mostly hit the cache;
        # one block when the last call hardly needed HiGHS
        # rows sent to HiGHS (not those of the dual simplex, which learns its bases part by part inside a block)
        calls = self.stats.highs_calls
        s0, size = 0, (N if self.bases and self._miss_rate < WARM_MISS_RATE else BLOCK_START)
        while s0 < N:
            e = min(N, s0 + size)
            if N - e < size // 2:
                e = N
            c0 = self.stats.highs_calls
            self._solve_block(F[s0:e], F32[s0:e], w[s0:e], status[s0:e],
                              None if alpha is None else alpha[s0:e], fmax)
            self._block_miss_rate = (self.stats.highs_calls - c0) / (e - s0)
            s0 = e
            size *= 2
        self._miss_rate = (self.stats.highs_calls - calls) / N
        return w, status, alpha

    def _solve_block(self, F, F32, w, status, alpha, fmax):
        """:meth:`solve` for one block of rows; writes into the output views."""
        N, m = F.shape
        return_alpha = alpha is not None
        used = list(self.bases)                   # src[i] >= 0: answered by used[src[i]]
        src = np.full(N, -1, dtype=np.int64)      # -1: open, -2: HiGHS or certificate
        open_ = np.ones(N, bool)
        alpha_done = np.zeros(N, bool)            # activations already written (compiled stage 1)
        ubest = np.full(N, np.inf)                # best (smallest) cached dual bound per open row
        floor = ZERO_REL * max(1.0, fmax * m)     # >= the 'zero' threshold of every row
        simplex = self.simplex
        if simplex and not self.bases:
            # bootstrap: the dual simplex needs one dual feasible basis. The first row is solved by the
            # simplex from the slack basis (:meth:`_start_basis`), whose optimal basis then serves the
            # block; where that fails, HiGHS finds one (the rows themselves are answered below)
            if not self._bootstrap_simplex(F, w, status, alpha, src, open_):
                for i in range(min(N, 4)):
                    self.stats.bootstrap_calls += 1
                    self._highs(F[i])
                    if self.bases:
                        break
            used = list(self.bases)

        def infeasible(g: np.ndarray) -> None:
            """Rows ``g`` declared infeasible by a Farkas certificate (cached or just learned)."""
            status[g] = _INF
            src[g] = -2
            open_[g] = False
            self.stats.farkas_hits += int(g.size)
            if return_alpha:
                alpha[g] = np.nan

        def accept(bb_index: int, rows: np.ndarray) -> int:
            bb = used[bb_index]
            idx, wv = self._try(bb, F, rows)
            if idx.size:
                g = rows[idx]
                w[g] = wv
                src[g] = bb_index
                open_[g] = False
                bb.hits += idx.size
                bb.total += idx.size
            return idx.size

        nb = len(used)
        rem = np.arange(N) if open_.all() else np.flatnonzero(open_)   # row 0 may be answered by the bootstrap
        if nb:
            D = self._dual_matrix()
            hits = np.cumsum([bb.hits for bb in used])
            k = int(np.searchsorted(hits, TOP_SHARE * hits[-1])) + 1
            k = min(nb, max(k, TOP_MIN))
            stage2 = not simplex or (nb <= SIMPLEX_STAGE2_MAX and N > SIMPLEX_STAGE2_MIN_ROWS)
            if simplex:
                k = min(k, SIMPLEX_TOP_MAX)
            label = np.full(N, -1, dtype=np.int16 if nb < 32768 else np.int64)
            # stage 1 in single precision over the most-hit bases (it only picks the basis to
            # check; a wrong pick in a near-tie fails the exact check), stage 2 in double
            # precision over all bases for the rows that failed
            for kk, single in ((k, True), (nb, False)) if stage2 else ((k, True),):
                if rem.size == 0:
                    break
                Dk = self._dual_matrix32()[:, :kk] if single else D
                Fs = F32 if single else F
                step = max(1, (1 << 21) // kk)
                for s0 in range(0, rem.size, step):
                    r = rem[s0:s0 + step]
                    V = (Fs[s0:s0 + step] if rem.size == N else Fs[r]) @ Dk
                    label[r] = V.argmin(axis=1)       # int16: radix sort below
                lab = label[rem]
                if simplex:
                    # compiled: every row against its own best-ranked basis (and its activations)
                    ok = self._check_compiled(F, rem, lab, used[:kk], 0, w, alpha, alpha_done, src, open_)
                    rem = rem[~ok]
                    continue
                order = np.argsort(lab, kind="stable")
                counts = np.bincount(lab, minlength=kk)
                ends = np.cumsum(counts)
                for bi in np.flatnonzero(counts):
                    accept(int(bi), rem[order[ends[bi] - counts[bi]:ends[bi]]])
                rem = rem[open_[rem]]
            if rem.size:
                ubest[rem] = np.einsum("ij,ji->i", F[rem], D[:, label[rem]])
            if rem.size and nb > 1 and stage2:
                # ties: any other basis whose bound is (numerically) as small is a candidate
                Fr = F[rem]
                thr = ubest[rem] + TIE_REL * (np.abs(ubest[rem]) + floor)
                step = max(1, (1 << 21) // nb)
                for s0 in range(0, rem.size, step):
                    blk = slice(s0, s0 + step)
                    cand = (Fr[blk] @ D) <= thr[blk, None]
                    cand[np.arange(cand.shape[0]), label[rem[blk]]] = False
                    if simplex:
                        # compiled: every (row, tied basis) pair; each row takes its first passing basis
                        # in order of recent hits
                        pr, pb = np.nonzero(cand)
                        if pr.size:
                            rows = rem[blk][pr]
                            ok, ww, aa = self._check_pairs(F, rows, pb, used[:nb], alpha is not None)
                            sel = np.flatnonzero(ok)
                            sel = sel[np.unique(rows[sel], return_index=True)[1]]
                            self._close(rows[sel], pb[sel], used[:nb], 0, ww[sel], aa[sel] if alpha is not None
                                        else None, w, alpha, alpha_done, src, open_)
                        continue
                    for bi in np.flatnonzero(cand.any(axis=0)):     # in order of recent hits
                        rows = rem[blk][cand[:, bi]]
                        rows = rows[open_[rows]]
                        if rows.size:
                            accept(int(bi), rows)
                rem = rem[open_[rem]]
            # misses in order of their best cached basis: consecutive HiGHS solves are then
            # near each other, and each warm start is close to the next optimum
            rem = rem[np.argsort(label[rem], kind="stable")]
        self.stats.cache_hits += int(np.count_nonzero(src >= 0))
        # cached Farkas certificates
        if rem.size and self.farkas:
            Fr = F[rem]
            inf = np.zeros(rem.size, bool)
            for cm in self.farkas:
                inf |= Fr @ cm < 0
            if inf.any():
                infeasible(rem[inf])
                rem = rem[~inf]
        if rem.size and simplex and nb:
            # the compiled dual simplex, warm-started from each row's best-ranked basis, in parts:
            # the bases learned from one part are tried on the open rows of the next ones
            left = []
            step = max(SIMPLEX_PART, -(-rem.size // 8))
            pos = 0
            while pos < rem.size:
                part = rem[pos:pos + step]
                pos += step
                part = part[open_[part]]
                if part.size == 0:
                    continue
                failed, new = self._simplex_rows(F, part, label[part], used[:nb], w, status, alpha, src, open_)
                left.append(failed)
                rest = rem[pos:]
                rest = rest[open_[rest]]
                if new and rest.size:
                    # each open row tries the new basis with the smallest dual bound, if that
                    # bound does not exceed its best cached one
                    i0 = len(used)
                    used.extend(new)
                    V = F[rest] @ np.array([bb.dvec for bb in new]).T
                    lab = V.argmin(axis=1)
                    u = V[np.arange(rest.size), lab]
                    thr = ubest[rest]
                    cand = u <= thr + TIE_REL * (np.abs(thr) + floor)
                    ubest[rest] = np.minimum(thr, u)
                    if cand.any():
                        ok = self._check_compiled(F, rest[cand], lab[cand], new, i0, w, alpha, alpha_done, src,
                                                  open_)
                        self.stats.cache_hits += int(ok.sum())
            rem = np.concatenate(left) if left else rem[:0]
        # HiGHS for the misses; each new basis / certificate is checked against the open rows.
        # Lean mode, when a big cache still misses most rows (many muscles, scattered candidates):
        # only every LEAN_EVERY-th HiGHS basis is read and cached, the rest cost one HiGHS call each
        lean = len(self.bases) >= LEAN_MIN_BASES and self._block_miss_rate > LEAN_MISS_RATE
        pos = 0
        while pos < rem.size:
            i = rem[pos]
            pos += 1
            if not open_[i]:
                continue
            open_[i] = False
            res, new = self._highs(F[i], learn=not lean or self.stats.highs_calls % LEAN_EVERY == 0)
            w[i] = res.w
            status[i] = _CODE[res.status]
            src[i] = -2
            if return_alpha:
                alpha[i] = res.alpha
            if new is None:
                continue
            rest = rem[pos:]
            rest = rest[open_[rest]]
            if isinstance(new, _Basis):
                u = F[rest] @ new.dvec
                thr = ubest[rest]
                cand = u <= thr + TIE_REL * (np.abs(thr) + floor)
                np.minimum(thr, u, out=thr)
                ubest[rest] = thr
                # row i too: the basis formula polishes HiGHS's own solution (exact within
                # HiGHS's tolerances only) where the basis passes the checks
                rows = np.r_[i, rest[cand]]
                if new not in used[nb:]:
                    used.append(new)
                open_[i] = True
                got = accept(len(used) - 1 if used[-1] is new else used.index(new), rows)
                if src[i] >= 0:
                    status[i] = _OPT                        # the 'zero' rule below decides
                    got -= 1
                    self.stats.polished += 1
                else:
                    open_[i] = False
                self.stats.cache_hits += got
            else:
                inf = F[rest] @ new < 0
                if inf.any():
                    infeasible(rest[inf])
            rem = rest[open_[rest]]
            pos = 0
        # statuses of the cached and simplex answers: the 'zero' rule of _DirectionLP
        cached = (src >= 0) | (src == -3)
        small = np.flatnonzero(cached & (w <= floor))
        if small.size:
            zero = small[w[small] <= ZERO_REL * np.maximum(1.0, F[small].sum(axis=1))]
            w[zero] = 0.0
            status[zero] = _ZERO
        if return_alpha:
            rest = (src >= 0) & ~alpha_done
            for bi in np.unique(src[rest]):
                g = np.flatnonzero(rest & (src == bi))
                alpha[g] = self._alpha(used[bi], F[g])

    def _alpha_map(self, bb: _Basis) -> np.ndarray:
        """``P`` (m x m) with ``x = P f`` (forces of the basic solution), built once per basis."""
        if bb.P is None:
            m = self.m
            col = bb.status[:m]
            P = np.diag(np.where(col == _UPPER, self.ub, self.lb)).astype(float)
            basic = np.asarray(bb.basic)
            k = np.flatnonzero(basic < m)
            P[basic[k]] = bb.T[k]
            bb.P = P
        return bb.P

    def _slot(self, bb: _Basis) -> int:
        """``bb``'s slot in the solver's packed arrays for the compiled checks (filled once per basis): the
        checks and the map to ``w`` (``CW``, padded to ``2 n + 3`` rows, the map to ``w`` in row ``q``),
        ``q``, whether ``w`` is basic, and the activation map ``x = P f`` of :meth:`_alpha_map` as the basis's
        ``T`` (n x m), the row of ``T`` of each basic column (-1: not basic) and each column's bound ``s_j``
        (``x_j = s_j f_j`` off the basis), so that no m x m matrix is built or copied per basis."""
        if bb.pad is not None and bb.pad[0] == self._slot_gen:
            return bb.pad[1]
        n, m = self.n, self.m
        if self._slots is None or self._nslots == self._slots[0].shape[0]:
            cap = 8 if self._slots is None else 2 * self._slots[0].shape[0]
            new = (np.zeros((cap, 2 * n + 3, m)), np.zeros(cap, dtype=np.int64), np.zeros(cap, dtype=np.bool_),
                   np.zeros((cap, n, m)), np.full((cap, m), -1, dtype=np.int64), np.zeros((cap, m)))
            if self._slots is not None:
                for x, y in zip(new, self._slots):
                    x[:self._nslots] = y[:self._nslots]
            self._slots = new
        CW, qv, wb, T3, rowk, bnd = self._slots
        i = self._nslots
        self._nslots += 1
        CW[i, :bb.q + 1] = bb.CW
        qv[i] = bb.q
        wb[i] = bb.w_basic
        # the activation map x = P f of _alpha_map without the m x m matrix: basic columns from T's rows
        T3[i] = bb.T
        basic = np.asarray(bb.basic)
        k = np.flatnonzero(basic < m)
        rowk[i] = -1
        rowk[i, basic[k]] = k
        bnd[i] = np.where(bb.status[:m] == _UPPER, self.ub, self.lb)
        bb.pad = (self._slot_gen, i)
        return i

    def _check_pairs(self, F, rows, lab, bases, want: bool):
        """:meth:`_try` of every row ``rows[t]`` against ``bases[lab[t]]`` in compiled code: (ok, w, alpha)."""
        if self._nslots + len(bases) > 4 * self.max_bases:      # evicted bases' slots: start afresh
            self._slots, self._nslots, self._slot_gen = None, 0, self._slot_gen + 1
        lab = np.asarray(lab, dtype=np.int64)
        gen = self._slot_gen
        if lab.size <= SMALL_ROWS:
            # few rows (most calls): the same slots, looked up in Python without numpy's per-call overhead
            labl = lab.tolist()
            memo = {}
            for b in sorted(set(labl)):                                  # slots of the bases these rows use only
                bb = bases[b]
                memo[b] = bb.pad[1] if bb.pad is not None and bb.pad[0] == gen else self._slot(bb)
            slot_of_row = np.array([memo[b] for b in labl], dtype=np.int64)
        else:
            uniq = np.flatnonzero(np.bincount(lab, minlength=len(bases)))   # slots of the bases these rows use only
            pos = np.empty(len(bases), dtype=np.int64)
            pos[uniq] = np.arange(uniq.size)
            slot = np.array([bb.pad[1] if bb.pad is not None and bb.pad[0] == gen else self._slot(bb)
                             for bb in map(bases.__getitem__, uniq.tolist())], dtype=np.int64)
            slot_of_row = slot[pos[lab]]
        CW3, qv, wb, T3, rowk, bnd = self._slots
        R = rows.size
        ok = np.empty(R, dtype=np.bool_)
        ww = np.empty(R)
        aa = np.empty((R if want else 1, self.m))
        _simplex.check_rows(F, rows.astype(np.int64), slot_of_row, CW3, qv, wb, T3, rowk, bnd,
                            self.lb, self.ub, want, ok, ww, aa)
        return ok, ww, aa

    @staticmethod
    def _close(g, lab, bases, offset, wv, av, w, alpha, alpha_done, src, open_) -> None:
        """Rows ``g`` answered by ``bases[lab]`` (``src = offset + lab``) with ``w`` = ``wv``, ``alpha`` = ``av``."""
        w[g] = wv
        if alpha is not None:
            alpha[g] = av
            alpha_done[g] = True
        src[g] = offset + lab
        open_[g] = False
        if len(lab) <= SMALL_ROWS:
            counts = collections.Counter(np.asarray(lab).tolist())
            pairs = sorted(counts.items())
        else:
            cnt = np.bincount(lab, minlength=len(bases))
            nz = np.flatnonzero(cnt)
            pairs = zip(nz.tolist(), cnt[nz].tolist())
        for bi, c in pairs:
            bb = bases[bi]
            bb.hits += c
            bb.total += c

    def _check_compiled(self, F, rows, lab, bases, offset, w, alpha, alpha_done, src, open_) -> np.ndarray:
        """:meth:`_check_pairs`, then the rows that pass get ``w`` (and ``alpha``), ``src = offset + lab``
        and are closed; returns their mask."""
        want = alpha is not None
        ok, ww, aa = self._check_pairs(F, rows, lab, bases, want)
        self._close(rows[ok], np.asarray(lab)[ok].astype(np.int64), bases, offset, ww[ok], aa[ok] if want else None,
                    w, alpha, alpha_done, src, open_)
        return ok

    def _try(self, bb: _Basis, F: np.ndarray, rows: np.ndarray):
        """Positions in ``rows`` of the rows of ``F`` for which ``bb`` is optimal, and their w."""
        # the whole block without a copy only when ``rows`` is the identity: after a HiGHS solve the rows
        # arrive as [solved row, other open rows], a permutation of the block when every row is open
        identity = rows.size == F.shape[0] and bool(np.all(rows == np.arange(rows.size)))
        Fr = F if identity else F[rows]
        S = bb.CW @ Fr.T                               # (q + 1, rows): checks, then w
        q = bb.q
        if q:
            idx = np.flatnonzero(S[:q].min(axis=0) >= 0.0)
        else:
            idx = np.arange(Fr.shape[0])
        wv = np.maximum(S[q, idx], 0.0) if bb.w_basic else np.zeros(idx.size)
        return idx, wv

    def _alpha(self, bb: _Basis, F: np.ndarray) -> np.ndarray:
        """Activations of the basic solution (``lb`` where ``f = 0``, clipped as in maxwrench)."""
        X = F @ self._alpha_map(bb).T
        with np.errstate(divide="ignore", invalid="ignore"):
            alpha = np.where(F > 0, X / np.where(F > 0, F, 1.0), self.lb[None, :])
        return np.clip(alpha, self.lb[None, :], self.ub[None, :])


class BasisCache:
    """Reusable cache of :class:`DirectionSolver` objects, keyed by ``(R, b, alpha_lb, alpha_ub)``.

    Keep one across calls (e.g. the iterations of an ABC estimator): candidate
    strength vectors near earlier ones are then answered from cached bases
    without HiGHS. ``max_bases``: bases kept per key (least recently hit
    dropped first); ``max_entries``: keys kept (oldest dropped first); ``simplex``: solve cache
    misses with the compiled dual simplex (default; False: HiGHS for every miss, as before).
    """

    def __init__(self, max_bases: int = 2048, max_entries: int = 4096, decay: float = 0.5, simplex: bool = True,
                 fused: bool = False):
        self.simplex = simplex
        self.max_bases = max_bases
        self.max_entries = max_entries
        self.decay = decay
        self._entries: dict[tuple, DirectionSolver] = {}
        # fused: calls of at most FUSED_MAX_ROWS rows go through the compiled all-direction pass
        # (neckstrength.wrench.fused) first; its misses come back to the DirectionSolvers
        self.fused = bool(fused) and simplex and _simplex is not None
        self._stores: dict[bytes, object] = {}

    @staticmethod
    def _rkey(R: np.ndarray) -> bytes:
        R = np.ascontiguousarray(R, dtype=float)
        return hashlib.blake2b(R.tobytes(), digest_size=16).digest() + repr(R.shape).encode()

    def entry(self, R: np.ndarray, b: np.ndarray, lb: np.ndarray, ub: np.ndarray,
              rkey: bytes | None = None) -> DirectionSolver:
        """The solver for one direction (``b = J^T u``) and activation-bound vector (``rkey``: ``_rkey(R)``
        if the caller has it)."""
        b = np.ascontiguousarray(b, dtype=float)
        lb = np.ascontiguousarray(lb, dtype=float)
        ub = np.ascontiguousarray(ub, dtype=float)
        key = (self._rkey(R) if rkey is None else rkey, b.tobytes(), lb.tobytes(), ub.tobytes())
        e = self._entries.get(key)
        if e is None:
            e = DirectionSolver(R, b, lb, ub, self.max_bases, self.decay, self.simplex)
            self._entries[key] = e
            if len(self._entries) > self.max_entries:
                self._entries.pop(next(iter(self._entries)))
        return e

    def __len__(self) -> int:
        return len(self._entries)

    def entries(self) -> list[DirectionSolver]:
        return list(self._entries.values())

    def stats(self) -> dict[str, int]:
        """Summed :class:`DirectionStats` over all keys, plus the number of keys."""
        tot = DirectionStats()
        for e in self._entries.values():
            for k, v in vars(e.stats).items():
                setattr(tot, k, getattr(tot, k) + v)
        out = dict(vars(tot))
        out["entries"] = len(self._entries)
        fc = sum((st.counters for st in self._stores.values()), np.zeros(6, dtype=np.int64))
        for name, v in zip(("fused_cache_hits", "fused_simplex_solved", "fused_simplex_pivots", "fused_learned_bases",
                            "fused_farkas_hits", "fused_failed"), fc.tolist()):
            out[name] = v
        return out

    def clear(self) -> None:
        self._entries.clear()
        self._stores.clear()

    def store(self, R: np.ndarray, rkey: bytes):
        """The compiled all-direction cache (:class:`neckstrength.wrench.fused.FusedStore`) of ``R``."""
        st = self._stores.get(rkey)
        if st is None:
            from neckstrength.wrench.fused import FusedStore

            st = self._stores[rkey] = FusedStore(R)
        return st


def _bound_rows(K: int, m: int, alpha_lb, alpha_ub) -> tuple[np.ndarray, np.ndarray]:
    """(K x m) activation bounds, checked as :func:`neckstrength.wrench.problem._bounds` checks one row."""
    lbs = np.broadcast_to(np.zeros(m) if alpha_lb is None else np.asarray(alpha_lb, float), (K, m)).copy()
    ubs = np.broadcast_to(np.ones(m) if alpha_ub is None else np.asarray(alpha_ub, float), (K, m)).copy()
    if np.any(lbs < 0) or np.any(ubs > 1) or np.any(lbs > ubs):
        raise ValueError("activation bounds must satisfy 0 <= alpha_lb <= alpha_ub <= 1")
    return lbs, ubs


def max_wrench_batched_arrays(R: np.ndarray, JT: np.ndarray, F: np.ndarray, U: np.ndarray,
                              alpha_lb=None, alpha_ub=None, *, chunk_size: int = 65536,
                              cache: BasisCache | None = None, return_alpha: bool = True,
                              n_threads: int = 1):
    """Max wrench for every strength vector in ``F`` (N x m) and unit wrench in ``U`` (K x d).

    ``R`` (n x m) moment arms, ``JT`` (n x d). ``alpha_lb``/``alpha_ub``: None,
    (m,) or (K, m). Returns ``w`` (N x K), ``alpha`` (N x K x m, or None if
    ``return_alpha`` is False) and int8 ``status`` (N x K, :data:`STATUS_CODES`),
    exactly as :func:`neckstrength.wrench.highs.max_wrench_batch`. ``F`` is
    processed ``chunk_size`` rows at a time, so temporary memory is bounded by
    the chunk; pass a :class:`BasisCache` to keep the bases for later calls.
    ``n_threads``: directions solved concurrently (numpy's BLAS runs
    single-threaded inside this call either way; HiGHS calls are serialised).
    Raises ``ValueError`` (before solving anything) on bad shapes, bounds or
    negative / non-finite strengths; never in the middle of a batch.
    """
    R = np.asarray(R, float)
    JT = np.asarray(JT, float)
    F = np.atleast_2d(np.asarray(F, float))
    U = np.atleast_2d(np.asarray(U, float))
    N, m = F.shape
    K = U.shape[0]
    if R.ndim != 2 or R.shape[1] != m:
        raise ValueError(f"F has {m} columns, R is {R.shape}")
    if JT.ndim != 2 or JT.shape[0] != R.shape[0] or U.shape[1] != JT.shape[1]:
        raise ValueError(f"shapes do not match: R {R.shape}, JT {JT.shape}, U {U.shape}")
    if not np.all(np.isfinite(F)) or np.any(F < 0):
        raise ValueError("strengths must be finite and non-negative")
    lbs, ubs = _bound_rows(K, m, alpha_lb, alpha_ub)
    cache = BasisCache() if cache is None else cache
    chunk_size = max(1, int(chunk_size))
    w = np.zeros((N, K))
    status = np.zeros((N, K), dtype=np.int8)
    alpha = np.empty((N, K, m)) if return_alpha else None    # every row is written below
    rkey = BasisCache._rkey(R)
    if cache.fused and 0 < N <= FUSED_MAX_ROWS and R.shape[0] > 0:
        return _fused_call(cache, R, JT, F, U, lbs, ubs, rkey, return_alpha)
    solvers = [cache.entry(R, JT @ U[k], lbs[k], ubs[k], rkey) for k in range(K)]
    n_threads = max(1, min(int(n_threads), K))

    def run(k: int, s: int, e: int, Fc: np.ndarray, fmax: float, Fc32: np.ndarray) -> None:
        wk, sk, ak = solvers[k]._solve(Fc, return_alpha, fmax=fmax, F32=Fc32)
        w[s:e, k] = wk
        status[s:e, k] = sk
        if return_alpha:
            alpha[s:e, k] = ak

    with _single_threaded_blas(), (ThreadPoolExecutor(n_threads) if n_threads > 1
                                   else contextlib.nullcontext()) as pool:
        for s in range(0, N, chunk_size):
            e = min(N, s + chunk_size)
            Fc = np.ascontiguousarray(F[s:e])
            fmax = float(Fc.max()) if Fc.size else 0.0
            Fc32 = Fc.astype(np.float32)
            if pool is None:
                for k in range(K):
                    run(k, s, e, Fc, fmax, Fc32)
            else:
                list(pool.map(run, range(K), *([x] * K for x in (s, e, Fc, fmax, Fc32))))
    return w, alpha, status


#: Calls with at most this many strength vectors use the compiled all-direction pass when the cache has
#: ``fused=True`` (larger calls amortise the per-direction solvers' bookkeeping over their rows). The calibration's
#: screen (hundreds of rows per call) gains from the pass too: a calibrated participant (S003) took 123.6 s CPU with
#: 256 here against 115.3 s with 4,096 and 166.8 s without the pass.
FUSED_MAX_ROWS = 4096


def _fused_call(cache: BasisCache, R, JT, F, U, lbs, ubs, rkey, return_alpha):
    """:func:`max_wrench_batched_arrays` through :mod:`neckstrength.wrench.fused`; the rows and directions it does
    not certify go to the per-direction solvers (and so to HiGHS), whose bases and Farkas certificates it then
    takes over."""
    from neckstrength.wrench import fused as _fz

    st = cache.store(R, rkey)
    K = U.shape[0]
    U = np.ascontiguousarray(U, dtype=float)
    ckey = U.tobytes() + JT.tobytes() + lbs.tobytes() + ubs.tobytes()    # the same directions as a recent call?
    hit = st.calls.get(ckey)
    if hit is None:
        Bv = [JT @ U[k] for k in range(K)]        # b = J^T u, rounded as the per-direction path does
        slots = np.array([st.slot(Bv[k], lbs[k], ubs[k]) for k in range(K)], dtype=np.int64)
        if len(st.calls) >= 64:
            st.calls.pop(next(iter(st.calls)))
        st.calls[ckey] = (Bv, slots)
    else:
        Bv, slots = hit
    F = np.ascontiguousarray(F, dtype=float)
    w, code, alpha = st.solve(F, slots, return_alpha, (SIMPLEX_MAX_ITER and
                                                       max(SIMPLEX_MAX_ITER, SIMPLEX_ITER_PER_COLUMN * R.shape[1])),
                              (PRIMAL_TOL, DUAL_TOL, GAP_REL, MAX_COND), ZERO_REL, cache.decay)
    status = np.empty(code.shape, dtype=np.int8)
    status[code == _fz.OK] = _OPT
    status[code == _fz.ZERO] = _ZERO
    status[code == _fz.INFEASIBLE] = _INF
    status[code == _fz.UNBOUNDED] = _UNB
    if return_alpha:
        alpha[(code == _fz.INFEASIBLE) | (code == _fz.UNBOUNDED)] = np.nan
    bad = code == _fz.FAILED
    if bad.any():
        for k in np.flatnonzero(bad.any(axis=0)):
            rows = np.flatnonzero(bad[:, k])
            e = cache.entry(R, Bv[k], lbs[k], ubs[k], rkey)
            with _single_threaded_blas():
                wk, sk, ak = e._solve(F[rows], return_alpha)
            w[rows, k] = wk
            status[rows, k] = sk
            if return_alpha:
                alpha[rows, k] = ak
            st.add_farkas(int(slots[k]), e.farkas)
            st.adopt(int(slots[k]), e.bases, F[rows[0]])
    return w, alpha, status


def max_wrench_batched(model: ReducedModel, F: np.ndarray, U: np.ndarray,
                       alpha_lb: np.ndarray | None = None, alpha_ub: np.ndarray | None = None, *,
                       chunk_size: int = 65536, cache: BasisCache | None = None, return_alpha: bool = True,
                       n_threads: int = 1):
    """Drop-in for :func:`neckstrength.wrench.highs.max_wrench_batch`: exact, and much faster.

    Returns ``w`` (N x K), ``alpha`` (N x K x m; None if ``return_alpha=False``)
    and ``status`` (N x K int8, :data:`STATUS_CODES`). See
    :func:`max_wrench_batched_arrays` for the options.
    """
    F = np.atleast_2d(np.asarray(F, float))
    U = np.atleast_2d(np.asarray(U, float))
    if F.shape[1] != model.m:
        raise ValueError(f"F has {F.shape[1]} columns, model {model.name} has {model.m} muscles")
    if U.shape[1] != model.JT.shape[1]:
        raise ValueError(f"U has {U.shape[1]} components, model task space has {model.JT.shape[1]}")
    return max_wrench_batched_arrays(model.moment_arms, model.JT, F, U, alpha_lb, alpha_ub,
                                     chunk_size=chunk_size, cache=cache, return_alpha=return_alpha,
                                     n_threads=n_threads)
