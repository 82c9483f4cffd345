"""Bayes evidence of the diagnosis's explanations of a data set (issue 32; the diagnosis's decision where
``decides``, the shipped configs' choice).

The calibrated decision (:mod:`neckstrength.gap.calibrate`) asks, per candidate, whether its held-out improvement
exceeds what noise on the model's own structure gives. This module asks instead which explanation makes the
recorded forces most probable, all explanations competing at once:

- "no effect": the base model, and the base model with the element null's finer structure
  (:class:`neckstrength.gap.calibrate.ElementNull`: its mean and covariance of the log forces over draws);
- each candidate effect (:mod:`neckstrength.gap.effects`) averaged over its screen grid without the neutral point
  (a uniform prior over each parameter's range);
- ``direction_scatter``, the aiming-scatter model of :mod:`neckstrength.gap.scatter`: per test an extra log
  variance ``v_k c^2 / (2 a^2)``, ``c`` over ``scatter_cones_deg``.

Each explanation is a Gaussian in the K log forces: its clean log forces at the fitted base-model strengths, plus
the recording noise (the largest of ``repeats`` log-normal trials of log SD ``sigma``: the mean and variance of the
largest of ``repeats`` standard normals, times ``sigma``), plus strengths known only up to a log-normal factor of SD
``strength_sd``, linearised (``strength_sd^2 J J'``, J the derivative of the log forces in the log free strengths).
The prior gives "no effect" ``prior_no_effect`` (half each to its two forms) and shares the rest equally among the
effects. An effect is named when the posterior probability of "no effect" is below ``threshold`` and the effect
fits (its best chi-square p-value at least ``fit_alpha``): the posterior says which explanation is least bad, the
chi-square whether it fits at all.

Measured in ``benchmarks/bench_gap_oracle.py --families diagnosis`` (docs/benchmarks.md#gap-oracle-diagnosis).
The probabilities are heuristic: checked against the share of controls on the user benchmark's mix of truths only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy import integrate, stats
from scipy.special import logsumexp

NO_EFFECT = ("none", "none_elements")

#: explanation -> list of (clean log forces per parameter point [G x K], extra covariance [K x K]); its likelihood is
#: the average over the list's components and their rows
Signatures = dict[str, list[tuple[np.ndarray, np.ndarray]]]


@dataclass(frozen=True)
class EvidenceSettings:
    """The choices the answer depends on (each stated where it is printed): ``strength_sd`` the log SD of the
    strengths' uncertainty around the fit (linearised); ``prior_no_effect`` the prior probability of "no effect";
    ``threshold`` an effect is named below this P(no effect); ``n_grid`` points of each candidate's screen grid
    (one or two parameters), ``sample_points`` quasi-random points of its box (three or more);
    ``scatter_cones_deg`` the aiming cones of ``direction_scatter``; ``element_spread`` / ``element_draws`` the
    element null's log SD and draws; ``repeats`` trials per recorded force (the largest kept); ``fit_prior_sd``
    the base fit's prior SD of the log strength ratios; ``fit_alpha`` the named effect must also fit: its best
    chi-square p-value at least this; ``fit_starts`` random starts of the base fit besides the baseline's (log SD
    half ``fit_prior_sd``; the most probable fit is kept: from the baseline alone the damped Gauss-Newton stops at
    a kink of the max-wrench LP now and then, chi-square 36 where the true strengths give 20, and every effect
    refitted from there looks better than "no effect"); ``refit_top`` effects, the most probable at the base fit,
    refitted under themselves from the baseline, the base fit and ``refit_starts`` random starts (the others stay
    at the base fit);
    ``element_centred``: the element null's mean shift without its part in the span of the strengths' Jacobian
    (which the fitted strengths already carry; off: the shift is added to forces whose strengths were fitted to
    the data, so its strength-like part is counted twice; an experiment of 2026-11-28, not the default);
    ``decides``: the reading is the diagnosis's decision (the
    calibrated test then a second reading beside it; :func:`neckstrength.gap.diagnose.evidence_decision`)."""

    strength_sd: float = 0.3
    prior_no_effect: float = 0.5
    threshold: float = 0.05
    n_grid: int = 17
    sample_points: int = 128
    scatter_cones_deg: tuple[float, ...] = (4.0, 8.0, 12.0, 16.0, 20.0)
    element_spread: float = 0.3
    element_draws: int = 200
    repeats: int = 3
    fit_prior_sd: float = 1.0
    fit_alpha: float = 0.001
    fit_starts: int = 8
    refit_top: int = 3
    refit_starts: int = 3
    decides: bool = False
    element_centred: bool = False


def largest_of_normals(repeats: int) -> tuple[float, float]:
    """Mean and variance of the largest of ``repeats`` independent standard normals (numerical integration)."""
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, not {repeats}")

    def dens(z):
        return repeats * stats.norm.pdf(z) * stats.norm.cdf(z) ** (repeats - 1)

    m1 = integrate.quad(lambda z: z * dens(z), -np.inf, np.inf)[0]
    m2 = integrate.quad(lambda z: z * z * dens(z), -np.inf, np.inf)[0]
    return float(m1), float(m2 - m1 ** 2)


def gaussian_logpdf(y: np.ndarray, means: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``log N(y; mean_i, cov)`` for each row of ``means``."""
    L = np.linalg.cholesky(cov)
    r = np.linalg.solve(L, (np.asarray(y, float)[None, :] - np.atleast_2d(means)).T)
    return -0.5 * (r ** 2).sum(axis=0) - np.log(np.diag(L)).sum() - 0.5 * len(y) * np.log(2 * np.pi)


