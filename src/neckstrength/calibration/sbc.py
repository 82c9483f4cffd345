"""Simulation-based calibration (SBC) of the strength estimators that report an uncertainty.

For each simulated participant ``i`` a true strength vector ``f_i`` is drawn from the method's own prior around a
reference ``f_ref`` (the thesis's healthy 'norm' strengths), its maximum forces in every direction are simulated
with the exact simulator (:func:`neckstrength.wrench.solve`) and multiplied by log-normal measurement noise
(forces only, no EMG), and the method is run on them. A calibrated posterior puts the truth at a uniformly
distributed rank: the probability integral transform ``u = P_post(f < f_true)`` (the continuous rank; weighted
particles for the sample-based methods) is U(0, 1), and a central ``L`` interval (``|u - 1/2| <= L/2``) covers the
truth in a share ``L`` of the participant-muscles (Talts et al. 2018).

Methods (``METHODS``):

- ``alg4``: thesis Algorithm 4 (:func:`neckstrength.abc.estimate_strengths`) with its prior point estimate from
  the bootstrap scaling (Eq. 5.3) of the same data. It reports ``f_c`` and the spread ``sigma_c``, a sampling-width
  heuristic rather than a posterior width. To give it the most favourable reading, ``f_c (1 +- z sigma_c)`` is
  treated as a normal interval (``u = Phi((f_true - f_c) / (sigma_c f_c))``); ``covered_reported`` is the
  interval the thesis prints, ``f_c (1 +- sigma_c)``. Its truths are drawn from the same log-normal prior as
  ``smc`` (Algorithm 4 states none).
- ``smc``: ABC-SMC (:func:`neckstrength.abc.abc_smc`) with prior log-normal(log f_ref, prior_sigma) per muscle.
- ``joint``: the joint sequential posterior (:class:`neckstrength.sequential.joint.JointPosterior`) with prior
  ``N(f_ref, (prior_sd_rel f_ref)^2)`` truncated at 0, tests in a random order (drawn independently of the data,
  so the posterior after ``t`` tests is a proper posterior given those tests), read after every ``t`` in
  ``checkpoints`` (capped at the number of directions).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np
import pandas as pd
from scipy.stats import norm

from neckstrength.abc.algorithm4 import ABCSettings, estimate_strengths
from neckstrength.abc.smc import SMCSettings, abc_smc
from neckstrength.estimation.datasets import Dataset, model_directions_table
from neckstrength.estimation.parameters import free_parameters
from neckstrength.estimation.scaling import bootstrap_prior
from neckstrength.model.reduction import ReducedModel
from neckstrength.sequential.algorithms import sample_prior
from neckstrength.sequential.joint import JointPosterior, JointSettings
from neckstrength.wrench import solve
from neckstrength.wrench.problem import STATUS_CODES

METHODS = ("alg4", "smc", "joint")
LEVELS = (0.5, 0.9)
_OPT = {v: k for k, v in STATUS_CODES.items()}["optimal"]


@dataclass(frozen=True)
class SBCSettings:
    """Sizes of one SBC run (config section ``calibration``; none of this is in the thesis)."""

    n_participants: int = 100
    noise: float = 0.05                       # log-sd of the multiplicative measurement noise on every force
    methods: tuple[str, ...] = METHODS
    checkpoints: tuple[int, ...] = (5, 10, 25)   # joint: tests after which the posterior is read
    bootstrap_direction: str = "back"         # alg4: Eq. 5.3 scaling direction

    def __post_init__(self):
        bad = [m for m in self.methods if m not in METHODS]
        if bad:
            raise ValueError(f"unknown SBC method(s) {bad}; known: {METHODS}")
        if self.n_participants < 1 or self.noise < 0:
            raise ValueError("n_participants must be >= 1 and noise >= 0")


def muscle_group(name: str) -> str:
    """Group of a muscle: the name without its side suffix (s3m24 'mf-R' -> 'mf')."""
    return name[:-2] if name.endswith(("-R", "-L")) else name


def draw_truth(f_ref: np.ndarray, prior: str, sd: float, rng: np.random.Generator) -> np.ndarray:
    """One strength vector from a method's prior: 'lognormal' (log-sd ``sd``) or 'truncnormal' (sd ``sd f_ref``)."""
    f_ref = np.asarray(f_ref, float)
    if prior == "lognormal":
        return f_ref * np.exp(sd * rng.standard_normal(len(f_ref)))
    if prior == "truncnormal":
        return sample_prior(f_ref, sd, 1, rng)[0]
    raise ValueError(f"unknown prior {prior!r}")


