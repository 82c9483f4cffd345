"""Beyond the thesis (Chapter 5): ABC-SMC that frees every muscle, and posterior coverage checks.

:func:`abc_smc` is a population Monte Carlo ABC sampler (Beaumont et al. 2009; Del Moral et al. 2012 style
adaptive tolerances): particles in log-strength space, a Gaussian perturbation kernel with twice the
weighted particle covariance, importance weights prior / mixture-of-kernels, and the tolerance of each
generation set to a quantile of the previous generation's distances. The distance is ``1 - D(f)`` with the
thesis's composite score (Eq. 5.5/5.6), so both estimators chase the same fit. Unlike Algorithm 4 it needs
no left/right tie: every muscle is free. It stops when its simulation budget (candidate evaluations, each
over all directions) is spent, so it can be compared with Algorithm 4 at equal budget.

:func:`coverage_check` repeats Algorithm 4 on simulated data sets with multiplicative measurement noise and
counts how often the true strength lies inside the reported spread ``f_c (1 +- sigma_c)`` (Sec. 7.1.3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from neckstrength.estimation.datasets import Dataset
from neckstrength.estimation.discrepancy import composite_score, data_discrepancy
from neckstrength.model.reduction import ReducedModel
from neckstrength.wrench import solve


@dataclass(frozen=True)
class SMCSettings:
    n_particles: int = 2000
    budget: int = 200_000            # candidate evaluations (each = one LP per direction)
    prior_sigma: float = 0.3         # prior: log-normal around f_0 with this log-sd (~ thesis sigma_0)
    quantile: float = 0.5            # next tolerance = this quantile of current distances
    epsilon: float = 3.0             # Eq. 5.5
    min_accept: float = 0.02         # stop early if a generation's acceptance rate falls below this


@dataclass
class SMCResult:
    particles: np.ndarray            # (N, m) strengths
    weights: np.ndarray              # (N,)
    distances: np.ndarray            # (N,) 1 - D
    generations: pd.DataFrame
    n_simulations: int

    def mean(self) -> np.ndarray:
        return np.average(self.particles, axis=0, weights=self.weights)

    def quantiles(self, qs=(0.05, 0.5, 0.95)) -> np.ndarray:
        out = np.zeros((len(qs), self.particles.shape[1]))
        order = np.argsort(self.particles, axis=0)
        for j in range(self.particles.shape[1]):
            x = self.particles[order[:, j], j]
            cw = np.cumsum(self.weights[order[:, j]])
            cw /= cw[-1]
            out[:, j] = np.interp(qs, cw, x)
        return out


def _distance(model, F, data, eps, cache):
    if getattr(data, "postures", None) is not None and hasattr(model, "wrenches"):
        # (posture, direction) tests (issue 20): a neckstrength.postures.PostureSet solves one posture at a time
        w, _, _ = model.wrenches(F, data.U, data.postures, data.alpha_lb, data.alpha_ub, cache=cache)
    elif any(p != "neutral" for p in (getattr(data, "postures", None) or ())):
        raise ValueError(f"data set {data.name} has tests in other postures: pass a PostureSet as the model")
    else:
        w, _, _ = solve(model, F, data.U, data.alpha_lb, data.alpha_ub, return_alpha=False, cache=cache)
    return 1.0 - composite_score(data_discrepancy(w, data.w_meas[None, :], eps))


def abc_smc(model: ReducedModel, data: Dataset, f0: np.ndarray, settings: SMCSettings,
            rng: np.random.Generator, progress=None) -> SMCResult:
    """ABC-SMC over all ``model.m`` strengths (log space), prior log-normal(log f0, prior_sigma)."""
    from neckstrength.wrench.batched import BasisCache

    s = settings
    cache = BasisCache()
    m = len(f0)
    mu = np.log(f0)
    N = s.n_particles

    def log_prior(x):
        return -0.5 * (((x - mu) / s.prior_sigma) ** 2).sum(axis=1)

    x = mu + s.prior_sigma * rng.standard_normal((N, m))
    dist = _distance(model, np.exp(x), data, s.epsilon, cache)
    n_sim = N
    wts = np.full(N, 1.0 / N)
    gens = [{"generation": 0, "tolerance": np.inf, "accept_rate": 1.0, "n_sim": n_sim,
             "median_distance": float(np.median(dist)), "min_distance": float(dist.min())}]
    g = 0
    while n_sim < s.budget:
        g += 1
        tol = float(np.quantile(dist, s.quantile))
        cov = 2.0 * np.cov(x.T, aweights=wts) + 1e-12 * np.eye(m)
        L = np.linalg.cholesky(cov)
        inv = np.linalg.inv(cov)
        new_x, new_d = [], []
        tried = 0
        while sum(len(a) for a in new_x) < N and n_sim < s.budget:
            batch = min(max(N, 1024), s.budget - n_sim)
            idx = rng.choice(N, size=batch, p=wts)
            prop = x[idx] + rng.standard_normal((batch, m)) @ L.T
            d = _distance(model, np.exp(prop), data, s.epsilon, cache)
            n_sim += batch
            tried += batch
            ok = d <= tol
            new_x.append(prop[ok])
            new_d.append(d[ok])
            if tried > 5 * N and sum(len(a) for a in new_x) / tried < s.min_accept:
                break
        nx = np.concatenate(new_x)[:N]
        nd = np.concatenate(new_d)[:N]
        if len(nx) < max(10, m + 2):
            gens.append({"generation": g, "tolerance": tol, "accept_rate": len(nx) / max(tried, 1), "n_sim": n_sim,
                         "median_distance": float(np.median(dist)), "min_distance": float(dist.min()),
                         "stopped": "too few accepted"})
            break
        diff = nx[:, None, :] - x[None, :, :]
        kern = np.exp(-0.5 * np.einsum("abi,ij,abj->ab", diff, inv, diff))
        denom = kern @ wts
        lw = log_prior(nx) - np.log(np.maximum(denom, 1e-300))
        nw = np.exp(lw - lw.max())
        x, dist, wts = nx, nd, nw / nw.sum()
        gens.append({"generation": g, "tolerance": tol, "accept_rate": len(nx) / max(tried, 1), "n_sim": n_sim,
                     "median_distance": float(np.median(dist)), "min_distance": float(dist.min()),
                     "ess": float(1.0 / (wts ** 2).sum())})
        if progress:
            progress(f"[smc {model.name}/{data.name}] generation {g}: tolerance {tol:.4f}, accepted {len(nx)}/{tried}, "
                     f"simulations {n_sim}/{s.budget}, median distance {np.median(dist):.4f}")
    return SMCResult(np.exp(x), wts, dist, pd.DataFrame(gens), n_sim)