def log_evidence(sig: Signatures, J: np.ndarray | dict[str, np.ndarray], y: np.ndarray, sigma: float,
                 strength_sd: float, repeats: int) -> dict[str, float]:
    """Log marginal likelihood of the recorded log forces ``y`` under each explanation of ``sig`` (noise ``sigma``
    per trial, the largest of ``repeats`` kept; strengths known up to a log SD ``strength_sd`` around those the
    signatures were made at, linearised with ``J``: one matrix for all, or one per explanation)."""
    K = len(y)
    z_mean, z_var = largest_of_normals(repeats)
    shift = z_mean * sigma
    out = {}
    for name, comps in sig.items():
        Jn = J[name] if isinstance(J, dict) else J
        cov0 = strength_sd ** 2 * Jn @ Jn.T + z_var * sigma ** 2 * np.eye(K)
        lls = [gaussian_logpdf(y, mu + shift, cov0 + extra + 1e-12 * np.eye(K)) for mu, extra in comps]
        lls = [logsumexp(v) - np.log(len(v)) for v in lls]
        out[name] = float(logsumexp(lls) - np.log(len(lls)))
    return out


def best_fit_chi2(comps: list[tuple[np.ndarray, np.ndarray]], J: np.ndarray, y: np.ndarray, sigma: float,
                  strength_sd: float, repeats: int) -> float:
    """Smallest Mahalanobis distance^2 of ``y`` from one explanation's components and parameter points (under the
    same Gaussian as :func:`log_evidence`): about chi-square with K degrees of freedom where the explanation holds,
    fewer for the best of many points. A posterior says which explanation is least bad; this says whether it fits."""
    K = len(y)
    z_mean, z_var = largest_of_normals(repeats)
    cov0 = strength_sd ** 2 * J @ J.T + z_var * sigma ** 2 * np.eye(K)
    best = np.inf
    for mu, extra in comps:
        L = np.linalg.cholesky(cov0 + extra + 1e-12 * np.eye(K))
        r = np.linalg.solve(L, (np.asarray(y, float)[None, :] - np.atleast_2d(mu) - z_mean * sigma).T)
        best = min(best, float((r ** 2).sum(axis=0).min()))
    return best


