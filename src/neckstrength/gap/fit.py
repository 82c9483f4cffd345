"""Fitting free strengths (for fixed effect parameters) to measured maximum forces.

Loss of one problem (a data set restricted to its training directions):

    L(phi) = sum_k w_k (F_k(phi) / F_meas,k - 1)^2 + ridge * |phi - phi_0|^2,    f = exp(phi)[pidx]

with ``F_k`` the predicted maximum force of test k (the exact max-wrench LP, Eq. 4.1 / 5.2, solved by
:func:`neckstrength.wrench.solve`), ``w_k`` = 1 for training and 0 for held-out directions,
``phi`` the log free strengths (left and right tied where the Chapter 5 settings tie them) within
``bounds_rel`` x the start, and a weak ridge towards the start ``phi_0`` (the baseline strengths scaled to
the training forces, the analogue of Eq. 5.3) that only decides strengths the training directions leave
undetermined. The relative residual is the quantity inside Eq. 5.5.

The minimiser is Levenberg-Marquardt with forward-difference Jacobians, vectorised over many problems
(cross-validation folds, data sets, benchmark cases) that share one model instance: each iteration is two
calls of the batched exact solver, one with every problem's Jacobian perturbations, one with three
damping trials per problem. The max force is piecewise linear and concave in the strengths, so the
Gauss-Newton model is exact inside each linear piece; the damping trials handle the kinks.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from neckstrength.estimation.parameters import free_parameters
from neckstrength.gap.effects import GapContext, Instance
from neckstrength.wrench import solve
from neckstrength.wrench.batched import single_threaded_blas
from neckstrength.wrench.problem import STATUS_CODES

_OPT = {v: k for k, v in STATUS_CODES.items()}["optimal"]


def _one_blas_thread(fn):
    """Run ``fn`` with numpy's BLAS on one thread: the fits' products are many and small, and on 2 cores a
    multi-threaded BLAS spends about as much CPU synchronising as computing (one Jacobian evaluation of 72
    strength vectors: 30 ms CPU multi-threaded, 14 ms on one thread)."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with single_threaded_blas():
            return fn(*args, **kwargs)
    return wrapper


@dataclass(frozen=True)
class FitSettings:
    max_iter: int = 30
    ridge: float = 1e-3
    bounds_rel: tuple[float, float] = (0.05, 20.0)
    fd_step: float = 1e-3
    tol: float = 1e-6
    lambda0: float = 1e-2
    chunk_size: int = 65536
    exact_gradient: bool = True


#: True (default): the fits' calls (a few strength vectors times every direction) go through the compiled
#: all-direction pass of :mod:`neckstrength.wrench.fused` (``benchmarks/bench_gap.py --fused`` times it against the
#: per-direction batched solver, False). Both return certified optimal forces; where the optimum is not unique they may
#: return different optimal activations, but the exact Jacobians below do not depend on which (the columns in which two
#: optimal vertices differ have ``lam . R_j = 0``; tests/gap/test_fused_fits.py). The fused pass takes, for each row,
#: the cached basis with the smallest dual bound (not the previous row's), so a row's answer does not depend on the
#: rows before it; the batch-independence and resume tests of tests/gap/test_calibrate.py run with it.
FUSED_SOLVER = True


def make_cache(max_bases: int = 512):
    """A basis cache for the batched solver (None when only the reference solver is available).

    Few bases per direction: the fits move through a small neighbourhood, and a cache per model instance
    is dropped with it, which bounds memory."""
    try:
        from neckstrength.wrench.batched import BasisCache
    except ImportError:  # pragma: no cover
        return None
    return BasisCache(max_bases=max_bases, max_entries=100_000, fused=FUSED_SOLVER)


