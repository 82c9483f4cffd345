"""The fitting engine of the gap diagnosis: every (effect combination, parameter) key fitted for many problems.

A *problem* is one data set restricted to its training directions (one per cross-validation fold, and
optionally one on all directions). Problems of many data sets share each model instance and are fitted together
(:func:`neckstrength.gap.fit.fit_strengths`), but each has its own targets and loss. Used by the diagnosis
(:mod:`neckstrength.gap.diagnose`) and by its calibration (:mod:`neckstrength.gap.calibrate`), which fits
simulated data sets with the same engine.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np

from neckstrength.estimation.discrepancy import data_discrepancy
from neckstrength.gap.effects import Effect, GapContext, base_instance, compose
from neckstrength.gap.fit import FitSettings, Simulator, fit_strengths, make_cache, start_point
from neckstrength.gap.forked import fork_map
from neckstrength.seeds import derive_rng

if TYPE_CHECKING:    # for the annotation only: gap.protocols uses gap.calibrate, which imports this module
    from neckstrength.gap.evidence import EvidenceSettings
    from neckstrength.gap.protocols import ProtocolSettings


@dataclass(frozen=True)
class BlindData:
    """What the diagnosis is given: a name and the measured maximum force (N) per test direction."""

    name: str
    forces: np.ndarray


@dataclass(frozen=True)
class CalibrationSettings:
    """The calibrated decision (:mod:`neckstrength.gap.calibrate`).

    ``replicates`` noise-only data sets per data set (parametric bootstrap from its fitted base model; 0 = no
    calibration: the candidate with the best score is reported, without a p-value); p-values have resolution
    ``1 / (replicates + 1)``. ``alpha``: level of the decision. ``noise`` (log-normal SD of the simulated data,
    :func:`neckstrength.gap.calibrate.estimate_noise`): 'auto' (the data set's repeat-trial scatter where
    ``repeats`` has it, else the literature prior), 'repeats' (an error without), 'prior' (the central value of
    ``noise_prior`` = (low, central, high)), a number, or 'heldout' (the smallest RMS log held-out residual: the
    misfit counts as noise, so the size of the remaining gap cannot be tested). ``repeats``: per data set
    ``(name, log SD, df, ci_low, ci_high)`` from the trial import's ``noise.csv``. ``sensitivity``: the decision
    again at the ends of the noise's range (the prior's low and high, or the repeats' 95% interval) with
    ``sensitivity_replicates`` noise-only data sets each (None: ``replicates``; p-values there have resolution
    ``1 / (sensitivity_replicates + 1)``). ``power_sizes``: effect sizes (share of
    the way from neutral to the far bound) at which the power is simulated, ``power_replicates`` data sets per
    effect and size, ``power_target`` the share identified that counts as detectable. ``strength_spread``: SD of
    individual log strengths, for the strengths the directions leave undetermined in the simulated truths.
    ``null_truth``: the structure of the noise-only replicates' truths, 'base' (the fitted model's own) or 'elements'
    (each full-model element its own strength, factor ``exp(N(0, element_spread))`` per element and replicate:
    :class:`neckstrength.gap.calibrate.ElementNull`). ``selection``: which significant effect is named,
    'largest_improvement' (the largest improvement of the held-out gap among the effects that pass the maxT test on
    their own; the default since 2026-11-28) or 'max_z' (the largest standardised improvement, before);
    :meth:`neckstrength.gap.calibrate.Calibration.decide`.
    ``starts`` / ``max_iter``: fits of the screen (the measured data set and its simulated ones alike)."""

    replicates: int = 39
    alpha: float = 0.05
    noise: str | float = "auto"
    noise_prior: tuple[float, float, float] = (0.05, 0.08, 0.15)
    repeats: tuple[tuple, ...] = ()
    sensitivity: bool = True
    sensitivity_replicates: int | None = None
    power_sizes: tuple[float, ...] = (0.25, 0.5, 1.0)
    power_replicates: int = 5
    power_target: float = 0.8
    strength_spread: float = 0.3
    starts: int = 1
    max_iter: int = 15
    sd_floor: float = 1e-3
    cv: str = "refit"
    cv_steps: int = 1
    null_truth: str = "base"
    element_spread: float = 0.3
    selection: str = "largest_improvement"


@dataclass(frozen=True)
class DiagnosisSettings:
    effects: tuple[str, ...] = ("cocontraction", "cocontraction_groups", "direction_tolerance", "kinematic",
                                "asymmetry", "finer_groups", "origin_offset", "point_scale", "shoulder_girdle")
    grid_points: int = 5
    folds: int = 5
    pairs_top: int = 3
    pair_grid_top: int = 1
    penalty: float = 0.005
    epsilon: float = 3.0
    bootstrap: int = 500
    starts: int = 4
    start_spread: float = 0.5
    refine_iter: int = 0
    refine_starts: int = 1
    reach_samples: int = 1500
    reach_iter: int = 8
    seed: int = 0
    fit: FitSettings = FitSettings()
    calibration: CalibrationSettings = CalibrationSettings(replicates=0)
    protocols: ProtocolSettings | None = None     # what to measure to tell (gap.protocols; None: not computed)
    evidence: EvidenceSettings | None = None       # the Bayes evidence's second reading (gap.evidence; None: none)

def direction_folds(K: int, folds: int, rng: np.random.Generator) -> np.ndarray:
    """Fold of each direction: a random permutation dealt round-robin (leave-one-out when folds >= K)."""
    folds = min(int(folds), K)
    return rng.permutation(K) % folds


def _key(pairs: Sequence[tuple[str, np.ndarray]], registry: dict | None = None) -> tuple:
    """Canonical key of an effect combination: sorted by name, neutral effects dropped (same model)."""
    out = []
    for n, th in pairs:
        th = tuple(float(x) for x in np.asarray(th, float))
        if registry is not None and registry[n].is_neutral(np.array(th)):
            continue
        out.append((n, th))
    return tuple(sorted(out))


class Engine:
    """Fits of every (effect combination, parameter) key for all problems; results cached by key."""

    def __init__(self, ctx: GapContext, data: Sequence[BlindData], s: DiagnosisSettings, folds: np.ndarray,
                 registry: dict[str, Effect], full: bool = True):
        """``full``: also the problem on all directions of each data set (fold -1); without it only the
        cross-validation problems (what a held-out score needs)."""
        self.ctx, self.s, self.folds, self.registry = ctx, s, folds, registry
        self.cache = make_cache()
        self.F = int(folds.max()) + 1          # folds: (data sets x directions)
        self.nd = len(data)
        self.names = [d.name for d in data]
        K = ctx.K
        T, W, ds, fo = [], [], [], []
        for i, d in enumerate(data):
            f = np.asarray(d.forces, float)
            if f.shape != (K,) or not np.all(np.isfinite(f)) or np.any(f <= 0):
                raise ValueError(f"data set {d.name}: need {K} positive finite forces")
            for fold in list(range(self.F)) + ([-1] if full else []):
                T.append(f)
                W.append((folds[i] != fold).astype(float) if fold >= 0 else np.ones(K))
                ds.append(i)
                fo.append(fold)
        self.T, self.W = np.array(T), np.array(W)
        self.pds, self.pfold = np.array(ds), np.array(fo)
        self.P = len(self.T)
        self.base_sim = Simulator(ctx, base_instance(ctx), self.cache, s.fit.chunk_size)
        self.max_rounds = 4
        self.prior = start_point(self.base_sim, self.T, self.W)
        self.p = self.prior.shape[1]
        self.results: dict[tuple, dict] = {}
        self.n_fits = 0
        self._last_sim: tuple | None = None      # the simulator (and basis cache) of the last key used

    def key(self, pairs) -> tuple:
        return _key(pairs, self.registry)

    def effects_of(self, key: tuple) -> tuple[list[Effect], list[np.ndarray]]:
        effs = [self.registry[n] for n, _ in key]
        return effs, [np.array(th) for _, th in key]

    def sim(self, key: tuple, keep: bool = False) -> Simulator:
        """A simulator for ``key`` (the base one is kept; others are built per use and dropped, with
        their basis caches; ``keep``: reuse / keep the last one kept, for the fold steps of
        :meth:`evaluate_one_step` after the all-direction fit)."""
        if key == ():
            return self.base_sim
        if keep and self._last_sim is not None and self._last_sim[0] == key:
            return self._last_sim[1]
        effs, ths = self.effects_of(key)
        sim = Simulator(self.ctx, compose(self.ctx, effs, ths), None, self.s.fit.chunk_size)
        if keep:
            self._last_sim = (key, sim)
        return sim

    def evaluate(self, key: tuple, warm: np.ndarray, mask: np.ndarray | None = None, starts: int | None = None,
                 keep: bool = False) -> dict:
        """Fit the problems in ``mask`` for ``key`` with ``starts`` starts (warm start + perturbations; the
        perturbations of a problem derive from the seed, the key, its data set's name and fold, so they do not
        depend on which other problems are fitted with it)."""
        mask = np.ones(self.P, bool) if mask is None else mask
        old = self.results.get(key)
        if old is not None:
            mask = mask & ~old["done"]
        idx = np.nonzero(mask)[0]
        if old is None:
            old = {"phi": np.full((self.P, self.p), np.nan), "loss": np.full(self.P, np.inf),
                   "sse": np.full(self.P, np.inf), "forces": np.full((self.P, self.ctx.K), np.nan),
                   "done": np.zeros(self.P, bool)}
            self.results[key] = old
        if len(idx) == 0:
            return old
        S = max(1, int(self.s.starts if starts is None else starts))
        phi0 = np.repeat(warm[idx], S, axis=0)
        pert = np.zeros(phi0.shape)
        if S > 1:
            for a, q in enumerate(idx):
                rng = derive_rng(self.s.seed, f"gap/starts/{key!r}/{self.names[self.pds[q]]}", int(self.pfold[q]) + 1)
                pert[a * S + 1:(a + 1) * S] = rng.normal(0.0, self.s.start_spread, (S - 1, self.p))
        phi0 = phi0 + pert
        rep = lambda a: np.repeat(a[idx], S, axis=0)  # noqa: E731
        sim = self.sim(key, keep)
        grad = sim.forces_grad_phi if self.s.fit.exact_gradient else None
        own = None
        if sim.inst.J > 1:
            # candidate wrenches (direction_tolerance): an active set per data set (the candidates maximal at
            # the start or end point of any of its problems), so that its fits do not depend on the batch
            own = np.repeat(self.pds[idx], S)
            sim.refresh_rows(sim.muscles(phi0), own)
        res = fit_strengths(sim.forces_phi, rep(self.T), rep(self.W), phi0, rep(self.prior), self.s.fit, grad,
                            owner=own)
        for _ in range(self.max_rounds if own is not None else 0):
            # a data set whose problems' fits end where another candidate is maximal adds it, and its problems
            # are fitted again
            grew = np.flatnonzero(sim.refresh_rows(sim.muscles(res.phi), own))
            if grew.size == 0:
                break
            r2 = fit_strengths(sim.forces_phi, rep(self.T)[grew], rep(self.W)[grew], res.phi[grew],
                               rep(self.prior)[grew], self.s.fit, grad, owner=own[grew])
            res.phi[grew], res.loss[grew], res.sse[grew] = r2.phi, r2.loss, r2.sse
            res.forces[grew] = r2.forces
            res.iterations[grew] += r2.iterations
        if sim.inst.J > 1:
            res.forces = sim.forces_all(sim.muscles(res.phi))     # the last refresh's, if at these points
            res.loss, res.sse = _train_loss(res.forces, rep(self.T), rep(self.W), res.phi, rep(self.prior),
                                            self.s.fit.ridge)
        self.n_fits += len(phi0)
        loss = res.loss.reshape(len(idx), S)
        best = loss.argmin(axis=1)
        pick = np.arange(len(idx)) * S + best
        old["phi"][idx] = res.phi[pick]
        old["loss"][idx] = res.loss[pick]
        old["sse"][idx] = res.sse[pick]
        old["forces"][idx] = res.forces[pick]
        old["done"][idx] = True
        return old

    def evaluate_one_step(self, key: tuple, warm: np.ndarray, steps: int = 1) -> dict:
        """Approximate cross-validation: fit the all-direction problem of every data set for ``key`` (warm
        start ``warm``), then each fold's problem by ``steps`` guarded Gauss-Newton steps on the fold's own
        training loss from that fit (forward-difference Jacobian, see below). A step's trials (full step, half step, a damped step)
        are evaluated with the exact LP and the one with the lowest training loss is kept, the all-direction
        fit itself included, so a fold's training loss never rises above its value there. Needs the engine
        with ``full=True``."""
        full = self.pfold == -1
        if not full.any():
            raise ValueError("evaluate_one_step needs the all-direction problems (engine with full=True)")
        res = self.evaluate(key, warm, mask=full, keep=True)
        fold_idx = np.nonzero(~full & ~res["done"])[0]
        if fold_idx.size == 0:
            return res
        # the all-direction fit of each fold problem's data set
        full_of = np.full(self.nd, -1)
        full_of[self.pds[full]] = np.nonzero(full)[0]
        src = full_of[self.pds[fold_idx]]
        sim = self.sim(key, keep=True)
        # candidate wrenches (direction_tolerance): each data set's active set (from its all-direction fit)
        # with the candidates maximal at that fit (its folds' common start)
        us = np.unique(src)
        own_fold = self.pds[fold_idx]
        sim.refresh_rows(sim.muscles(res["phi"][us]), self.pds[us])
        T, W, prior = self.T[fold_idx], self.W[fold_idx], self.prior[fold_idx]
        lo = prior + np.log(self.s.fit.bounds_rel[0])
        hi = prior + np.log(self.s.fit.bounds_rel[1])
        ridge = self.s.fit.ridge
        phi = np.clip(res["phi"][src], lo, hi)
        A, p = phi.shape
        eye = np.eye(p)
        F = loss = sse = None
        h = self.s.fit.fd_step
        for _ in range(max(1, int(steps))):
            # forward differences, not the envelope gradient: the all-direction fit tends to end on a kink of
            # the piecewise-linear forces, where the envelope gradient depends on which optimal vertex the
            # solver returns (and so on what else is in the batch); a difference quotient over fd_step is a
            # continuous function of the point. The folds of a data set share their start: one set of LPs each.
            _, first, inv = np.unique(phi, axis=0, return_index=True, return_inverse=True)
            U = phi[first]
            sign = np.where(U + h > hi[first], -1.0, 1.0)                          # (u, p)
            Ph = np.concatenate([U[:, None, :], U[:, None, :] + h * sign[:, None, :] * eye[None]], axis=1)
            Fh = sim.forces_phi(Ph.reshape(-1, p), owner=np.repeat(own_fold[first], p + 1)
                                ).reshape(len(U), p + 1, -1)
            F0 = Fh[:, 0]
            G = ((Fh[:, 1:] - F0[:, None, :]) / (h * sign[:, :, None])).transpose(0, 2, 1)   # (u, K, p)
            F0, G = F0[inv.ravel()], G[inv.ravel()]
            if F is None:
                F = F0
                loss, sse = _train_loss(F, T, W, phi, prior, ridge)
            Jr = G / T[:, :, None]                                  # (A, K, p) relative Jacobian
            r = F0 / T - 1.0
            Jw = Jr * W[:, :, None]
            H = np.einsum("akp,akq->apq", Jw, Jr) + ridge * eye[None]
            g = np.einsum("akp,ak->ap", Jw, r) + ridge * (phi - prior)
            dg = np.einsum("app->ap", H)
            trials = []
            for mu in (0.0, 1.0):
                Hm = H + mu * dg[:, :, None] * eye[None] + 1e-9 * eye[None]
                d = -np.linalg.solve(Hm, g[..., None])[..., 0]
                trials.append(d)
                if mu == 0.0:
                    trials.append(0.5 * d)
            trial = np.clip(phi[:, None, :] + np.stack(trials, axis=1), lo[:, None], hi[:, None])   # (A, 3, p)
            nt = trial.shape[1]
            Ft = sim.forces_phi(trial.reshape(-1, p), owner=np.repeat(own_fold, nt)).reshape(A, nt, -1)
            lt, st = _train_loss(Ft.reshape(A * nt, -1), np.repeat(T, nt, 0), np.repeat(W, nt, 0),
                                 trial.reshape(A * nt, p), np.repeat(prior, nt, 0), ridge)
            lt, st = lt.reshape(A, nt), st.reshape(A, nt)
            b = lt.argmin(axis=1)
            better = lt[np.arange(A), b] < loss
            phi = np.where(better[:, None], trial[np.arange(A), b], phi)
            F = np.where(better[:, None], Ft[np.arange(A), b], F)
            loss = np.where(better, lt[np.arange(A), b], loss)
            sse = np.where(better, st[np.arange(A), b], sse)
        if sim.inst.J > 1:
            F = sim.forces_all(sim.muscles(phi))
            loss, sse = _train_loss(F, T, W, phi, prior, ridge)
        res["phi"][fold_idx] = phi
        res["loss"][fold_idx] = loss
        res["sse"][fold_idx] = sse
        res["forces"][fold_idx] = F
        res["done"][fold_idx] = True
        return res


#: CPU per grid point relative to a plain effect: the order in which the worker processes take the effects, the
#: most expensive first (measured on s3m24
#: in a participant's screen, 2026-11-24: direction_tolerance solves 11 candidate wrenches per test on refreshes,
#: finer_groups has 96 columns; the rest cost about the same per grid point).
_GRID_COST = {"direction_tolerance": 3.5, "finer_groups": 2.5}


def grid_cost(e: Effect, grid_points: int) -> float:
    """Relative cost of fitting effect ``e`` on its grid (grid points x :data:`_GRID_COST`): the order in which the
    worker processes take the effects, the most expensive first."""
    return len(e.grid(grid_points)) * _GRID_COST.get(e.name, 1.0)


def single_effect_grids(eng: Engine, effects: Sequence[Effect], say=None, tag: str = "",
                        one_step: int = 0, workers: int = 1, checkpoints=None) -> dict[str, list[tuple]]:
    """Fit every problem at every grid point of every effect (each grid point warm-started from the fits at
    the nearest point already done); returns the keys per candidate ('none' and each effect). ``one_step``
    > 0: the folds by :meth:`Engine.evaluate_one_step` with that many steps. ``workers`` > 1: the effects are
    fitted in that many forked processes, one effect at a time each, the most expensive first (a process that
    is done takes the next one, so the processes end together whatever the effects really cost); each effect's
    fits depend only on the base model's and its own, so the results are the same. ``checkpoints``
    (:class:`neckstrength.gap.store.Checkpoints`): each effect's fits are stored as they finish and taken from
    there when present (an interrupted batch resumes by effect)."""
    say = say or (lambda msg: None)
    ck = None
    if checkpoints is not None:
        ck = checkpoints.key(eng.ctx, eng.s, eng.T, eng.W, eng.prior, tag=f"grids/{one_step}/{sorted(eng.registry)}")
    mine: dict[str, list[tuple]] = {}

    def take(got) -> None:
        keys, new, nf = got
        mine.update(keys)
        eng.results.update(new)
        eng.n_fits += nf

    todo = []
    for e in effects:
        got = checkpoints.get(ck, f"grid-{e.name}") if ck is not None else None
        if got is not None:
            take(got)
            say(f"{tag}effect {e.name}: {len(mine[e.name])} grid points (resumed from {checkpoints.folder})")
        else:
            todo.append(e)

    def grids_of(e: Effect):
        """The effect's keys, its new results and its number of fits."""
        before = set(eng.results)
        n0 = eng.n_fits
        keys = _grids(eng, [e], one_step)
        return keys, {k: v for k, v in eng.results.items() if k not in before}, eng.n_fits - n0

    workers = max(1, min(int(workers), len(todo)))
    if workers > 1:
        order = sorted(todo, key=lambda e: -grid_cost(e, eng.s.grid_points))
        for i, got in fork_map(grids_of, order, workers):     # in forked processes
            name = order[i].name
            take(got)
            if ck is not None:
                checkpoints.put(ck, f"grid-{name}", got)
            say(f"{tag}effect {name}: {len(mine[name])} grid points (in a worker process; {eng.n_fits} "
                "fits so far)")
    else:
        for e in todo:
            got = grids_of(e)                  # in this process: its results and fit count are in eng already
            mine.update(got[0])
            if ck is not None:
                checkpoints.put(ck, f"grid-{e.name}", got)
            say(f"{tag}effect {e.name}: {len(mine[e.name])} grid points ({eng.n_fits} fits so far)")
    return {"none": [()], **{e.name: mine[e.name] for e in effects}}


