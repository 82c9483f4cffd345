"""Chapter 5: ABC strength estimation with importance sampling (thesis Algorithm 4).

Pieces (each with its equation):

- :func:`data_discrepancy`  Eq. 5.5, Gaussian RBF of the relative wrench error
- :func:`composite_score`   Eq. 5.6, mean over directions
- :func:`candidate_grid`    Eq. 5.4 and "every unique permutation": 3^m' candidates
- :func:`muscle_posterior`  Eqs. 5.7-5.9, activation-weighted discrete posterior per free parameter
- :func:`update_estimate`   Eqs. 5.10-5.12, expected value and spread update (sigma clipped)
- :func:`estimate_strengths` the loop, with rejection at the q-th percentile of D_k, convergence
  ``min D_k > eps_D`` or ``maxIter``, a checkpoint after every iteration and progress lines.

Free parameters: for s3m24 the thesis ties left and right strengths during sampling (Sec. 5.3.2.1);
``tie_sides=True`` makes each L/R pair one free parameter whose activation weight is the sum of both
sides' activations. The simulator is :func:`neckstrength.wrench.solve` (exact).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from neckstrength.estimation.datasets import Dataset
from neckstrength.estimation.discrepancy import composite_score, data_discrepancy
from neckstrength.estimation.parameters import free_parameters
from neckstrength.model.reduction import ReducedModel
from neckstrength.wrench import solve
from neckstrength.wrench.problem import STATUS_CODES


@dataclass(frozen=True)
class ABCSettings:
    """Algorithm 4 settings; defaults are the thesis values where it states them."""

    sigma0: float = 0.2                # Sec. 5.3.2.2 (spatial); 0.3 for planar (Sec. 5.3.1.2)
    epsilon: float = 3.0               # Eq. 5.5 shape parameter
    q: float = 90.0                    # rejection percentile (not stated; Fig. 5.3 suggests the 90th)
    eps_D: float = 0.95                # convergence: min D_k > eps_D
    max_iter: int = 20                 # 30 for p2m7, 20 otherwise
    sigma_min: float = 0.01            # Sec. 5.2.2.7 clip
    sigma_max: float = 0.3
    tie_sides: bool = False            # s3m24: left = right during sampling (Sec. 5.3.2.1)
    store_candidates: int = 3000       # candidates (with D_k) kept per iteration for Fig. 5.3


def candidate_grid(f_c: np.ndarray, sigma_c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 5.4 samples and all 3^m' combinations.

    ``f_c``, ``sigma_c``: (m',). Returns ``samples`` (3, m') = [f(1-s), f, f(1+s)], the combination
    index ``P`` (3^m', m') with values 0, 1, 2, and the candidate parameter vectors (3^m', m').
    """
    mp = len(f_c)
    samples = np.vstack([f_c * (1 - sigma_c), f_c, f_c * (1 + sigma_c)])
    P = np.indices((3,) * mp, dtype=np.int8).reshape(mp, -1).T
    theta = samples[P, np.arange(mp)[None, :]]
    return samples, P, theta


