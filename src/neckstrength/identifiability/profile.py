"""Profiles of the best achievable misfit with one muscle group fixed (issue 31 item 1).

For a data set (maximum forces of a battery of tests) and a muscle group ``g`` held at ``r x normal`` (both sides
tied), the *profile* is

    P_g(r) = min over the other groups' factors s (sides tied, lo <= s <= hi) of  RMS_k [ log w_k(f(r, s)) - log w_k^data ]

with ``f(r, s)`` the strengths ``normal x factor`` and ``w_k`` the max-wrench LP of test ``k`` (thesis Eq. 4.1 / 5.2,
solved by :func:`neckstrength.wrench.solve`). If ``P_g(r)`` is large at ``r = 1`` the forces rule a normal group out;
if it stays ~0 the other groups can compensate and the forces alone cannot tell.

The minimisation is over log factors in a box (``bounds``), by a *batched* box-constrained Levenberg-Marquardt: all
grid points and starts are iterated together, so that each iteration is one call of the batched LP solver for every
problem at once (forward-difference Jacobian in the same call). Starts: the normal point (all other factors 1) plus
``n_starts`` uniform draws in the log box from a seeded stream; then a continuation round started from the best
solutions of the neighbouring grid points. The landscape has local optima: every profile value is an upper bound on
the true minimum (the best of the starts).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from neckstrength.model.reduction import ReducedModel
from neckstrength.wrench import solve
from neckstrength.wrench.batched import BasisCache
from neckstrength.wrench.problem import STATUS_CODES

_OPTIMAL = {v: k for k, v in STATUS_CODES.items()}["optimal"]

#: residual given to a test the candidate cannot produce (status not optimal, e.g. EMG bounds infeasible):
#: log(1e-3), i.e. as if the force were a thousandth of the measured one
INFEASIBLE_RESIDUAL = float(np.log(1e-3))


@dataclass(frozen=True)
class ProfileSettings:
    """Settings of the misfit profiles (config ``identifiability``; nothing of this is in the thesis)."""

    grid: tuple[float, ...] = tuple(np.round(np.arange(0.2, 1.2001, 0.1), 10))
    bounds: tuple[tuple[str, float, float], ...] = (("anatomical", 0.5, 2.0), ("wide", 0.25, 4.0))
    n_starts: int = 4              # random starts per grid point besides the normal start
    continuation: bool = True      # a second round from the neighbouring grid points' best solutions
    max_iter: int = 60
    fd_step: float = 1e-5          # forward-difference step in log factor
    tol: float = 1e-10             # relative cost decrease that ends a problem's iterations

    def __post_init__(self):
        if not self.grid or min(self.grid) <= 0:
            raise ValueError(f"identifiability grid must be non-empty and positive, got {self.grid}")
        for name, lo, hi in self.bounds:
            if not 0 < lo < 1 < hi:
                raise ValueError(f"identifiability bounds {name!r}: need 0 < lo < 1 < hi, got ({lo}, {hi})")
        if self.n_starts < 0 or self.max_iter < 1:
            raise ValueError("identifiability n_starts must be >= 0 and max_iter >= 1")


@dataclass
class Block:
    """Tests that share one reduced model: ``model`` evaluated at strengths ``f * rho`` (``rho``: the posture's
    force-length factor, 1 at neutral), unit wrenches ``U`` and activation bounds (None or (k, m))."""

    model: ReducedModel
    rho: np.ndarray
    idx: np.ndarray
    U: np.ndarray
    alpha_lb: np.ndarray | None = None
    alpha_ub: np.ndarray | None = None


@dataclass
class Battery:
    """A battery of tests (one or several blocks); :meth:`wrenches` maps strength vectors to max wrenches."""

    labels: list[str]
    blocks: list[Block]
    cache: BasisCache = field(default_factory=BasisCache, repr=False)

    @property
    def n_tests(self) -> int:
        return len(self.labels)

    @property
    def muscle_names(self) -> tuple[str, ...]:
        return self.blocks[0].model.muscle_names

    def wrenches(self, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        F = np.atleast_2d(np.asarray(F, float))
        w = np.zeros((len(F), self.n_tests))
        st = np.zeros((len(F), self.n_tests), dtype=np.int64)
        for b in self.blocks:
            wb, _, sb = solve(b.model, F * b.rho[None, :], b.U, b.alpha_lb, b.alpha_ub, return_alpha=False,
                              cache=self.cache)
            w[:, b.idx] = wb
            st[:, b.idx] = sb
        return w, st


def neutral_battery(model: ReducedModel, labels: Sequence[str], U: np.ndarray, alpha_lb=None, alpha_ub=None) -> Battery:
    U = np.atleast_2d(np.asarray(U, float))
    return Battery(list(labels), [Block(model, np.ones(model.m), np.arange(len(U)), U, alpha_lb, alpha_ub)])


def posture_battery(pset, labels: Sequence[str], U: np.ndarray, postures: Sequence[str]) -> Battery:
    """Tests in several postures (:class:`neckstrength.postures.model.PostureSet`); ``postures[k]`` of test k."""
    U = np.atleast_2d(np.asarray(U, float))
    pa = np.asarray(list(postures))
    blocks = []
    for p in dict.fromkeys(postures):
        idx = np.flatnonzero(pa == p)
        blocks.append(Block(pset.models[p], np.asarray(pset.rho[p], float), idx, U[idx]))
    return Battery(list(labels), blocks)


def group_names(muscle_names: Sequence[str]) -> list[str]:
    """Groups of a model in order of first appearance (a spatial model's '-R'/'-L' sides are one group)."""
    return list(dict.fromkeys(n[:-2] if n.endswith(("-R", "-L")) else n for n in muscle_names))


def group_index(muscle_names: Sequence[str]) -> np.ndarray:
    groups = group_names(muscle_names)
    return np.array([groups.index(n[:-2] if n.endswith(("-R", "-L")) else n) for n in muscle_names])


def log_residuals(w: np.ndarray, status: np.ndarray, w_data: np.ndarray) -> np.ndarray:
    """log(w / w_data) per test; a test the candidate cannot produce gets :data:`INFEASIBLE_RESIDUAL`."""
    ok = (status == _OPTIMAL) & (w > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.log(np.where(ok, w, 1.0) / w_data[None, :])
    return np.where(ok, r, INFEASIBLE_RESIDUAL)


@dataclass
class LMResult:
    x: np.ndarray          # (N, p) log factors of the free groups
    residuals: np.ndarray  # (N, K)
    cost: np.ndarray       # (N,) 0.5 sum r^2
    iterations: np.ndarray
    evaluations: int       # strength vectors sent to the LP solver


def batched_lm(resid: Callable[[np.ndarray, np.ndarray], np.ndarray], X0: np.ndarray, lo: float, hi: float,
               max_iter: int = 60, fd_step: float = 1e-5, tol: float = 1e-10) -> LMResult:
    """Box-constrained Levenberg-Marquardt for many independent least-squares problems at once.

    ``resid(X, ids)``: rows ``X`` (M x p) of problems ``ids`` (M,) -> residuals (M x K), one batched evaluation.
    Each problem keeps its own damping; variables on a bound whose gradient points outwards are held (active set),
    the damped Gauss-Newton step is solved for the others and clipped to the box. A step is accepted only if it
    lowers the cost, so no problem's cost ever increases. Jacobian: forward differences (backward at the upper
    bound) with step ``fd_step``, evaluated in the same batch as the residual."""
    X = np.clip(np.array(X0, float), lo, hi)
    N, p = X.shape
    n_eval = 0
    eye = np.eye(p)[None]

    def evaluate(ids, Xs, jac):
        nonlocal n_eval
        if not jac:
            n_eval += len(ids)
            return resid(Xs, ids), None
        M = len(Xs)
        h = np.where(Xs + fd_step <= hi, fd_step, -fd_step)
        pts = np.repeat(Xs[:, None, :], p + 1, axis=1)
        pts[:, 1:, :] += h[:, :, None] * eye
        R = resid(pts.reshape(-1, p), np.repeat(ids, p + 1)).reshape(M, p + 1, -1)
        n_eval += M * (p + 1)
        J = (R[:, 1:, :] - R[:, :1, :]) / h[:, :, None]
        return R[:, 0, :], np.transpose(J, (0, 2, 1))

    rr, J = evaluate(np.arange(N), X, True)
    cost = 0.5 * np.sum(rr ** 2, axis=1)
    lam = np.full(N, 1e-3)
    active = np.ones(N, bool)
    iters = np.zeros(N, int)
    for _ in range(max_iter):
        ia = np.flatnonzero(active)
        if not len(ia):
            break
        Ja, ra, xa = J[ia], rr[ia], X[ia]
        g = np.einsum("nkp,nk->np", Ja, ra)
        H = np.einsum("nkp,nkq->npq", Ja, Ja)
        held = ((xa <= lo + 1e-12) & (g > 0)) | ((xa >= hi - 1e-12) & (g < 0))
        d = np.einsum("npp->np", H)
        A = H + (lam[ia][:, None] * (d + 1e-9 * (1 + d.max(axis=1, keepdims=True))))[:, :, None] * eye
        A = np.where(held[:, :, None] | held[:, None, :], 0.0, A) + held[:, :, None] * eye
        step = np.linalg.solve(A, np.where(held, 0.0, -g)[:, :, None])[:, :, 0]
        xn = np.clip(xa + step, lo, hi)
        rn, _ = evaluate(ia, xn, False)
        cn = 0.5 * np.sum(rn ** 2, axis=1)
        acc = cn < cost[ia]
        iters[ia] += 1
        moved = np.abs(xn - xa).max(axis=1)
        small = acc & ((cost[ia] - cn) <= tol * cost[ia] + 1e-30)
        lam[ia] = np.where(acc, lam[ia] / 3.0, lam[ia] * 5.0)
        done = small | (lam[ia] > 1e10) | (moved < 1e-12) | (cn < 1e-26)
        ja = ia[acc]
        if len(ja):
            X[ja] = xn[acc]
            cost[ja] = cn[acc]
            rr[ja], J[ja] = evaluate(ja, X[ja], True)
        active[ia[done]] = False
    return LMResult(X, rr, cost, iters, n_eval)


@dataclass
class ProfileProblem:
    """One data set for the profiles: its battery, measured wrenches, the 'normal' strengths (factor 1)."""

    name: str
    battery: Battery
    w_data: np.ndarray
    normal: np.ndarray
    truth_factors: dict[str, float] | None = None   # known for simulated data: group -> factor

    def __post_init__(self):
        self.w_data = np.asarray(self.w_data, float)
        if self.w_data.shape != (self.battery.n_tests,):
            raise ValueError(f"{self.name}: {len(self.w_data)} wrenches for {self.battery.n_tests} tests")
        if np.any(~np.isfinite(self.w_data)) or np.any(self.w_data <= 0):
            bad = [self.battery.labels[k] for k in np.flatnonzero(~(self.w_data > 0))]
            raise ValueError(f"{self.name}: wrenches must be positive and finite; bad tests {bad}")


def strengths_from_factors(normal: np.ndarray, gidx: np.ndarray, factors: np.ndarray) -> np.ndarray:
    """(N, G) group factors -> (N, m) strengths ``normal x factor`` (sides tied)."""
    return np.asarray(normal, float)[None, :] * np.atleast_2d(factors)[:, gidx]


def profile_group(prob: ProfileProblem, group: str, s: ProfileSettings, rng: np.random.Generator,
                  bounds: tuple[str, float, float]) -> pd.DataFrame:
    """The profile of ``group`` on ``prob`` within one box ``bounds`` = (name, lo, hi) for the other groups.

    Returns one row per grid value: best RMS log residual, largest |residual|, the minimiser's factors (columns
    ``f_<group>``) and the groups on a bound, the number of starts and of LP evaluations."""
    names = group_names(prob.battery.muscle_names)
    if group not in names:
        raise ValueError(f"group {group!r} not in model groups {names}")
    gidx = group_index(prob.battery.muscle_names)
    gi = names.index(group)
    free = [j for j in range(len(names)) if j != gi]
    p = len(free)
    bname, lo_f, hi_f = bounds
    lo, hi = np.log(lo_f), np.log(hi_f)
    grid = np.asarray(s.grid, float)
    n_g = len(grid)

    def full_factors(X, rvals):
        Fac = np.empty((len(X), len(names)))
        Fac[:, free] = np.exp(X)
        Fac[:, gi] = rvals
        return Fac

    def solve_from(X0, owner):
        rv = grid[owner]

        def resid(X, ids):
            F = strengths_from_factors(prob.normal, gidx, full_factors(X, rv[ids]))
            w, st = prob.battery.wrenches(F)
            return log_residuals(w, st, prob.w_data)

        return batched_lm(resid, X0, lo, hi, s.max_iter, s.fd_step, s.tol)

    starts = [np.zeros((n_g, p))]
    for _ in range(s.n_starts):
        starts.append(rng.uniform(lo, hi, size=(n_g, p)))
    X0 = np.concatenate(starts)
    owner = np.tile(np.arange(n_g), len(starts))
    res = solve_from(X0, owner)
    X_all, c_all, r_all, ev = res.x, res.cost, res.residuals, res.evaluations
    own_all = owner
    best = _best_per_owner(c_all, own_all, n_g)
    if s.continuation and n_g > 1:
        Xc, oc = [], []
        for i in range(n_g):
            for j in (i - 1, i + 1):
                if 0 <= j < n_g:
                    Xc.append(X_all[best[j]])
                    oc.append(i)
        oc = np.array(oc)
        res2 = solve_from(np.array(Xc), oc)
        X_all = np.concatenate([X_all, res2.x])
        c_all = np.concatenate([c_all, res2.cost])
        r_all = np.concatenate([r_all, res2.residuals])
        own_all = np.concatenate([own_all, oc])
        ev += res2.evaluations
        best = _best_per_owner(c_all, own_all, n_g)
    n_st = np.bincount(own_all, minlength=n_g)
    rows = []
    for i in range(n_g):
        b = best[i]
        fac = full_factors(X_all[b:b + 1], grid[i:i + 1])[0]
        on_lo = [names[j] for j, x in zip(free, X_all[b]) if x <= lo + 1e-6]
        on_hi = [names[j] for j, x in zip(free, X_all[b]) if x >= hi - 1e-6]
        row = {"dataset": prob.name, "group": group, "bounds": bname, "lo": lo_f, "hi": hi_f, "r": grid[i],
               "rms": float(np.sqrt(np.mean(r_all[b] ** 2))), "max_abs_residual": float(np.abs(r_all[b]).max()),
               "n_tests": prob.battery.n_tests, "n_unproducible": int(np.sum(r_all[b] == INFEASIBLE_RESIDUAL)),
               "on_lower": " ".join(on_lo), "on_upper": " ".join(on_hi), "n_starts": int(n_st[i]),
               "lp_evaluations_total": ev}
        row.update({f"f_{n}": float(v) for n, v in zip(names, fac)})
        rows.append(row)
    return pd.DataFrame(rows)


def _best_per_owner(cost: np.ndarray, owner: np.ndarray, n: int) -> np.ndarray:
    best = np.full(n, -1)
    for i in range(n):
        idx = np.flatnonzero(owner == i)
        best[i] = idx[np.argmin(cost[idx])]
    return best