def draw_participant(model: ReducedModel, directions: pd.DataFrame, f_ref: np.ndarray, prior: str, sd: float,
                     noise: float, rng: np.random.Generator, name: str = "sbc", max_tries: int = 100
                     ) -> tuple[np.ndarray, Dataset]:
    """A true strength vector from the prior and its noisy simulated forces (redrawn while some direction is not
    producible, which conditions the prior on producibility; with positive strengths every direction is)."""
    d, U = model_directions_table(model, directions)
    scale = d["force_scale"].to_numpy(float)
    for _ in range(max_tries):
        f = draw_truth(f_ref, prior, sd, rng)
        w, _, st = solve(model, f[None, :], U, return_alpha=False)
        if np.all(st[0] == _OPT) and np.all(w[0] > 0):
            w_meas = w[0] * np.exp(noise * rng.standard_normal(len(U)))
            return f, Dataset(name, list(d["name"]), U, w_meas, scale, None, None, f)
    raise RuntimeError(f"no producible strength vector in {max_tries} draws from the {prior} prior")


def weighted_pit(samples: np.ndarray, weights: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Continuous rank of ``truth`` (m,) among weighted ``samples`` (N, m): P(f < truth) + P(f = truth) / 2."""
    w = np.asarray(weights, float) / np.sum(weights)
    below = (samples < truth[None, :]).astype(float)
    tie = (samples == truth[None, :]).astype(float)
    return w @ below + 0.5 * (w @ tie)


def weighted_quantiles(samples: np.ndarray, weights: np.ndarray, qs: Sequence[float]) -> np.ndarray:
    """(len(qs), m) weighted quantiles (linear interpolation of the weighted empirical CDF at mid-points)."""
    w = np.asarray(weights, float) / np.sum(weights)
    out = np.zeros((len(qs), samples.shape[1]))
    for j in range(samples.shape[1]):
        o = np.argsort(samples[:, j])
        cw = np.cumsum(w[o]) - 0.5 * w[o]
        out[:, j] = np.interp(qs, cw, samples[o, j])
    return out


def pit_rows(model: ReducedModel, truth: np.ndarray, u: np.ndarray, lower: dict, upper: dict, mean: np.ndarray,
             info: dict) -> list[dict]:
    """One row per muscle: truth, PIT, posterior mean, interval bounds and coverage at each level in ``LEVELS``."""
    rows = []
    for j, name in enumerate(model.muscle_names):
        r = {**info, "muscle": name, "group": muscle_group(name), "truth": float(truth[j]), "pit": float(u[j]),
             "mean": float(mean[j])}
        for L in LEVELS:
            k = int(round(100 * L))
            r[f"lower{k}"], r[f"upper{k}"] = float(lower[L][j]), float(upper[L][j])
            r[f"covered{k}"] = bool(lower[L][j] <= truth[j] <= upper[L][j])
        rows.append(r)
    return rows


def _sample_rows(model, truth, F, w, info):
    u = weighted_pit(F, w, truth)
    qs = [q for L in LEVELS for q in (0.5 - L / 2, 0.5 + L / 2)]
    Q = weighted_quantiles(F, w, qs)
    lower = {L: Q[2 * i] for i, L in enumerate(LEVELS)}
    upper = {L: Q[2 * i + 1] for i, L in enumerate(LEVELS)}
    return pit_rows(model, truth, u, lower, upper, np.average(F, axis=0, weights=w), info)


def run_alg4(model: ReducedModel, data: Dataset, truth: np.ndarray, settings: ABCSettings, bootstrap_direction: str,
             info: dict) -> list[dict]:
    """Algorithm 4 on one participant; ``f_c (1 +- z sigma_c)`` read as a normal interval (see module doc)."""
    f0, _ = bootstrap_prior(model, data, bootstrap_direction)
    res = estimate_strengths(model, data, settings, f0, progress=None)
    pidx, _ = free_parameters(model, settings.tie_sides)
    f_c, sig = res.f_c[pidx], res.sigma_c[pidx]
    sd = sig * f_c
    u = norm.cdf((truth - f_c) / sd)
    lower = {L: f_c - norm.ppf(0.5 + L / 2) * sd for L in LEVELS}
    upper = {L: f_c + norm.ppf(0.5 + L / 2) * sd for L in LEVELS}
    n_sim = res.iterations * 3 ** len(set(pidx.tolist()))
    rows = pit_rows(model, truth, u, lower, upper, f_c, {**info, "n_sim": n_sim})
    for j, r in enumerate(rows):
        r["sigma_c"] = float(sig[j])
        r["covered_reported"] = bool(f_c[j] * (1 - sig[j]) <= truth[j] <= f_c[j] * (1 + sig[j]))
    return rows


def run_smc(model: ReducedModel, data: Dataset, truth: np.ndarray, f_ref: np.ndarray, settings: SMCSettings,
            rng: np.random.Generator, info: dict) -> list[dict]:
    res = abc_smc(model, data, f_ref, settings, rng)
    last = res.generations.iloc[-1]
    return _sample_rows(model, truth, res.particles, res.weights,
                        {**info, "n_sim": int(res.n_simulations), "tolerance": float(last["tolerance"])})


def run_joint(model: ReducedModel, data: Dataset, truth: np.ndarray, f_ref: np.ndarray, settings: JointSettings,
              checkpoints: Sequence[int], rng: np.random.Generator, info: dict, cache=None) -> list[dict]:
    """Joint posterior, tests in a random order; rows after every checkpoint ``t`` (capped at the directions)."""
    K = len(data.directions)
    ts = sorted({min(int(t), K) for t in checkpoints})
    post = JointPosterior(model, data.directions, data.U, data.force_scale, f_ref, settings, rng, cache=cache)
    order = list(rng.permutation(K))
    rows = []
    for n, i in enumerate(order[:ts[-1]], start=1):
        post.update(data.directions[i], float(data.forces[i]))
        if n in ts:
            rows += _sample_rows(model, truth, post.F, post.weights(),
                                 {**info, "t": n, "n_sim": int(post.n_lps // K), "ess_share": post.ess_share()})
    return rows


def run_sbc(model: ReducedModel, directions: pd.DataFrame, f_ref: np.ndarray, settings: SBCSettings,
            abc: ABCSettings, smc: SMCSettings, joint: JointSettings, rng_for: Callable[[str, int], np.random.Generator],
            progress: Callable[[str], None] | None = None, first: int = 0) -> pd.DataFrame:
    """SBC of ``settings.methods`` on ``settings.n_participants`` simulated participants each (indices ``first``,
    ``first + 1``, ...: a run can be split into chunks that together equal one run).

    ``rng_for(method, i)`` gives the random stream of participant ``i`` of ``method`` (truth, noise and the method's
    own sampling), so a run can be extended or repeated method by method with the same participants.
    Returns one row per method, participant, muscle (and ``t`` for ``joint``).
    """
    from neckstrength.wrench.batched import BasisCache

    rows: list[dict] = []
    for method in settings.methods:
        t0 = time.time()
        for i in range(first, first + settings.n_participants):
            rng = rng_for(method, i)
            info = {"method": method, "model": model.name, "participant": i}
            if method == "joint":
                truth, data = draw_participant(model, directions, f_ref, "truncnormal", joint.prior_sd_rel,
                                               settings.noise, rng)
                # a fresh basis cache per participant: one shared with earlier participants fills with their
                # bases and slows the solver (docs/clinician.md); the numbers are the same (exact solver)
                rows += run_joint(model, data, truth, f_ref, joint, settings.checkpoints, rng, info,
                                  cache=BasisCache())
            else:
                truth, data = draw_participant(model, directions, f_ref, "lognormal", smc.prior_sigma,
                                               settings.noise, rng)
                if method == "alg4":
                    rows += run_alg4(model, data, truth, abc, settings.bootstrap_direction, info)
                else:
                    rows += run_smc(model, data, truth, f_ref, smc, rng, info)
            if progress:
                progress(f"[sbc {model.name}/{method}] participant {i + 1}/{first + settings.n_participants} "
                         f"({time.time() - t0:.0f} s)")
    df = pd.DataFrame(rows)
    if "t" not in df:
        df["t"] = np.nan
    return df


def method_label(method: str, t) -> str:
    """'alg4 (heuristic)', 'smc', 'joint t=5'."""
    if method == "alg4":
        return "alg4 sigma_c (heuristic)"
    if method == "joint" and t == t:  # not NaN
        return f"joint t={int(t)}"
    return method


def coverage_summary(df: pd.DataFrame, by: Sequence[str] = ()) -> pd.DataFrame:
    """Coverage of the 50% / 90% intervals per method (and ``t``, and ``by``), with binomial standard errors,
    and a uniformity check of the PIT (Kolmogorov-Smirnov p-value); ``calibrated90`` = 90% coverage in [0.85, 0.95]."""
    from scipy.stats import kstest

    d = df.copy()
    d["label"] = [method_label(m, t) for m, t in zip(d["method"], d["t"])]
    keys = ["model", "label", *by]
    out = []
    for k, g in d.groupby(keys, sort=False):
        k = k if isinstance(k, tuple) else (k,)
        n = len(g)
        r = dict(zip(keys, k))
        r["n_participants"] = int(g["participant"].nunique())
        r["n_values"] = n
        for L in LEVELS:
            c = float(g[f"covered{int(round(100 * L))}"].mean())
            r[f"coverage{int(round(100 * L))}"] = c
            r[f"se{int(round(100 * L))}"] = math.sqrt(max(c * (1 - c), 1e-12) / n)
        if "covered_reported" in g and g["covered_reported"].notna().any():
            r["coverage_reported_1sigma"] = float(g["covered_reported"].astype(float).mean())
        r["pit_ks_p"] = float(kstest(g["pit"].to_numpy(float), "uniform").pvalue)
        r["mean_abs_rel_error"] = float(np.mean(np.abs(g["mean"] - g["truth"]) / g["truth"]))
        r["median_rel_width90"] = float(np.median((g["upper90"] - g["lower90"]) / g["truth"]))
        r["mean_n_sim"] = float(g.groupby("participant")["n_sim"].first().mean()) if "n_sim" in g else np.nan
        r["calibrated90"] = bool(0.85 <= r["coverage90"] <= 0.95)
        out.append(r)
    return pd.DataFrame(out)


def with_sizes(joint: JointSettings, **over) -> JointSettings:
    return replace(joint, **over)