def muscle_posterior(weights: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Eqs. 5.7-5.9 for accepted candidates.

    ``weights`` (N', m'): sum over directions of activation x discrepancy for each free parameter;
    ``P`` (N', m'): which of the 3 samples each candidate used. Returns pi (m', 3); a parameter with
    zero total weight (never active) gets the uniform distribution.
    """
    mp = P.shape[1]
    phi = np.zeros((mp, 3))
    for j in range(mp):
        phi[j] = np.bincount(P[:, j], weights=weights[:, j], minlength=3)
    tot = phi.sum(axis=1, keepdims=True)
    return np.where(tot > 0, phi / np.where(tot > 0, tot, 1.0), 1.0 / 3.0)


def update_estimate(samples: np.ndarray, pi: np.ndarray, sigma_prev: np.ndarray, sigma_min: float,
                    sigma_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. 5.10-5.12: ``f_c = sum_p f_p pi_p``; ``sigma_c = K sigma_{c-1}`` clipped.

    ``K = 1 - Delta`` if the middle sample is (one of) the most probable, else ``1 + exp(-5 Delta - 1)``,
    ``Delta = max(pi) - min(pi)``.
    """
    f_c = (samples.T * pi).sum(axis=1)
    delta = pi.max(axis=1) - pi.min(axis=1)
    middle_best = pi[:, 1] >= pi.max(axis=1) - 1e-15
    K = np.where(middle_best, 1.0 - delta, 1.0 + np.exp(-5.0 * delta - 1.0))
    return f_c, np.clip(K * sigma_prev, sigma_min, sigma_max)


@dataclass
class ABCResult:
    model: str
    dataset: str
    param_names: list[str]
    muscle_names: list[str]
    f0: np.ndarray
    scale_a: float
    f_c: np.ndarray                  # (m',) final point estimate
    sigma_c: np.ndarray              # (m',)
    D_fc: float                      # composite score of the final point estimate
    iterations: int
    converged: bool
    history: pd.DataFrame            # iteration x parameter: f_low, f_c, f_high, sigma, pi
    scores: pd.DataFrame             # per iteration: D_k quantiles, min, accepted count, time
    dk_hist: pd.DataFrame            # per iteration histogram of D_k
    d_final: pd.DataFrame            # per direction: quantiles of d_{i,k} over candidates, last iteration
    fit: pd.DataFrame                # per direction: measured vs simulated at f_c
    candidates: pd.DataFrame         # sampled candidates with D_k percentile (Fig. 5.3)
    settings: dict = field(default_factory=dict)


_THREADS = {"n": 1}


def _simulate(model, F, data, chunk, return_alpha, cache=None):
    if getattr(data, "postures", None) is not None and hasattr(model, "wrenches"):
        # (posture, direction) tests (issue 20): a neckstrength.postures.PostureSet solves one posture at a time
        return model.wrenches(F, data.U, data.postures, data.alpha_lb, data.alpha_ub, return_alpha=return_alpha,
                              cache=cache, n_threads=_THREADS["n"])
    if any(p != "neutral" for p in (getattr(data, "postures", None) or ())):
        raise ValueError(f"data set {data.name} has tests in other postures: pass a PostureSet as the model")
    return solve(model, F, data.U, data.alpha_lb, data.alpha_ub, return_alpha=return_alpha,
                            chunk_size=chunk, cache=cache, n_threads=_THREADS["n"])


def _settings_key(model: ReducedModel, data: Dataset, s: ABCSettings, f0: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in (model.moment_arms, model.JT, model.strengths, data.U, data.w_meas, f0):
        h.update(np.ascontiguousarray(a, float).tobytes())
    for a in (data.alpha_lb, data.alpha_ub):
        h.update(b"none" if a is None else np.ascontiguousarray(a, float).tobytes())
    h.update(json.dumps(asdict(s), sort_keys=True).encode())
    return h.hexdigest()[:16]


def estimate_strengths(model: ReducedModel, data: Dataset, settings: ABCSettings, f0: np.ndarray,
                       scale_a: float = float("nan"), rng: np.random.Generator | None = None,
                       checkpoint: str | Path | None = None, progress: Callable[[str], None] | None = print,
                       chunk: int = 65536, n_threads: int = 1) -> ABCResult:
    """Run Algorithm 4 from the prior point estimate ``f0`` (model muscles).

    ``rng`` only subsamples the candidates stored for plotting (the algorithm itself is deterministic); without it
    the stored candidates are evenly spaced over each iteration's draws (no random stream).
    ``checkpoint``: a .npz file written after every iteration; a later call with identical inputs
    resumes from it (an interrupted run loses at most one iteration).
    """
    try:
        from neckstrength.wrench.batched import BasisCache
    except ImportError:  # pragma: no cover - reference solver only
        BasisCache = lambda: None  # noqa: E731

    s = settings
    _THREADS["n"] = max(1, int(n_threads))  # directions solved in parallel threads (same results)
    pidx, pnames = free_parameters(model, s.tie_sides)
    mp = len(pnames)
    # parameter value = strength of (either) muscle of the parameter; tied sides start from their mean
    counts = np.bincount(pidx, minlength=mp)
    theta = np.bincount(pidx, weights=f0, minlength=mp) / counts
    sigma = np.full(mp, s.sigma0)
    K = len(data.directions)
    key = _settings_key(model, data, s, f0)
    hist_rows, score_rows, dk_rows, cand_rows = [], [], [], []
    start_iter = 0
    d_sum = None                       # the last iteration's per-direction d summary (5 quantiles and the mean)
    if checkpoint is not None and Path(checkpoint).exists():
        ck = np.load(checkpoint, allow_pickle=False)
        if str(ck["key"]) == key and "rng_state" not in ck.files:
            if progress:
                progress(f"[{model.name}/{data.name}] {checkpoint} is of an older format (no generator state): "
                         "starting over")
        elif str(ck["key"]) == key:
            # everything an uninterrupted run would hold after this iteration: the updated estimate, the tables,
            # the generator of the stored candidates and the iteration's d summary (not recomputed from the
            # updated estimate), so that the resumed run is identical to one that never stopped
            theta, sigma, start_iter = ck["theta"], ck["sigma"], int(ck["iteration"])
            tables = json.loads(str(ck["tables"]))
            hist_rows, score_rows, dk_rows, cand_rows = (tables[k] for k in ("hist", "score", "dk", "cand"))
            state = json.loads(str(ck["rng_state"]))
            if rng is not None and state is not None:
                rng.bit_generator.state = state
            d_sum = ck["d_sum"]
            if progress:
                progress(f"[{model.name}/{data.name}] resuming after iteration {start_iter} from {checkpoint}")
    bins = np.linspace(0, 1, 41)
    converged = bool(score_rows and score_rows[-1]["converged"])
    it = start_iter
    while not converged and it < s.max_iter:
        it += 1
        t0 = time.time()
        # the solver's basis cache lives for one iteration (its two passes share it): a warm start changes the
        # last digit of a wrench, so a cache kept across iterations would make a resumed run differ from an
        # uninterrupted one
        cache = BasisCache()
        samples, P, th = candidate_grid(theta, sigma)
        F = th[:, pidx]
        w, _, status = _simulate(model, F, data, chunk, False, cache)
        d = data_discrepancy(w, data.w_meas[None, :], s.epsilon)
        D = composite_score(d)
        d_sum = np.vstack([np.percentile(d, [5, 25, 50, 75, 95], axis=0), d.mean(axis=0)[None, :]])
        thr = np.percentile(D, s.q)
        acc = np.nonzero(D >= thr)[0]
        # activations only for the accepted candidates (Eq. 5.7), accumulated in chunks
        weights = np.zeros((len(acc), mp))
        for a0 in range(0, len(acc), chunk):
            sel = acc[a0:a0 + chunk]
            _, alpha, _ = _simulate(model, F[sel], data, chunk, True, cache)
            per_muscle = np.einsum("kij,ki->kj", np.nan_to_num(alpha), d[sel])
            weights[a0:a0 + len(sel)] = np.stack([per_muscle[:, pidx == j].sum(axis=1) for j in range(mp)], 1)
        pi = muscle_posterior(weights, P[acc])
        for j in range(mp):
            hist_rows.append({"iteration": it, "parameter": pnames[j], "f_low": samples[0, j], "f_c": samples[1, j],
                              "f_high": samples[2, j], "sigma": sigma[j], "pi_low": pi[j, 0], "pi_mid": pi[j, 1],
                              "pi_high": pi[j, 2]})
        theta, sigma = update_estimate(samples, pi, sigma, s.sigma_min, s.sigma_max)
        converged = bool(D.min() > s.eps_D)
        qs = np.percentile(D, [5, 25, 50, 75, 95])
        score_rows.append({"iteration": it, "n_candidates": len(D), "n_accepted": int(len(acc)),
                           "threshold": float(thr), "D_min": float(D.min()), "D_q05": qs[0], "D_q25": qs[1],
                           "D_median": qs[2], "D_q75": qs[3], "D_q95": qs[4], "D_max": float(D.max()),
                           "n_not_producible": int((status != 0).sum()), "seconds": time.time() - t0,
                           "converged": converged})
        counts_h, _ = np.histogram(D, bins=bins)
        dk_rows += [{"iteration": it, "bin_low": bins[b], "bin_high": bins[b + 1], "count": int(counts_h[b])}
                    for b in range(len(counts_h))]
        n_keep = min(s.store_candidates, len(D))
        keep = (rng.choice(len(D), size=n_keep, replace=False) if rng is not None
                else np.unique(np.linspace(0, len(D) - 1, n_keep).round().astype(int)) if n_keep else np.arange(0))
        pct = 100.0 * (np.argsort(np.argsort(D)) + 0.5) / len(D)
        for k in keep:
            row = {"iteration": it, "D_k": float(D[k]), "percentile": float(pct[k])}
            row.update({pnames[j]: float(th[k, j]) for j in range(mp)})
            cand_rows.append(row)
        if progress:
            progress(f"[{model.name}/{data.name}] iteration {it}/{s.max_iter}: {len(D)} candidates x {K} directions "
                     f"in {time.time() - t0:.1f} s; min D_k {D.min():.3f}, median {qs[2]:.3f}, max {D.max():.3f}"
                     + ("; converged" if converged else ""))
        if checkpoint is not None:
            tables = json.dumps({"hist": hist_rows, "score": score_rows, "dk": dk_rows, "cand": cand_rows},
                                default=float)
            tmp = Path(str(checkpoint) + ".tmp.npz")
            np.savez(tmp, key=key, theta=theta, sigma=sigma, iteration=it, tables=tables, d_sum=d_sum,
                     rng_state=json.dumps(rng.bit_generator.state if rng is not None else None))
            os.replace(tmp, checkpoint)
    # final point estimate and its fit (from a fresh cache, as after a resume)
    cache = BasisCache()
    f_c_muscles = theta[pidx]
    w_fc, _, st_fc = _simulate(model, f_c_muscles[None, :], data, chunk, False, cache)
    d_fc = data_discrepancy(w_fc[0], data.w_meas, s.epsilon)
    fit = pd.DataFrame({"direction": data.directions, "measured_N": data.forces,
                        "simulated_N": w_fc[0] / data.force_scale, "d": d_fc,
                        "status": [STATUS_CODES[int(x)] for x in st_fc[0]]})
    if d_sum is None:  # max_iter 0: the candidates of the prior estimate
        samples, P, th = candidate_grid(theta, sigma)
        w, _, _ = _simulate(model, th[:, pidx], data, chunk, False, cache)
        d = data_discrepancy(w, data.w_meas[None, :], s.epsilon)
        d_sum = np.vstack([np.percentile(d, [5, 25, 50, 75, 95], axis=0), d.mean(axis=0)[None, :]])
    d_final = pd.DataFrame({"direction": data.directions, "d_q05": d_sum[0], "d_q25": d_sum[1],
                            "d_median": d_sum[2], "d_q75": d_sum[3], "d_q95": d_sum[4], "d_mean": d_sum[5]})
    return ABCResult(model.name, data.name, pnames, list(model.muscle_names), f0, scale_a, theta, sigma,
                     float(composite_score(d_fc)), it, converged, pd.DataFrame(hist_rows), pd.DataFrame(score_rows),
                     pd.DataFrame(dk_rows), d_final, fit, pd.DataFrame(cand_rows), asdict(s))