def posterior(loglik: dict[str, float], logprior: dict[str, float]) -> dict[str, float]:
    """Posterior probability of each explanation (those in both dicts)."""
    lp = {t: loglik[t] + logprior[t] for t in loglik if t in logprior}
    z = logsumexp(list(lp.values()))
    return {t: float(np.exp(v - z)) for t, v in lp.items()}


def log_jacobian(base: Callable[[np.ndarray], np.ndarray], f: np.ndarray, pidx: np.ndarray,
                 eps: float = 0.01, base_rows: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """``d log force / d log free strength`` (K x p) of ``base`` at strengths ``f`` (forward differences; ``pidx``
    maps each muscle to its free strength). ``base_rows`` (optional): the same forces for many strength vectors
    (N x m -> N x K) in one call, so the p + 1 evaluations are one batch of LPs."""
    F = np.vstack([f] + [f * np.exp(eps * (pidx == j)) for j in range(int(pidx.max()) + 1)])
    L = np.log(base_rows(F) if base_rows is not None else np.array([base(x) for x in F]))
    return ((L[1:] - L[0]) / eps).T


def fit_strengths_map(base: Callable[[np.ndarray], np.ndarray], strengths0: np.ndarray, pidx: np.ndarray,
                      y: np.ndarray, sigma: float, repeats: int, prior_sd: float = 1.0,
                      iters: int = 200, base_rows: Callable[[np.ndarray], np.ndarray] | None = None,
                      start: np.ndarray | None = None, return_loss: bool = False):
    """Strengths of the base model fitted to the recorded log forces ``y``: the most probable log free strength ratios
    to ``strengths0`` under a normal prior of SD ``prior_sd``, the largest-of-trials bias removed (damped
    Gauss-Newton from ``strengths0`` scaled to the forces' mean, or from the strengths ``start``). ``return_loss``:
    also the objective at the fit (squared log residuals plus the prior's penalty, in units of sigma^2; inf where a
    force is not positive)."""
    z_mean, _ = largest_of_normals(repeats)
    t = np.asarray(y, float) - z_mean * sigma
    w = (sigma / prior_sd) ** 2
    p = int(pidx.max()) + 1

    def f_of(phi):
        return strengths0 * np.exp(phi[pidx])

    def loss(phi, r):
        return r @ r + w * phi @ phi

    if start is None:
        phi = np.full(p, float(np.mean(t - np.log(base(strengths0)))))
    else:
        s0, f0 = np.asarray(strengths0, float), np.asarray(start, float)
        phi = np.zeros(p)
        for j in range(p):
            k = (pidx == j) & (s0 > 0) & (f0 > 0)
            if k.any():
                phi[j] = float(np.mean(np.log(f0[k] / s0[k])))
    r = t - np.log(base(f_of(phi)))
    mu = 1e-2
    for _ in range(iters):
        J = log_jacobian(base, f_of(phi), pidx, base_rows=base_rows)
        H = J.T @ J + w * np.eye(p)
        new = phi + np.linalg.solve(H + mu * np.diag(np.diag(H)), J.T @ r - w * phi)
        if not np.all(np.abs(new) <= 20.0):          # a step to strengths e^20 times the baseline's: refused
            r2 = np.full_like(r, np.nan)
        else:
            with np.errstate(divide="ignore"):
                r2 = t - np.log(base(f_of(new)))
        if np.all(np.isfinite(r2)) and loss(new, r2) < loss(phi, r):
            done = loss(phi, r) - loss(new, r2) < 1e-10 * loss(phi, r)
            phi, r, mu = new, r2, mu / 3
            if done:
                break
        else:
            mu *= 10
            if mu > 1e8:
                break
    if return_loss:
        val = float(loss(phi, r))
        return f_of(phi), (val if np.isfinite(val) else np.inf)
    return f_of(phi)


@dataclass
class EvidenceResult:
    """One data set's evidence: log likelihood and posterior per explanation, the probability of "no effect", the
    most probable effect, the strengths used, and whether the most probable explanation (``best``, "no effect"
    included) fits at all: its smallest Mahalanobis distance^2 ``fit_chi2`` and the chi-square upper tail ``fit_p``
    with K degrees of freedom (approximate); ``fit_p_effect`` the same for the most probable effect. ``named``: that
    effect where P(no effect) < ``threshold`` and ``fit_p_effect`` >= ``fit_alpha``, else ``none``."""

    loglik: dict[str, float]
    posterior: dict[str, float]
    p_no_effect: float
    best_effect: str
    named: str
    strengths: np.ndarray
    settings: EvidenceSettings
    best: str = ""
    fit_chi2: float = np.nan
    fit_p: float = np.nan
    fit_p_effect: float = np.nan


def prior_points(effect, settings: EvidenceSettings) -> list[np.ndarray]:
    """The parameter points an effect's likelihood is averaged over (its uniform prior over the parameter box):
    the screen grid without the neutral point for one or two parameters (``n_grid`` per axis for one; a product
    grid for two); for three or more a scrambled Sobol sample of ``sample_points`` points of the box (a constant
    seed: a quadrature rule, not a drawn result),
    since the screen grid lies on the axes only and misses oblique parameter vectors (a submaximal-effort lobe
    pointing between the skull axes)."""
    if effect.n_params <= 2:
        return effect.grid(settings.n_grid)[1:]
    from scipy.stats import qmc

    from neckstrength.seeds import HASH_SEED, derive_rng

    rng = derive_rng(HASH_SEED, f"gap/evidence/prior/{effect.name}")
    u = qmc.Sobol(effect.n_params, scramble=True, seed=rng).random(int(settings.sample_points))
    return [np.asarray(p, float) for p in qmc.scale(u, effect.lower, effect.upper)]


class Explanations:
    """The diagnosis's explanations of one context (``ctx``: :class:`neckstrength.gap.effects.GapContext`) and
    candidate ``effects``; made once, used for many data sets of that context."""

    def __init__(self, ctx, effects: Sequence[str], settings: EvidenceSettings = EvidenceSettings()):
        from neckstrength.estimation.parameters import free_parameters
        from neckstrength.gap.calibrate import ElementNull
        from neckstrength.gap.effects import available_effects, base_instance, compose
        from neckstrength.gap.fit import Simulator

        self.ctx, self.s = ctx, settings
        self.base_sim = Simulator(ctx, base_instance(ctx))
        self.sims = {e.name: [Simulator(ctx, compose(ctx, [e], [th])) for th in prior_points(e, settings)]
                     for e in available_effects(ctx, effects)}
        self.enull = ElementNull(ctx, settings.element_spread)
        self.pidx = np.asarray(free_parameters(ctx.model, ctx.tie_sides)[0])
        d = ctx.directions
        self.P = d[["px", "py", "pz"]].to_numpy(float)
        N = d[["nx", "ny", "nz"]].to_numpy(float)
        self.N = N / np.linalg.norm(N, axis=1, keepdims=True)

    @property
    def names(self) -> list[str]:
        return [*NO_EFFECT, *self.sims, "direction_scatter"]

    def logprior(self) -> dict[str, float]:
        n_eff = len(self.names) - len(NO_EFFECT)
        p0 = self.s.prior_no_effect
        return {t: float(np.log(p0 / len(NO_EFFECT) if t in NO_EFFECT else (1 - p0) / n_eff)) for t in self.names}

    def base(self, f: np.ndarray) -> np.ndarray:
        return self.base_sim.forces(np.asarray(f, float)[None, :])[0]

    def base_rows(self, F: np.ndarray) -> np.ndarray:
        return self.base_sim.forces(np.atleast_2d(np.asarray(F, float)))

    def fit(self, y: np.ndarray, sigma: float, rng: np.random.Generator | None = None, one=None, many=None,
            starts: Sequence[np.ndarray] = (), n_random: int | None = None, return_all: bool = False):
        """The most probable strengths of the base model (or of the model whose forces ``one`` / ``many`` give):
        from the baseline scaled to the forces, from each of ``starts`` and, with ``rng``, from ``n_random``
        (default ``fit_starts``) random starts around the baseline; the fit of the smallest MAP objective
        (``return_all``: every fit as ``(strengths, loss)``, in start order)."""
        one, many = one or self.base, many or self.base_rows
        s0 = self.ctx.model.strengths

        def run(st=None):
            return fit_strengths_map(one, s0, self.pidx, y, sigma, self.s.repeats, self.s.fit_prior_sd,
                                     base_rows=many, start=st, return_loss=True)

        fits = [run()] + [run(np.asarray(st, float)) for st in starts]
        n = int(self.s.fit_starts if n_random is None else n_random)
        if rng is not None and n > 0:
            p = int(self.pidx.max()) + 1
            lvl = float(np.mean(np.asarray(y, float) - np.log(one(s0))))
            for _ in range(n):
                fits.append(run(s0 * np.exp(lvl + rng.normal(0.0, 0.5 * self.s.fit_prior_sd, p))[self.pidx]))
        return fits if return_all else min(fits, key=lambda fl: fl[1])[0]

    def signatures(self, f: np.ndarray, rng: np.random.Generator) -> Signatures:
        """Every explanation's component(s) at strengths ``f`` (see the module docstring). Sets :attr:`live`: per
        effect, the simulators of the prior points whose forces were all positive (the rows of its component)."""
        from neckstrength.gap.scatter import ScatterSettings, direction_sensitivity

        K = len(self.N)
        zero = np.zeros((K, K))
        F = np.asarray(f, float)[None, :]
        lb = np.log(self.base(f))
        out: Signatures = {"none": [(lb[None, :], zero)]}
        self.live = {}
        for name, sims in self.sims.items():
            with np.errstate(divide="ignore"):
                rows = np.log(np.array([sim.forces(F)[0] for sim in sims]))
            ok = np.all(np.isfinite(rows), axis=1)
            if ok.any():
                out[name] = [(rows[ok], zero)]
                self.live[name] = [sim for sim, k in zip(sims, ok) if k]
        ss = ScatterSettings()
        v = direction_sensitivity(self.ctx.model, f, self.P, self.N, ss)
        a = np.radians(ss.ring_deg)
        out["direction_scatter"] = [(lb[None, :], np.diag(v * c ** 2 / (2 * a ** 2)))
                                    for c in np.radians(np.asarray(self.s.scatter_cones_deg, float))]
        n = self.s.element_draws
        with np.errstate(divide="ignore"):
            d = np.log(np.maximum(self.enull.forces(np.repeat(F, n, axis=0), self.enull.factors(n, rng)),
                                  1e-300)) - lb
        d = d[np.all(np.isfinite(d) & (d > -20), axis=1)]
        out["none_elements"] = [((lb + d.mean(axis=0))[None, :], np.cov(d.T))]
        return out

    def refit(self, name: str, sig: Signatures, J: np.ndarray, f: np.ndarray, y: np.ndarray,
              sigma: float, rng: np.random.Generator | None = None,
              n_random: int = 0) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
        """Effect ``name``'s component and Jacobian at strengths refitted under it: at its most likely prior point
        (linearised around the base fit ``f``), the strengths are fitted again with the effect applied (same prior
        as the base fit; from the baseline, from ``f`` and from ``n_random`` random starts), and the effect's log
        forces over all its prior points and the Jacobian are made again at those strengths. Without this a large
        effect (a left/right ratio of 2) is judged at strengths that the base fit bent towards it, and neither fits
        nor wins."""
        z_mean, z_var = largest_of_normals(self.s.repeats)
        K = len(y)
        rows = sig[name][0][0]
        cov = self.s.strength_sd ** 2 * J @ J.T + z_var * sigma ** 2 * np.eye(K)
        k = int(np.argmax(gaussian_logpdf(y, rows + z_mean * sigma, cov)))
        sims = self.live[name]
        best = sims[k]

        def one(x):
            return best.forces(np.asarray(x, float)[None, :])[0]

        def many(X):
            return best.forces(np.atleast_2d(np.asarray(X, float)))

        f2 = self.fit(y, sigma, rng, one, many, starts=[f], n_random=n_random)
        F = np.asarray(f2, float)[None, :]
        with np.errstate(divide="ignore"):
            rows2 = np.log(np.array([sim.forces(F)[0] for sim in sims]))
        rows2 = rows2[np.all(np.isfinite(rows2), axis=1)]
        return [(rows2, np.zeros((K, K)))], log_jacobian(one, f2, self.pidx, base_rows=many)

    def explain(self, y: np.ndarray, sigma: float, rng: np.random.Generator,
                strengths: np.ndarray | None = None) -> tuple[np.ndarray, Signatures, dict[str, np.ndarray]]:
        """The base-model strengths (fitted when None), every explanation's signature and its Jacobian: "no
        effect", its element null and the aiming scatter at the base fit, each effect at strengths refitted
        under it (:meth:`refit`): the ``refit_top`` most probable effects at the base fit, from the baseline, the
        base fit and ``refit_starts`` random starts; the others stay at the base fit (less probable there than
        those refitted, they are not the answer's contenders)."""
        f = self.fit(y, sigma, rng) if strengths is None else np.asarray(strengths, float)
        sig, J = self.signatures(f, rng), log_jacobian(self.base, f, self.pidx, base_rows=self.base_rows)
        if self.s.element_centred and "none_elements" in sig:
            (mu, cov), = sig["none_elements"]
            lb = np.log(self.base(f))
            d = mu[0] - lb
            d = d - J @ np.linalg.lstsq(J, d, rcond=None)[0]
            sig["none_elements"] = [((lb + d)[None, :], cov)]
        Js = {t: J for t in sig}
        names = [n for n in self.sims if n in sig]
        ll0 = log_evidence({n: sig[n] for n in names}, J, y, sigma, self.s.strength_sd, self.s.repeats)
        top = set(sorted(names, key=lambda n: -ll0[n])[:int(self.s.refit_top)])
        for name in names:
            if name in top:
                sig[name], Js[name] = self.refit(name, sig, J, f, y, sigma, rng, int(self.s.refit_starts))
        return f, sig, Js

    def evidence(self, forces: np.ndarray, sigma: float, rng: np.random.Generator,
                 strengths: np.ndarray | None = None, strength_sd: float | None = None) -> EvidenceResult:
        """The evidence of one data set's recorded forces (N, the largest of ``repeats`` trials per test) with noise
        ``sigma`` (log SD of one trial); ``strengths``: the base model's (fitted here when None)."""
        y = np.log(np.asarray(forces, float))
        sd = self.s.strength_sd if strength_sd is None else float(strength_sd)
        f, sig, Js = self.explain(y, sigma, rng, strengths)
        ll = log_evidence(sig, Js, y, sigma, sd, self.s.repeats)
        post = posterior(ll, self.logprior())
        p0 = sum(post.get(t, 0.0) for t in NO_EFFECT)
        effects = {t: v for t, v in post.items() if t not in NO_EFFECT}
        beff = max(effects, key=effects.get)
        best = max(post, key=post.get)
        chi2 = best_fit_chi2(sig[best], Js[best], y, sigma, sd, self.s.repeats)
        p_eff = float(stats.chi2.sf(best_fit_chi2(sig[beff], Js[beff], y, sigma, sd, self.s.repeats), len(y)))
        named = beff if (p0 < self.s.threshold and p_eff >= self.s.fit_alpha) else "none"
        return EvidenceResult(ll, post, p0, beff, named, f, self.s, best, chi2, float(stats.chi2.sf(chi2, len(y))),
                              p_eff)