def _grids(eng: Engine, effects: Sequence[Effect], one_step: int) -> dict[str, list[tuple]]:
    """:func:`single_effect_grids` in this process, without checkpoints or messages."""
    cand_keys: dict[str, list[tuple]] = {}
    for e in effects:
        grid = e.grid(eng.s.grid_points)
        done: list[tuple[np.ndarray, tuple]] = [(e.neutral, ())]
        span = np.maximum(e.upper - e.lower, 1e-12)
        for th in grid[1:]:
            near = min(done, key=lambda t: float(np.linalg.norm((t[0] - th) / span)))
            key = eng.key([(e.name, th)])
            if one_step:
                eng.evaluate_one_step(key, eng.results[near[1]]["phi"], one_step)
            else:
                eng.evaluate(key, eng.results[near[1]]["phi"])
            done.append((th, key))
        cand_keys[e.name] = [k for _, k in done]
    return cand_keys


def cv_predictions(eng: Engine, keys: list[tuple]) -> np.ndarray:
    """(data sets x K) held-out predictions of a candidate whose grid is ``keys`` (per problem the key with the
    lowest training loss)."""
    chosen = _selection(eng, [keys] * eng.P)
    return np.array([_cv_predictions(eng, chosen, i) for i in range(eng.nd)]).reshape(eng.nd, eng.ctx.K)


def _train_loss(F, T, W, phi, prior, ridge):
    sse = (W * (F / T - 1.0) ** 2).sum(axis=1)
    return sse + ridge * ((phi - prior) ** 2).sum(axis=1), sse


def _d(forces: np.ndarray, T: np.ndarray, eps: float) -> np.ndarray:
    return data_discrepancy(forces, T, eps)


def _selection(engine: Engine, keys_per_problem: list[list[tuple]]) -> list[tuple]:
    """Per problem, the key with the lowest training loss among its candidate keys."""
    out = []
    for p, keys in enumerate(keys_per_problem):
        losses = [engine.results[k]["loss"][p] if k in engine.results else np.inf for k in keys]
        out.append(keys[int(np.argmin(losses))])
    return out


def _cv_predictions(engine: Engine, chosen: list[tuple], i: int) -> np.ndarray:
    """Held-out prediction of every direction of data set ``i`` from its fold's chosen key."""
    K = engine.ctx.K
    pred = np.full(K, np.nan)
    for p in np.nonzero(engine.pds == i)[0]:
        f = engine.pfold[p]
        if f < 0:
            continue
        sel = engine.folds[i] == f
        pred[sel] = engine.results[chosen[p]]["forces"][p, sel]
    return pred