class Simulator:
    """Predicted maximum forces (N) of an :class:`Instance` for base-model strength vectors.

    ``pidx`` maps model muscles to free parameters (:func:`neckstrength.abc.free_parameters`).
    With several candidate wrenches per test (J > 1) the fit works on an *active set* of candidates
    (initially the target; :meth:`refresh` adds every candidate that is the maximum for some strength
    vector), so that an iteration solves few LPs (:meth:`forces_phi`, used by the fit); :meth:`run` and
    :meth:`forces` evaluate all J unless ``active_only``.

    With :meth:`refresh_rows` each *owner* (the engine: a data set) has its own active set (``row_active``;
    the force methods take ``owner``, the owner of each strength vector): its forces are the maximum over
    *its* active candidates, so its fits do not depend on which other data sets are fitted with it. The LPs
    solved are those of the union of the sets (``active``); the other owners' candidates are solved but not
    used. Without ``owner`` the union is used (one data set, or callers that fit a fixed set of rows).

    With a matching window (``inst.window``, :mod:`neckstrength.gap.window`) the forces of :meth:`forces`,
    :meth:`forces_all` and the refreshes are the maxima over each test's whole window (certified within its
    ``tol``); a refresh adds the direction of the window's maximum at each strength vector as a candidate
    wherever the owner's active candidates fall short of it by more than ``tol``, so the fits' forces (on the
    active candidates) are inner approximations that are exact to ``tol`` at the refresh points.
    """

    def __init__(self, ctx: GapContext, inst: Instance, cache=None, chunk_size: int = 65536):
        self.ctx, self.inst, self.chunk = ctx, inst, chunk_size
        self.cache = make_cache() if cache is None else cache
        self.model = inst.reduced(ctx.model)
        self.U = inst.task_directions(ctx.model)
        J = inst.J
        self.lb = np.repeat(inst.lb, J, axis=0)
        self.ub = np.repeat(inst.ub, J, axis=0)
        self.fmul = inst.fmul
        self.active = np.zeros((self.K, J), bool)
        self.active[:, 0] = True
        self.alive = np.ones((self.K, J), bool)      # candidates that exist (the rest pad a test's row)
        self.row_active: np.ndarray | None = None     # (owners, K, J) active sets per owner (data set)
        self.window = getattr(inst, "window", None)
        self._J0 = J
        self._exact: tuple | None = None
        self._memo: dict[bytes, tuple] = {}
        self.n_lp = 0
        self.pidx, self.pnames = free_parameters(ctx.model, ctx.tie_sides)
        # per-test moment arms and J^T (posture_drift): each test's LPs with its own model
        self._tests = inst.test_matrices()
        self._test_models = None if self._tests is None else [
            replace(self.model, moment_arms=R, JT=JT) for R, JT in zip(*self._tests)]

    def _solve(self, Fa: np.ndarray, sel: np.ndarray, return_alpha: bool):
        """:func:`neckstrength.wrench.solve` on the candidate rows ``sel`` (K*J mask) for column strengths ``Fa``;
        with per-test matrices (``Instance.dR``) one call per test, with that test's model."""
        if self._test_models is None:
            return solve(self.model, Fa, self.U[sel], self.lb[sel], self.ub[sel], return_alpha=return_alpha,
                         chunk_size=self.chunk, cache=self.cache)
        idx = np.flatnonzero(sel)
        test = idx // self.inst.J
        w = np.zeros((len(Fa), len(idx)))
        status = np.zeros((len(Fa), len(idx)), dtype=np.int8)
        alpha = np.zeros((len(Fa), len(idx), Fa.shape[1])) if return_alpha else None
        for k in np.unique(test):
            c = np.flatnonzero(test == k)
            r = idx[c]
            wk, ak, sk = solve(self._test_models[k], Fa, self.U[r], self.lb[r], self.ub[r],
                               return_alpha=return_alpha, chunk_size=self.chunk, cache=self.cache)
            w[:, c], status[:, c] = wk, sk
            if return_alpha:
                alpha[:, c] = ak
        return w, alpha, status

    @property
    def K(self) -> int:
        return self.inst.U6.shape[0]

    def _own(self, forces: np.ndarray, owner) -> np.ndarray:
        """``forces`` (N x K x J, -1 = not solved) with the candidates outside each row's owner's active set
        at -1 (``owner``: the owner of each row; None: the union)."""
        if owner is None or self.row_active is None:
            return forces
        return np.where(self.row_active[np.asarray(owner)], forces, -1.0)

    def run(self, F: np.ndarray, return_alpha: bool = False, active_only: bool = False, owner=None):
        """Forces (N x K), status of the best candidate direction (N x K), its index j (N x K), and the
        column activations there (N x K x m') when ``return_alpha``. ``owner``: see the class docstring
        (with ``active_only``)."""
        F = np.atleast_2d(np.asarray(F, float))
        Fa = self.inst.strengths(F)
        N, K, J = len(F), self.K, self.inst.J
        use = self.active if (active_only and J > 1) else self.alive
        sel = use.ravel()
        w_s, alpha_s, status_s = self._solve(Fa, sel, return_alpha)
        self.n_lp += w_s.size
        w = np.full((N, K * J), -1.0)
        w[:, sel] = np.where(np.isfinite(w_s) & (status_s == _OPT), w_s, 0.0)
        status = np.full((N, K * J), _OPT, dtype=np.int8)
        status[:, sel] = status_s
        w = w.reshape(N, K, J)
        forces = np.where(w >= 0, w * self.fmul[None], -1.0)
        if active_only and J > 1:
            forces = self._own(forces, owner)
        self._cand_forces = forces
        j = forces.argmax(axis=2)
        f = np.maximum(np.take_along_axis(forces, j[..., None], 2)[..., 0], 0.0)
        st = np.take_along_axis(status.reshape(N, K, J), j[..., None], 2)[..., 0]
        a = None
        if return_alpha:
            a_full = np.zeros((N, K * J, alpha_s.shape[2]))
            a_full[:, sel] = alpha_s
            a = a_full.reshape(N, K, J, -1)
            a = np.take_along_axis(a, j[..., None, None], 2)[:, :, 0]
        return f, st, j, a

    def exact(self, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Window maxima (N x K) and their task-space wrenches (N x K x d) at strengths ``F`` (the last ones
        kept)."""
        F = np.atleast_2d(np.asarray(F, float))
        last = self._exact
        if last is not None and last[0].shape == F.shape and np.array_equal(last[0], F):
            return last[1], last[2]
        # each distinct strength vector once, and those solved before (up to 20000 kept) not again
        memo = self._memo
        keys = [r.tobytes() for r in F]
        todo = sorted({kk: i for i, kk in enumerate(keys) if kk not in memo}.values())
        if todo:
            Fa = self.inst.strengths(F[todo])
            if self._tests is None:
                f_new, _, W_new = self.window.solve(self.model.moment_arms, self.model.JT, Fa, self.inst.lb,
                                                    self.inst.ub)
            else:       # each test's window with its own matrices
                parts = [replace(self.window, specs=(spec,)).solve(self._tests[0][k], self._tests[1][k], Fa,
                                                                   self.inst.lb[k:k + 1], self.inst.ub[k:k + 1])
                         for k, spec in enumerate(self.window.specs)]
                f_new = np.concatenate([q[0] for q in parts], axis=1)
                W_new = np.concatenate([q[2] for q in parts], axis=1)
            if len(memo) + len(todo) > 20000:
                memo.clear()
            for a, i in enumerate(todo):
                memo[keys[i]] = (f_new[a], W_new[a])
        f = np.array([memo[kk][0] for kk in keys])
        W = np.array([memo[kk][1] for kk in keys])
        self._exact = (F.copy(), f, W)
        return f, W

    def _grow(self, new: dict[int, list[tuple[np.ndarray, float]]]) -> dict[int, list[int]]:
        """Add candidates ``new`` (test -> [(6-D unit wrench, force per unit wrench)]); their slots per test."""
        inst = self.inst
        K, J = self.K, inst.J
        free = {k: np.flatnonzero(~self.alive[k]) for k in new}
        extra = max([max(0, len(v) - len(free[k])) for k, v in new.items()] + [0])
        if extra:
            U6 = np.concatenate([inst.U6, np.repeat(inst.U6[:, :1], extra, axis=1)], axis=1)
            fmul = np.concatenate([inst.fmul, np.repeat(inst.fmul[:, :1], extra, axis=1)], axis=1)
            pad = lambda a: np.concatenate([a, np.zeros(a.shape[:-1] + (extra,), bool)], axis=-1)  # noqa: E731
            self.alive, self.active = pad(self.alive), pad(self.active)
            if self.row_active is not None:
                self.row_active = pad(self.row_active)
            free = {k: np.r_[free[k], np.arange(J, J + extra)] for k in new}
        else:
            U6, fmul = inst.U6.copy(), inst.fmul.copy()
        slots = {}
        for k, items in new.items():
            slots[k] = []
            for (u6, fm), j in zip(items, free[k]):
                U6[k, j], fmul[k, j] = u6, fm
                self.alive[k, j] = True
                slots[k].append(int(j))
        self.inst = replace(inst, U6=U6, fmul=fmul)
        self.U = self.inst.task_directions(self.ctx.model)
        self.lb = np.repeat(inst.lb, self.inst.J, axis=0)
        self.ub = np.repeat(inst.ub, self.inst.J, axis=0)
        self.fmul = fmul
        return slots

    def _window_refresh(self, F: np.ndarray, owner: np.ndarray | None) -> np.ndarray:
        """Per row of ``F``: a candidate that reaches the window maximum within ``tol`` (one of the starting
        candidates or of the owner's set; else the window maximum's direction, added) joins its owner's active set
        (the union's without owners). Returns per row whether the set grew."""
        F = np.atleast_2d(np.asarray(F, float))
        N, K = len(F), self.K
        ex, W = self.exact(F)
        self.run(F)
        forces = self._cand_forces
        tol = self.window.tol
        sets = self.active[None].repeat(N, 0) if owner is None else self.row_active[owner]
        before = sets.sum(axis=(1, 2))
        need: dict[int, list] = {}
        where: dict[int, list] = {}
        for i in range(N):
            for k in range(K):
                if ex[i, k] <= 0:
                    continue
                # an owner reuses only the starting candidates and its own, so that its set (and its fits) do not
                # depend on the other owners in the batch
                mine = self.alive[k] if owner is None else (sets[i, k] | (np.arange(self.inst.J) < self._J0))
                good = np.flatnonzero(mine & (forces[i, k] >= ex[i, k] * (1 - tol)))
                if good.size:
                    sets[i, k, good[np.argmax(forces[i, k, good])]] = True
                else:
                    need.setdefault(k, []).append(self.window.candidate(k, W[i, k]))
                    where.setdefault(k, []).append(i)
        if need:
            slots = self._grow(need)
            J = self.inst.J
            if sets.shape[2] < J:
                sets = np.concatenate([sets, np.zeros((N, K, J - sets.shape[2]), bool)], axis=2)
            for k, rows in where.items():
                for i, j in zip(rows, slots[k]):
                    sets[i, k, j] = True
        if owner is None:
            self.active |= sets.any(axis=0)
        else:
            for i, o in enumerate(owner):
                self.row_active[o] |= sets[i]
            self.active |= self.row_active.any(axis=0)
        after = sets.sum(axis=(1, 2)) if owner is None else self.row_active[owner].sum(axis=(1, 2))
        self._last_all = (F.copy(), ex)
        return after > before

    def refresh(self, F: np.ndarray) -> bool:
        """Evaluate all candidates at ``F``; add the maximising ones to the active set. True if it grew.

        The forces over all candidates at ``F`` are kept (:meth:`forces_all`), so that a caller who wants
        them at the same point does not solve the same LPs again. With a window: the window maxima (see the
        class docstring)."""
        if self.inst.J == 1:
            return False
        if self.window is not None:
            return bool(self._window_refresh(F, None).any())
        f, _, j, _ = self.run(F)
        self._last_all = (np.array(F, float, copy=True), f)
        before = self.active.sum()
        for k in range(self.K):
            self.active[k, np.unique(j[:, k])] = True
        return bool(self.active.sum() > before)

    def refresh_rows(self, F: np.ndarray, owner: np.ndarray) -> np.ndarray:
        """Per-owner :meth:`refresh`: the candidates that are maximal at ``F[i]`` join the active set of owner
        ``owner[i]`` (a new owner's set starts with the target). Returns, per row of ``F``, whether its
        owner's set grew."""
        owner = np.asarray(owner, dtype=np.int64)
        if self.inst.J == 1:
            return np.zeros(len(owner), bool)
        n = int(owner.max()) + 1 if owner.size else 0
        old = self.row_active
        if old is None or old.shape[0] < n:
            ra = np.zeros((n, self.K, self.inst.J), bool)
            ra[:, :, 0] = True
            if old is not None:
                ra[:old.shape[0]] = old
            self.row_active = ra
        if self.window is not None:
            return self._window_refresh(F, owner)
        f, _, j, _ = self.run(F)
        self._last_all = (np.array(F, float, copy=True), f)
        before = self.row_active[owner].sum(axis=(1, 2))
        self.row_active[owner[:, None], np.arange(self.K)[None, :], j] = True
        self.active |= self.row_active.any(axis=0)
        return self.row_active[owner].sum(axis=(1, 2)) > before

    def forces(self, F: np.ndarray) -> np.ndarray:
        """Predicted forces: over all candidates, or with a window its maxima."""
        if self.window is not None:
            return self.exact(F)[0]
        return self.run(F)[0]

    def forces_all(self, F: np.ndarray) -> np.ndarray:
        """:meth:`forces` over all candidates (with a window: its maxima); those of the last :meth:`refresh` if it
        was at ``F``."""
        last = getattr(self, "_last_all", None)
        F = np.atleast_2d(np.asarray(F, float))
        if last is not None and last[0].shape == F.shape and np.array_equal(last[0], F):
            return last[1]
        return self.forces(F)

    def muscles(self, phi: np.ndarray) -> np.ndarray:
        """Model-muscle strengths for log free strengths ``phi`` (N x p)."""
        return np.exp(np.atleast_2d(phi))[:, self.pidx]

    def forces_phi(self, phi: np.ndarray, owner=None) -> np.ndarray:
        """Forces for log free strengths (N x p), on the active candidate set (for the fit)."""
        return self.run(self.muscles(phi), active_only=True, owner=owner)[0]

    @_one_blas_thread
    def forces_grad_phi(self, phi: np.ndarray, lazy: bool = False, owner=None):
        """Forces (N x K) and their exact derivatives d F / d phi (N x K x p) on the active candidate set.

        Envelope theorem on the LP (Eq. 4.1 / 5.2 in muscle forces): at an optimal vertex the multiplier
        ``lam`` of ``R diag(f) alpha - b w = 0`` satisfies ``lam . b = 1`` and ``lam . R_j = 0`` for every
        column strictly inside its activation bounds, and ``w = sum_j (lam . R_j) alpha_j f_j``, so
        ``dw / df_j = (lam . R_j) alpha_j`` (one side of a kink, as a forward difference would be). ``lam``
        is solved from the interior columns of the returned activations (least squares, min-norm at
        degenerate vertices); the chain rule goes through the column map ``A``, the force scale and
        ``f = exp(phi)[pidx]``. One LP per sample and direction instead of ``p + 1`` for finite differences.

        Only the candidate wrench that gives each test's force (the maximum over its J candidates) enters
        the derivative, so ``lam`` is solved for that one only. With ``lazy`` the derivatives are not
        computed here: returns the forces and a function ``rows -> (len(rows) x K x p)`` derivatives of
        those rows (the same numbers), so that a caller that keeps one of several trial points pays the
        linear algebra for that one only. ``owner``: see the class docstring.
        """
        phi = np.atleast_2d(np.asarray(phi, float))
        Fm = self.muscles(phi)                                   # (N, m) base-model strengths
        inst = self.inst
        Fa = inst.strengths(Fm)                                  # (N, m') column strengths
        N, K, J = len(Fm), self.K, inst.J
        use = self.active if J > 1 else np.ones((K, J), bool)
        sel = use.ravel()
        w_s, alpha_s, status_s = self._solve(Fa, sel, True)
        self.n_lp += w_s.size
        ok = np.isfinite(w_s) & (status_s == _OPT) & (w_s > 0)
        w_s = np.where(ok, w_s, 0.0)
        wf = np.full((N, K * J), -1.0)
        wf[:, sel] = w_s
        fm = np.repeat(self.fmul.reshape(1, K * J), N, axis=0)
        forces = np.where(wf >= 0, wf * fm, -1.0).reshape(N, K, J)
        if J > 1:
            forces = self._own(forces, owner)
        j = forces.argmax(axis=2)
        f = np.maximum(np.take_along_axis(forces, j[..., None], 2)[..., 0], 0.0)
        # position of each test's maximising candidate among the solved ones (columns of w_s / alpha_s)
        col = np.cumsum(sel) - 1
        s_of = col[np.arange(K)[None, :] * J + j]                # (N, K)

        def grad(rows=None) -> np.ndarray:
            with single_threaded_blas():
                return self._grad_phi(Fm, Fa, w_s, alpha_s, ok, s_of, sel, rows)

        return (f, grad) if lazy else (f, grad())

    def _grad_phi(self, Fm, Fa, w_s, alpha_s, ok, s_of, sel, rows) -> np.ndarray:
        """d F / d phi (R x K x p) of :meth:`forces_grad_phi` for the strength vectors ``rows`` (all if None)."""
        if rows is not None:
            rows = np.asarray(rows, dtype=np.int64)
            Fm, Fa, s_of = Fm[rows], Fa[rows], s_of[rows]
        else:
            rows = np.arange(len(Fm))
        inst = self.inst
        N, K = s_of.shape
        r2 = rows[:, None]
        al = np.nan_to_num(alpha_s[r2, s_of])                    # (N, K, m') activations at the maximum
        okg = ok[r2, s_of]                                       # (N, K)
        lb, ub = self.lb[sel][s_of], self.ub[sel][s_of]          # (N, K, m')
        tol = 1e-7
        interior = (al > lb + tol) & (al < ub - tol) & (Fa[:, None, :] > 0)
        Rm = self.model.moment_arms                              # (n, m')
        n = Rm.shape[0]
        if self._tests is None:
            bs = (self.model.JT @ self.U[sel].T).T               # (S, n)
            b = bs[s_of]                                         # (N, K, n)
            RR = (Rm[:, None, :] * Rm[None, :, :]).reshape(n * n, -1).T      # (m', n*n) outer products R_j R_j'
            G = (interior.reshape(N * K, -1).astype(float) @ RR).reshape(N, K, n, n)
        else:                                                    # test k's own R_k and J^T_k
            Rk, JTk = self._tests
            b = np.einsum("kad,nkd->nka", JTk, self.U[sel][s_of])
            G = np.einsum("nkj,kaj,kbj->nkab", interior.astype(float), Rk, Rk)
        G += b[..., :, None] * b[..., None, :]
        scale = np.trace(G, axis1=2, axis2=3)[..., None, None]
        G += 1e-12 * np.maximum(scale, 1e-30) * np.eye(n)[None, None]
        lam = np.linalg.solve(G, b[..., None])[..., 0]                                     # (N, K, n)
        lamR = lam @ Rm if self._tests is None else np.einsum("nka,kaj->nkj", lam, self._tests[0])
        gcol = lamR * al * okg[..., None]                                                   # dw/dFa (N, K, m')
        gcol = gcol * (Fa > 0)[:, None, :]
        gmus = gcol @ inst.A                                     # dw/dF base muscles (N, K, m)
        g = gmus * self.fmul.reshape(-1)[sel][s_of][..., None]
        p = int(self.pidx.max()) + 1
        onehot = np.zeros((len(self.pidx), p))
        onehot[np.arange(len(self.pidx)), self.pidx] = 1.0
        return (g * Fm[:, None, :]) @ onehot                                            # (N, K, p)


@dataclass
class FitResult:
    phi: np.ndarray          # (P, p) log free strengths
    loss: np.ndarray         # (P,) weighted loss incl. ridge
    sse: np.ndarray          # (P,) training sum of squared relative residuals (no ridge)
    forces: np.ndarray       # (P, K) predicted forces at phi (all directions)
    iterations: np.ndarray   # (P,)


def start_point(sim_base: Simulator, targets: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Log free strengths of the baseline scaled to the training forces (geometric mean ratio; Eq. 5.3
    uses one direction, this uses all training directions so no held-out direction enters)."""
    m = sim_base.ctx.model
    f_base = sim_base.forces(m.strengths[None, :])[0]
    ok = f_base > 0
    pidx, _ = sim_base.pidx, sim_base.pnames
    p = int(pidx.max()) + 1
    theta = np.log(np.bincount(pidx, weights=m.strengths, minlength=p) / np.bincount(pidx, minlength=p))
    out = np.zeros((len(targets), p))
    for i, (t, w) in enumerate(zip(targets, weights)):
        sel = ok & (w > 0)
        a = float(np.mean(np.log(t[sel] / f_base[sel]))) if sel.any() else 0.0
        out[i] = theta + a
    return out


def _loss(F: np.ndarray, T: np.ndarray, W: np.ndarray, phi: np.ndarray, prior: np.ndarray, ridge: float):
    r = F / T - 1.0
    sse = (W * r ** 2).sum(axis=-1)
    return sse + ridge * ((phi - prior) ** 2).sum(axis=-1), sse


@_one_blas_thread
def fit_strengths(fforces: Callable[[np.ndarray], np.ndarray], targets: np.ndarray, weights: np.ndarray,
                  phi0: np.ndarray, prior: np.ndarray, settings: FitSettings = FitSettings(),
                  fgrad: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
                  owner: np.ndarray | None = None) -> FitResult:
    """Levenberg-Marquardt on the log free strengths of P problems at once.

    ``fforces(phi)`` maps (N x p) log free strengths to (N x K) predicted forces; ``targets`` (P x K)
    measured forces; ``weights`` (P x K) 1 = training direction, 0 = not used (held out);
    ``phi0`` (P x p) start; ``prior`` (P x p) ridge centre; bounds are ``prior + log(bounds_rel)``.
    Held-out directions enter neither the loss nor any step (their weight is 0), only the returned
    predictions. ``fgrad(phi)`` (optional) returns forces and their exact Jacobian (N x K x p,
    :meth:`Simulator.forces_grad_phi`, called with ``lazy=True`` for the trials); then each iteration
    solves the LPs of the damping trials only (the Jacobian at the accepted trial comes from the same
    solves) instead of ``p`` extra forward differences. ``owner`` (P,): passed on to ``fforces`` / ``fgrad`` as the
    owner of each problem's strength vectors (:class:`Simulator`'s active sets per data set); None: not passed.
    """
    s = settings
    T = np.asarray(targets, float)
    W = np.asarray(weights, float)
    prior = np.asarray(prior, float)
    lo = prior + np.log(s.bounds_rel[0])
    hi = prior + np.log(s.bounds_rel[1])
    phi = np.clip(np.asarray(phi0, float).copy(), lo, hi)
    P, p = phi.shape
    owner = None if owner is None else np.asarray(owner)

    def own(rows=None, times: int = 1) -> dict:
        """The ``owner`` keyword for the strength vectors of problems ``rows`` (all), each ``times`` times."""
        if owner is None:
            return {}
        return {"owner": owner if rows is None else np.repeat(owner[rows], times)}

    if fgrad is not None:
        F, Jac = fgrad(phi, **own())
    else:
        F, Jac = fforces(phi, **own()), None
    loss, sse = _loss(F, T, W, phi, prior, s.ridge)
    mu = np.full(P, s.lambda0)
    stall = np.zeros(P, int)
    iters = np.zeros(P, int)
    active = np.ones(P, bool)
    sw = np.sqrt(W)
    eye = np.eye(p)
    mults = np.array([0.1, 1.0, 10.0])
    for _ in range(s.max_iter):
        idx = np.nonzero(active)[0]
        if len(idx) == 0:
            break
        A = len(idx)
        ph = phi[idx]
        if Jac is not None:
            Jr = Jac[idx].transpose(0, 2, 1) / T[idx][:, None, :]                  # (A, p, K)
        else:
            hsign = np.where(ph + s.fd_step > hi[idx], -1.0, 1.0)                 # (A, p)
            Ph = ph[:, None, :] + s.fd_step * hsign[:, None, :] * eye[None]      # (A, p, p)
            Fh = fforces(Ph.reshape(-1, p), **own(idx, p)).reshape(A, p, -1)
            Jr = (Fh - F[idx][:, None, :]) / (s.fd_step * hsign[:, :, None]) / T[idx][:, None, :]
        Jm = Jr.transpose(0, 2, 1) * sw[idx][:, :, None]                         # (A, K, p)
        r = sw[idx] * (F[idx] / T[idx] - 1.0)
        JTJ = np.einsum("akp,akq->apq", Jm, Jm)
        g = np.einsum("akp,ak->ap", Jm, r) + s.ridge * (ph - prior[idx])
        H = JTJ + s.ridge * eye[None]
        dg = np.einsum("app->ap", JTJ)
        steps = np.empty((A, len(mults), p))
        for t, mt in enumerate(mults):
            Hm = H + (mu[idx] * mt)[:, None, None] * (dg[:, :, None] * eye[None] + 1e-9 * eye[None])
            steps[:, t] = -np.linalg.solve(Hm, g[..., None])[..., 0]
        trial = np.clip(ph[:, None, :] + steps, lo[idx][:, None, :], hi[idx][:, None, :])
        if Jac is not None:
            Ft, grad_rows = fgrad(trial.reshape(-1, p), lazy=True, **own(idx, len(mults)))
            Ft = Ft.reshape(A, len(mults), -1)
        else:
            Ft = fforces(trial.reshape(-1, p), **own(idx, len(mults))).reshape(A, len(mults), -1)
        lt, st = _loss(Ft, T[idx][:, None, :], W[idx][:, None, :], trial, prior[idx][:, None, :], s.ridge)
        best = lt.argmin(axis=1)
        lb = lt[np.arange(A), best]
        better = lb < loss[idx]
        rel = np.where(better, (loss[idx] - lb) / np.maximum(loss[idx], 1e-300), 0.0)
        if Jac is not None:
            # the Jacobian of the accepted trials only
            acc = np.flatnonzero(better)
            Jt = np.zeros((A, Ft.shape[2], p))
            if acc.size:
                Jt[acc] = grad_rows(acc * len(mults) + best[acc])
        for a, i in enumerate(idx):
            iters[i] += 1
            if better[a]:
                phi[i] = trial[a, best[a]]
                F[i] = Ft[a, best[a]]
                if Jac is not None:
                    Jac[i] = Jt[a]
                loss[i], sse[i] = lb[a], st[a, best[a]]
                mu[i] = max(mu[i] * mults[best[a]], 1e-12)
                stall[i] = stall[i] + 1 if rel[a] < s.tol else 0
            else:
                mu[i] *= 100.0
                stall[i] += 1
            if stall[i] >= 3 or mu[i] > 1e8:
                active[i] = False
    return FitResult(phi, loss, sse, F, iters)
