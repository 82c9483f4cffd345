"""Sequential estimation on the *joint* posterior, with importance resampling (beyond the thesis, issue 7).

The thesis's Algorithms 7-9 (:mod:`neckstrength.sequential`) keep one PDF per muscle: every test's likelihood
factor (Eq. 6.5) is a marginal over the *prior* of the other muscles, so the candidates drawn once from the prior
are all it ever needs. The price is that what earlier tests learned about muscle A never sharpens what a later
test says about muscle B, and that a posterior far out in the prior's tail (a 75% deficit is a 4-sigma event
under N(f_0, 0.3 f_0)) rests on the few prior candidates that happen to lie there.

Here the posterior is the joint one, represented by weighted candidates (importance sampling, as the Chapter 5
ABC):

    p(f | w_1..t)  ∝  p_0(f) prod_s d(w_s; f),    d = exp(-(eps (w(f) - w_s) / w_s)^2)   (Eq. 5.5 / 6.4)

with weights ``iw_k prod_s d_ks`` (``iw = p_0 / q`` for candidates drawn from a proposal q). No rejection step
(Algorithm 8's q-percentile) is needed: the kernel weighs every candidate. When the effective sample size of the
weights falls below ``resample_ess`` x N ("the prior sample becomes too thin"), new candidates are drawn from a
defensive mixture ``q = (1 - lambda) LogNormal(mu, c^2 Sigma) + lambda p_0`` fitted to the current weighted
candidates (mean and covariance of log f, inflated by ``c``); their maximum wrenches in every direction are
computed with the batched solver and their weights ``p_0 / q prod_s d`` recomputed from all tests so far. The
defensive prior share bounds ``iw <= 1 / lambda``. A test that alone would collapse the ESS (a measurement the
model cannot fit: the participants) is brought in by tempering, ``d^phi`` with phi rising to 1 in up to
``max_resamples`` steps, each chosen so that the ESS at most halves, with a resample after each (adaptive SMC).

Two criteria propose the next test on this posterior:

- ``marginal_entropy``: Eq. 6.6/6.7 (the thesis's criterion) evaluated on the joint posterior: ``N_S``
  posterior-predictive measurements per remaining direction (candidate drawn by weight, measurement noise of the
  kernel), the posterior re-weighted by each, the mean over muscles of the drop of each muscle's marginal entropy
  (histogram on the same :class:`~neckstrength.sequential.StrengthGrid` as Chapter 6).
- ``joint_eig``: the expected information gain about the *joint* strength vector, the mutual information
  ``I(f; y_i) = H(y_i) - H(y_i | f)``. With the kernel read as a Gaussian measurement error of ``log w`` (sd
  ``1 / (eps sqrt 2)``, exact to first order in the relative error), ``H(y | f)`` is the noise entropy for every
  producible candidate, so the gain is the entropy of the predictive distribution of the measurement (a weighted
  histogram of ``log w_ki`` convolved with the noise) minus the noise entropy. Non-producible candidates form a
  separate, noise-free outcome. It costs one histogram per direction.

A ``random`` criterion (uniform over the remaining directions) is the baseline.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import pandas as pd
from scipy.special import log_ndtr

from neckstrength.model.reduction import ReducedModel
from neckstrength.sequential.algorithms import StrengthGrid, activation_bounds, pdf_entropy, sample_prior
from neckstrength.wrench import solve
from neckstrength.wrench.problem import STATUS_CODES

CRITERIA = ("marginal_entropy", "joint_eig", "random")


_OPT = {v: k for k, v in STATUS_CODES.items()}["optimal"]


@dataclass(frozen=True)
class JointSettings:
    """Settings of the joint sequential estimator (none of them is in the thesis; docs/chapter6.md)."""

    n_candidates: int = 100_000     # N (like N_F)
    prior_sd_rel: float = 0.3       # p_0 = N(f_0, (0.3 f_0)^2), truncated at 0 (as Chapter 6)
    noise_rel: float = 0.10         # kernel sd of the relative (log) measurement error: d = exp(-delta^2 / (2 sd^2))
    resample_ess: float = 0.05      # resample when ESS < resample_ess x N
    defensive: float = 0.1          # prior share lambda of the proposal
    inflate: float = 1.2            # proposal covariance = inflate^2 x weighted covariance of log f
    max_resamples: int = 4          # per update: tempering steps, each followed by a resample (each one recomputes N x K wrenches)
    n_moves: int = 2                # Metropolis-Hastings steps after each resample (0 = importance resampling only)
    n_sim: int = 50                 # N_S for 'marginal_entropy'
    max_particles: int = 20_000     # criteria use the heaviest candidates holding 1 - 1e-4 of the weight, at most this
    n_ybins: int = 256              # predictive histogram for 'joint_eig' (at least 4 bins per noise sd)
    n_bins: int = 50                # per-muscle PDF grid (as chapter6.n_bins)
    bin_range_sd: float = 4.0
    emg_band: float = 0.05          # measured activation +- band when activations are given as {muscle: value}

    def __post_init__(self):
        if not 0 < self.resample_ess <= 1:
            raise ValueError("resample_ess must be in (0, 1]")
        if not 0 < self.defensive < 1:
            raise ValueError("defensive must be in (0, 1)")
        if self.inflate <= 0 or self.noise_rel <= 0:
            raise ValueError("inflate and noise_rel must be positive")

    @property
    def epsilon(self) -> float:
        """Eq. 6.4's epsilon of the same kernel: exp(-(eps delta)^2) with eps = 1 / (noise_rel sqrt 2)."""
        return 1.0 / (self.noise_rel * math.sqrt(2.0))

    @property
    def noise_sd(self) -> float:
        """sd of log w equivalent to the kernel (first order in the relative error)."""
        return self.noise_rel


def relative_error(f_c: np.ndarray, f_true: np.ndarray) -> float:
    """Mean over muscles of |f_c - f_a| / f_a."""
    return float(np.mean(np.abs(np.asarray(f_c) - f_true) / f_true))


class JointPosterior:
    """Weighted candidates for the joint posterior of one data set, updated one measurement at a time.

    ``update(direction, force, activations=None)`` adds a test (with activation bounds the candidates' wrenches
    in that direction are recomputed within them, Algorithm 7 step 3); ``propose(criterion, rng)`` scores the
    remaining directions; ``estimate()`` gives E / Var / marginal entropy per muscle.
    """

    def __init__(self, model: ReducedModel, directions: Sequence[str], U: np.ndarray, force_scale: np.ndarray,
                 f0: np.ndarray, settings: JointSettings, rng: np.random.Generator, n_threads: int = 1,
                 progress: Callable[[str], None] | None = None, cache=None):
        from neckstrength.wrench.batched import BasisCache

        self.model = model
        self.directions = list(directions)
        self.U = np.asarray(U, float)
        self.force_scale = np.asarray(force_scale, float)
        self.f0 = np.asarray(f0, float)
        self.sd = settings.prior_sd_rel * self.f0
        self.settings = settings
        self.rng = rng
        self.n_threads = n_threads
        self.cache = BasisCache() if cache is None else cache   # share between runs on one model: bases reused
        # directions with activation bounds: bounds differ per participant, so their bases live with this
        # posterior (kept across its steps; a cache shared over many participants would only grow)
        self.bounded_cache = BasisCache()
        self.progress = progress
        self.grid = StrengthGrid.around(self.f0, settings.prior_sd_rel, settings.n_bins, settings.bin_range_sd)
        self.tests: list[dict] = []
        self.n_resamples = 0
        self.n_lps = 0
        self.last_acceptance = float('nan')
        # log of the evidence (marginal likelihood of the kernel likelihood) of the tests so far, and its Monte
        # Carlo variance (a heuristic: the sum of the increments' genealogy variances, :meth:`_advance_loglik`)
        self.log_evidence = 0.0
        self.log_evidence_var = 0.0
        self.F = self._draw_prior(settings.n_candidates)
        self.ancestor = np.arange(len(self.F))   # index of each candidate's draw at the last fresh draw (mc_se)
        self.log_iw = np.zeros(len(self.F))
        self.W = self._wrenches(self.F)
        self.loglik = np.zeros(len(self.F))

    # -- the candidates' wrenches, the untested directions solved when first read
    #: defer the untested directions' wrenches after a resample-move until something reads them (:attr:`W`: the
    #: proposal's criterion, a new test's column): a test brought in by tempering resamples several times and only
    #: the last candidates' untested wrenches are ever read. False: solved after every move (the reference of
    #: tests/sequential/test_joint.py; the same numbers, to the solver's rounding)
    defer_untested = True

    @property
    def W(self) -> np.ndarray:
        """Max wrenches (N x K) of the candidates in every direction (the deferred columns solved on first read)."""
        self._fresh_cols(None)
        return self._W

    @W.setter
    def W(self, value: np.ndarray) -> None:
        self._W = value
        self._stale = np.zeros(0, int)          # columns of _W not yet solved for the current candidates
        self._uid = None                        # per candidate: equal ids are copies of one candidate (solved once)

    def wrenches_in(self, cols) -> np.ndarray:
        """Max wrenches (N x len(cols)) of the candidates in the tests ``cols`` only (deferred ones among them solved;
        :attr:`W` solves every deferred column)."""
        cols = np.atleast_1d(np.asarray(cols, int))
        self._fresh_cols(cols)
        return self._W[:, cols]

    def _fresh_cols(self, cols) -> None:
        """Solve the deferred columns among ``cols`` (all if None) for the current candidates, once per distinct
        candidate (copies of one candidate share its row, as in :meth:`_move`)."""
        stale = getattr(self, "_stale", None)
        if stale is None or not len(stale):
            return
        todo = stale if cols is None else np.intersect1d(stale, np.atleast_1d(np.asarray(cols, int)))
        if not len(todo):
            return
        if self._uid is None:
            self._W[:, todo] = self._wrenches(self.F, todo)[:, todo]
        else:
            _, first, inv = np.unique(self._uid, return_index=True, return_inverse=True)
            self._W[:, todo] = self._wrenches(self.F[first], todo)[:, todo][inv.ravel()]
        self._stale = np.setdiff1d(stale, todo)

    # -- densities
    def _draw_prior(self, n: int) -> np.ndarray:
        """``n`` draws from the prior p_0 (a subclass with another prior overrides this and :meth:`log_prior`)."""
        return sample_prior(self.f0, self.settings.prior_sd_rel, n, self.rng)

    def log_prior(self, F: np.ndarray) -> np.ndarray:
        """log p_0 (truncated normal per muscle, redrawn below 0 as :func:`sample_prior`)."""
        z = (F - self.f0) / self.sd
        c = -0.5 * math.log(2 * math.pi) - np.log(self.sd) - log_ndtr(self.f0 / self.sd)
        return np.where(np.all(F > 0, axis=1), (-0.5 * z ** 2 + c).sum(axis=1), -np.inf)

    # -- wrenches
    def _solve_all(self, F: np.ndarray, cols: np.ndarray | None = None):
        """Max wrench of every candidate in the tests ``cols`` (all if None; no activation bounds): w, status."""
        U = self.U if cols is None else self.U[cols]
        w, _, st = solve(self.model, F, U, return_alpha=False, cache=self.cache, n_threads=self.n_threads)
        return w, st

    def _wrenches(self, F: np.ndarray, cols: np.ndarray | None = None) -> np.ndarray:
        """Max wrenches of candidates ``F`` (N x K) in the tests ``cols`` (all if None; the other columns NaN):
        one batched solve over every candidate and every unbounded test, one per test with activation bounds."""
        K = len(self.directions)
        cols = np.arange(K) if cols is None else np.asarray(cols, int)
        bounded = {t["i"]: t["bounds"] for t in self.tests if t["bounds"] is not None and t["i"] in set(cols)}
        free = np.array([c for c in cols if c not in bounded], int)
        W = np.full((len(F), K), np.nan)
        if len(free):
            w, st = self._solve_all(F, None if np.array_equal(free, np.arange(K)) else free)
            self.n_lps += w.size
            W[:, free] = np.where(st == _OPT, w, 0.0)
        for i, b in bounded.items():
            W[:, i] = self._bounded(F, i, b)
        return W

    def _tested_cols(self) -> np.ndarray:
        return np.array(sorted({t["i"] for t in self.tests}), int)

    def _bounded(self, F: np.ndarray, i: int, bounds) -> np.ndarray:
        lb, ub = bounds
        w, _, st = solve(self.model, F, self.U[i:i + 1], np.asarray(lb)[None], np.asarray(ub)[None],
                         return_alpha=False, cache=self.bounded_cache, n_threads=self.n_threads)
        self.n_lps += w.size
        return np.where(st[:, 0] == _OPT, w[:, 0], 0.0)

    def _test_loglik(self, W_col: np.ndarray, w_meas: float) -> np.ndarray:
        return -(self.settings.epsilon * (W_col - w_meas) / w_meas) ** 2

    # -- state
    @property
    def tested(self) -> list[str]:
        return [self.directions[t["i"]] for t in self.tests]

    @property
    def remaining(self) -> list[str]:
        return [d for d in self.directions if d not in self.tested]

    def weights(self) -> np.ndarray:
        lw = self.log_iw + self.loglik
        lw = lw - lw.max()
        w = np.exp(lw)
        return w / w.sum()

    def ess_share(self) -> float:
        w = self.weights()
        return float(1.0 / (w ** 2).sum() / len(w))

    def mc_se(self, h: np.ndarray) -> float:
        """Monte Carlo standard error of the posterior mean ``sum_k w_k h_k`` of per-candidate values ``h``.

        Since the last fresh draw (the prior, or the fitted proposal of the last resample) the candidates descend
        from independent draws; the multinomial resampling and the Metropolis-Hastings moves of ``resample-move``
        only copy and move them, each independently. The descendants of one draw form a cluster, the clusters are
        independent given the proposal, and the self-normalised estimate's delta-method variance is
        ``sum_c (W_c (hbar_c - hbar))^2`` (``W_c`` a cluster's normalised weight, ``hbar_c`` its weighted mean;
        the genealogy estimator of Chan & Lai 2013 / Lee & Whiteley 2018 with the last fresh draw as the root).
        It leaves out the error of the proposal itself (fitted from earlier candidates) and cannot see a mode no
        candidate reached: benchmarks/bench_clinician.py compares it with the spread between independent
        candidate sets (docs/clinician.md)."""
        w = self.weights()
        h = np.asarray(h, float)
        mean = float(w @ h)
        Wc = np.bincount(self.ancestor, weights=w, minlength=len(w))
        Hc = np.bincount(self.ancestor, weights=w * h, minlength=len(w))
        return float(np.sqrt(((Hc - mean * Wc) ** 2).sum()))

    def mc_clusters(self) -> float:
        """Effective number of independent draws the candidates descend from, ``1 / sum_c W_c^2`` (see
        :meth:`mc_se`; below about 10 the Monte Carlo error estimate is not to be trusted: at 1 it is 0)."""
        Wc = np.bincount(self.ancestor, weights=self.weights(), minlength=len(self.F))
        return float(1.0 / (Wc ** 2).sum())

    def marginal_pdf(self, w: np.ndarray | None = None) -> np.ndarray:
        w = self.weights() if w is None else w
        memo = getattr(self, "_fbin_memo", None)      # the bins change only when the candidates do (a new F array)
        if memo is None or memo[0] is not self.F:
            memo = self._fbin_memo = (self.F, self.grid.index(self.F))
        fb = memo[1]
        return np.stack([np.bincount(fb[:, j], weights=w, minlength=self.grid.n_bins) for j in range(self.model.m)])

    def estimate(self) -> pd.DataFrame:
        w = self.weights()
        E = w @ self.F
        V = w @ (self.F - E) ** 2
        H = pdf_entropy(self.marginal_pdf(w), self.grid)
        return pd.DataFrame({"muscle": list(self.model.muscle_names), "f_c": E, "v_c": V, "sd_c": np.sqrt(V),
                             "entropy": H})

    # -- undo support: everything an update changes, and its restoration
    def snapshot(self) -> dict:
        """The state an :meth:`update` changes (candidates, weights, tests, counters, evidence, random state)."""
        import copy

        return {"F": self.F.copy(), "ancestor": self.ancestor.copy(), "W": self._W.copy(),
                "W_stale": self._stale.copy(), "W_uid": None if self._uid is None else self._uid.copy(),
                "log_iw": self.log_iw.copy(),
                "loglik": self.loglik.copy(), "tests": [dict(t) for t in self.tests], "n_resamples": self.n_resamples,
                "n_lps": self.n_lps, "last_acceptance": self.last_acceptance, "log_evidence": self.log_evidence,
                "log_evidence_var": self.log_evidence_var, "rng": copy.deepcopy(self.rng.bit_generator.state)}

    def restore(self, s: dict) -> None:
        """Back to a :meth:`snapshot` (undo-then-measure equals a replay of the remaining measurements). The arrays
        are copied, so later updates (which write into them in place) leave the snapshot as it was."""
        self.F, self.W, self.log_iw, self.loglik = s["F"].copy(), s["W"].copy(), s["log_iw"].copy(), s["loglik"].copy()
        uid = s.get("W_uid")
        self._stale, self._uid = s.get("W_stale", np.zeros(0, int)).copy(), None if uid is None else uid.copy()
        self.ancestor, self.tests = s["ancestor"].copy(), [dict(t) for t in s["tests"]]
        self.n_resamples, self.n_lps, self.last_acceptance = s["n_resamples"], s["n_lps"], s["last_acceptance"]
        self.log_evidence, self.log_evidence_var = s["log_evidence"], s["log_evidence_var"]
        self.rng.bit_generator.state = s["rng"]

    # -- update and resampling
    def update(self, direction: str, force: float, activations=None) -> pd.DataFrame:
        if direction not in self.directions:
            raise ValueError(f"unknown direction {direction!r}; known: {self.directions}")
        if direction in self.tested:
            raise ValueError(f"direction {direction!r} has already been tested (each direction is tested once)")
        i = self.directions.index(direction)
        w_meas = float(force) * float(self.force_scale[i])
        if not np.isfinite(w_meas) or w_meas <= 0:
            raise ValueError(f"measured force must be positive, got {force!r}")
        bounds = activation_bounds(activations, self.model.muscle_names, self.settings.emg_band)
        if bounds is not None:
            self._W[:, i] = self._bounded(self.F, i, bounds)
            self._stale = self._stale[self._stale != i]
        else:
            self._fresh_cols([i])
        self.tests.append({"i": i, "w_meas": w_meas, "force": float(force), "bounds": bounds, "phi": 0.0})
        self._temper_in(self.tests[-1])
        return self.estimate()

    def _ess_of(self, logw: np.ndarray) -> float:
        lw = logw - logw.max()
        w = np.exp(lw)
        return float(w.sum() ** 2 / (w ** 2).sum() / len(w))

    def _temper_in(self, t: dict) -> None:
        """Add test ``t`` to the weights; if the ESS would fall below ``resample_ess``, bring it in by tempering
        (its log-likelihood times phi, 0 < phi <= 1, each step chosen so that the ESS halves at most, then
        resampled), up to ``max_resamples`` steps; the last step takes phi = 1 whatever the ESS."""
        thr = self.settings.resample_ess
        for _ in range(self.settings.max_resamples):
            base = self.log_iw + self._loglik_all(exclude=t)
            new = self._test_loglik(self._W[:, t["i"]], t["w_meas"])
            if self._ess_of(base + new) >= thr:
                t["phi"] = 1.0
                break
            lo, hi = t["phi"], 1.0
            target = max(thr, 0.5 * self._ess_of(base + lo * new))
            for _ in range(40):        # the ESS falls with phi: bisection for ESS(phi) = target
                mid = 0.5 * (lo + hi)
                if self._ess_of(base + mid * new) >= target:
                    lo = mid
                else:
                    hi = mid
            t["phi"] = lo
            self._advance_loglik()
            self.resample()
        else:
            t["phi"] = 1.0
        self._advance_loglik()
        t["ess_share"] = self.ess_share()

    def _advance_loglik(self) -> None:
        """Recompute the log-likelihood after a test's phi changed, and add the change's evidence increment
        ``log sum_k wbar_k exp(l'_k - l_k)`` (``wbar`` the current normalised weights: the sequential Monte Carlo
        estimate of the marginal likelihood, Del Moral, Doucet & Jasra 2006) to :attr:`log_evidence`. Its Monte
        Carlo variance is added to :attr:`log_evidence_var` as ``(se / mean)^2`` of the incremental weights, the se
        from the candidates' genealogy (:meth:`mc_se`); the increments are treated as independent, so the total is
        a heuristic (checked against independent candidate sets in docs/clinician.md)."""
        new = self._loglik_all()
        d = new - self.loglik
        lw0 = self.log_iw + self.loglik
        ok = np.isfinite(lw0)
        if ok.any():
            w = self.weights()
            dm = float(d[ok].max())
            g = np.where(ok, np.exp(d - dm), 0.0)
            mean = float(w @ g)
            if mean > 0:
                self.log_evidence += math.log(mean) + dm
                self.log_evidence_var += (self.mc_se(g) / mean) ** 2
            else:
                self.log_evidence = -math.inf
        self.loglik = new

    def _loglik_all(self, exclude: dict | None = None) -> np.ndarray:
        out = np.zeros(len(self.F))
        for t in self.tests:
            if t is not exclude and t["phi"] > 0:
                out += t["phi"] * self._test_loglik(self._W[:, t["i"]], t["w_meas"])
        return out

    def resample(self) -> None:
        """Importance resampling, then resample-move: (1) new candidates from the defensive log-normal mixture
        fitted to the current weights, weighted ``p_0 / q x likelihood``; (2) if ``n_moves`` > 0, multinomial
        resampling by weight (equal weights after it) and ``n_moves`` Metropolis-Hastings steps per candidate
        (random walk in log f, covariance 2.38^2 / m x the weighted covariance) on the current target, which
        restore diversity where the posterior is too narrow for any fitted proposal."""
        s = self.settings
        N, m = self.F.shape
        w = self.weights()
        mu, C = self._log_moments(w)
        Lc = np.linalg.cholesky(s.inflate ** 2 * C)
        n_prior = self.rng.binomial(N, s.defensive)
        Yn = mu + self.rng.standard_normal((N - n_prior, m)) @ Lc.T
        F = np.vstack([np.exp(Yn), self._draw_prior(n_prior)])
        Yf = np.log(F)
        Z = np.linalg.solve(Lc, (Yf - mu).T).T
        log_ln = (-0.5 * (Z ** 2).sum(axis=1) - np.log(np.diag(Lc)).sum() - 0.5 * m * math.log(2 * math.pi)
                  - Yf.sum(axis=1))
        lp = self.log_prior(F)
        log_q = np.logaddexp(math.log1p(-s.defensive) + log_ln, math.log(s.defensive) + lp)
        self.F = F
        self.ancestor = np.arange(N)        # fresh independent draws: each its own cluster (mc_se)
        self.log_iw = lp - log_q
        # with moves to follow, the new candidates need only the tested directions (their weights); the others
        # are solved once, after the moves, for the candidates that survive them (same numbers, fewer LPs)
        self.W = self._wrenches(F, self._tested_cols() if s.n_moves > 0 else None)
        self.loglik = self._loglik_all()
        if s.n_moves > 0:
            self._move(s.n_moves)
        self.n_resamples += 1
        if self.progress:
            self.progress(f"resampled ({self.n_resamples}): ESS share now {self.ess_share():.3f}"
                          + (f", MH acceptance {self.last_acceptance:.2f}" if s.n_moves > 0 else ""))

    def _log_moments(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Y = np.log(self.F)
        mu = w @ Y
        C = ((Y - mu) * w[:, None]).T @ (Y - mu) / max(1.0 - (w ** 2).sum(), 1e-12)
        return mu, C + 1e-6 * np.eye(len(mu))

    def _move(self, n_moves: int) -> None:
        """Multinomial resampling, then random-walk Metropolis-Hastings in log f on p_0(f) prod d^phi."""
        N, m = self.F.shape
        w = self.weights()
        _, C = self._log_moments(w)
        idx = np.minimum(np.searchsorted(np.cumsum(w), self.rng.random(N) * w.sum(), side="right"), N - 1)
        F, W = self.F[idx], self._W[idx]
        self.ancestor = self.ancestor[idx]
        # rows with the same origin are copies of one candidate (deferred columns: of one candidate before too)
        origin = idx.copy() if self._uid is None or not len(self._stale) else self._uid[idx]
        tested = self._tested_cols()
        logt = self.log_prior(F) + self._loglik_all_for(W)
        L = np.linalg.cholesky((2.38 ** 2 / m) * C)
        acc = 0
        for j in range(n_moves):
            Fp = F * np.exp(self.rng.standard_normal((N, m)) @ L.T)
            logu = np.log(self.rng.random(N))
            # random walk in log f: the Jacobian of f = exp(y) enters the acceptance ratio
            rest = self.log_prior(Fp) - logt + np.log(Fp).sum(axis=1) - np.log(F).sum(axis=1)
            Wp = self._wrenches_early_reject(Fp, tested, logu - rest, W)
            alive = np.flatnonzero(np.isfinite(Wp[:, tested]).all(axis=1)) if len(tested) else np.arange(N)
            a = np.zeros(N, bool)
            logtp = np.full(N, -np.inf)
            logtp[alive] = self.log_prior(Fp[alive]) + self._loglik_all_for(Wp[alive])
            a[alive] = logu[alive] < (logtp[alive] - logt[alive] + np.log(Fp[alive]).sum(axis=1)
                                      - np.log(F[alive]).sum(axis=1))
            F[a], W[a], logt[a] = Fp[a], Wp[a], logtp[a]
            origin[a] = (j + 1) * N + np.flatnonzero(a)
            acc += int(a.sum())
        self.last_acceptance = acc / (N * n_moves)
        rest = np.setdiff1d(np.arange(W.shape[1]), tested)
        self.F, self.W = F, W
        if len(rest):                         # the untested directions, once per distinct candidate
            # compact ids (0 .. distinct - 1 < N): the next move's new ids, from N on, cannot collide with them
            self._stale, self._uid = rest, np.unique(origin, return_inverse=True)[1].ravel()
            if not self.defer_untested:
                self._fresh_cols(rest)
        self.loglik = self._loglik_all()
        self.log_iw = -self.loglik            # equal weights: the candidates are draws from the current target

    #: early rejection in the Metropolis-Hastings moves (False: every proposal solved in every tested direction;
    #: the same chain, the reference of tests/sequential/test_joint.py)
    early_reject = True

    #: a proposal is dropped early only when its partial log-likelihood is below the acceptance threshold by more
    #: than this (the full sum, added in another order, then cannot reach it either)
    EARLY_REJECT_MARGIN = 1e-9

    #: LP-free exact rejection in the Metropolis-Hastings moves (with :attr:`early_reject`): every cached basis's dual
    #: vector ``d`` bounds the maximum wrench from above, ``w*(f) <= d . f`` for every ``f`` (weak duality), so each
    #: test's log-likelihood term is at most its value at the smallest such bound (0 where the bound reaches the
    #: measured force); a proposal whose summed bounds cannot reach its acceptance threshold is rejected without an LP
    #: (False: the LPs decide every rejection; the same chain either way)
    dual_bound_reject = True

    #: the dual bounds also for tests with activation bounds (EMG), from each such test's own solver, with its
    #: cached infeasibility certificates (False: those tests' LPs decide; the same chain either way)
    dual_bound_bounded = True

    #: the bound of each test: the smallest over this many most recently hit bases of its direction's solver
    DUAL_BOUND_BASES = 16

    #: the bounds are widened by this relative amount before use (the solver's answers are exact to its tolerances,
    #: about 1e-11 relative; a bound that is off by its rounding must not reject a proposal the reference accepts)
    DUAL_BOUND_SLACK = 1e-6

    def _wrenches_early_reject(self, Fp: np.ndarray, tested: np.ndarray, need: np.ndarray,
                               W_cur: np.ndarray) -> np.ndarray:
        """Wrenches of the proposals ``Fp`` in the ``tested`` directions for the Metropolis-Hastings step, with
        early rejection (Solonen et al. 2012): a proposal is accepted iff its log-likelihood ``sum_s phi_s l_s``
        exceeds ``need`` (log u minus the prior, Jacobian and current-state terms). Every term ``l_s`` is <= 0 and at
        most its value at the dual bound of the wrench (:attr:`dual_bound_reject`), so once the terms solved so far
        plus the bounds of the others fall below ``need`` the proposal is rejected whatever the others are, and its
        remaining directions are not solved (before any LP, where the bounds alone decide). The directions go in
        groups of ``n_threads`` (solved concurrently). Rows left with NaN are rejected ones; the accepted ones have
        every tested direction, so the chain is the same as with every LP solved (to the solver's rounding: a row's
        wrench does not depend on its batch)."""
        N, K = len(Fp), len(self.directions)
        Wp = np.full((N, K), np.nan)
        if not len(tested):
            return Wp
        by_col = {t["i"]: t for t in self.tests if t["phi"] > 0}
        # the directions that penalise the current candidates (``W_cur``) most first
        order = tested[np.argsort(self._loglik_cols(W_cur, tested).mean(axis=0), kind="stable")]
        ll = np.zeros(N)
        if not self.early_reject:
            Wp[:, tested] = self._wrenches(Fp, tested)[:, tested]
            return Wp
        alive = np.flatnonzero(need < 0.0)        # need >= 0: rejected whatever the likelihood (it is <= 0)
        # upper bounds of the terms not solved yet (0: no bound), one column per direction of ``order``
        ub = (self._loglik_upper_bounds(Fp[alive], order) if self.dual_bound_reject and alive.size
              else np.zeros((alive.size, len(order))))
        keep = ub.sum(axis=1) > need[alive] - self.EARLY_REJECT_MARGIN
        alive, ub = alive[keep], ub[keep]
        g = max(1, int(self.n_threads))
        for s0 in range(0, len(order), g):
            if not alive.size:
                break
            cols = order[s0:s0 + g]
            Wp[alive[:, None], cols[None, :]] = self._wrenches(Fp[alive], cols)[:, cols]
            for c in cols:
                t = by_col.get(int(c))
                if t is not None:
                    ll[alive] += t["phi"] * self._test_loglik(Wp[alive, c], t["w_meas"])
            keep = ll[alive] + ub[:, s0 + g:].sum(axis=1) > need[alive] - self.EARLY_REJECT_MARGIN
            alive, ub = alive[keep], ub[keep]
        return Wp

    def _dual_bound_matrix(self, c: int, bounds=None) -> np.ndarray | None:
        """(m x k) dual vectors of the most recently hit cached bases of direction ``c``, or None where there is none
        or the wrenches come from elsewhere (a subclass's solver). Without ``bounds`` the unbounded solver's (this
        posterior's model and cache); with a test's activation bounds ``(lb, ub)`` that test's own solver (in
        :attr:`bounded_cache`), whose dual vectors ``max(d lb, d ub)`` may be negative where a lower bound is."""
        if bounds is None and type(self)._solve_all is not JointPosterior._solve_all:
            return None
        if bounds is not None and (not self.dual_bound_bounded or type(self)._bounded is not JointPosterior._bounded):
            return None
        memo = getattr(self, "_dual_solvers", None)
        if memo is None or memo[0] is not self.cache or memo[1] is not self.bounded_cache:
            memo = self._dual_solvers = (self.cache, self.bounded_cache, {})
        if bounds is None:
            key, cache = c, self.cache
            lb, ub = np.zeros(self.model.m), np.ones(self.model.m)
        else:
            lb, ub = (np.asarray(x, float) for x in bounds)
            key, cache = (c, lb.tobytes(), ub.tobytes()), self.bounded_cache
        solver = memo[2].get(key)
        if solver is None:
            # the solver the batched call made for this direction (its b = J^T u as that call rounds it)
            R = np.asarray(self.model.moment_arms, float)
            b = np.asarray(self.model.JT, float) @ self.U[c]
            found = [e for e in cache.entries()
                     if e.R.shape == R.shape and np.array_equal(e.b, b) and np.array_equal(e.lb, lb)
                     and np.array_equal(e.ub, ub) and np.array_equal(e.R, R)]
            if not found:
                return None
            solver = memo[2][key] = max(found, key=lambda e: len(e.bases))
        bases = solver.bases[:self.DUAL_BOUND_BASES]
        if not bases:
            return None
        return np.array([bb.dvec for bb in bases]).T

    def _farkas_matrix(self, c: int, bounds) -> np.ndarray | None:
        """(m x k) the cached infeasibility certificates of the bounded test ``c``'s solver (``f @ col < 0``: no
        solution, so the wrench is 0; exact with the solver's margin), or None."""
        memo = getattr(self, "_dual_solvers", None)
        if memo is None:
            return None
        lb, ub = (np.asarray(x, float) for x in bounds)
        solver = memo[2].get((c, lb.tobytes(), ub.tobytes()))
        if solver is None or not solver.farkas:
            return None
        return np.array(solver.farkas).T

    def _loglik_upper_bounds(self, F: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(len(F) x len(cols)) upper bounds of the terms ``phi_s l_s`` of candidates ``F`` (:attr:`dual_bound_reject`):
        ``l_s`` at the smallest dual bound of the wrench where that is below the measured force, else 0 (also where
        there is no bound). A test with activation bounds (:attr:`dual_bound_bounded`): its dual bounds may be
        negative (lower activation bounds), so they are widened by the slack times the sum of their terms' sizes
        and taken at 0 at least (the wrench is >= 0, and 0 where the bounded LP has no solution); where one of its
        solver's cached infeasibility certificates proves that there is none, the term is its value at 0 (exact)."""
        by_col = {t["i"]: t for t in self.tests if t["phi"] > 0}
        out = np.zeros((len(F), len(cols)))
        use, mats = [], []
        for k, c in enumerate(cols):
            t = by_col.get(int(c))
            D = None if t is None else self._dual_bound_matrix(int(c), t["bounds"])
            if D is not None:
                use.append((k, t, D))
                mats.append(D)
        if not use:
            return out
        V = np.vstack([D.T for D in mats]) @ F.T            # (bases of every direction) x candidates
        s0 = 0
        for k, t, D in use:
            nb = D.shape[1]
            if t["bounds"] is None:                         # dual vectors >= 0: a relative widening
                u = V[s0:s0 + nb].min(axis=0) * (1.0 + self.DUAL_BOUND_SLACK)
            else:
                u = (V[s0:s0 + nb] + self.DUAL_BOUND_SLACK * (np.abs(D).T @ F.T)).min(axis=0)
                u = np.maximum(u, 0.0)
                C = self._farkas_matrix(int(t["i"]), t["bounds"])
                if C is not None:                           # proven infeasible: the wrench is 0
                    u[(F @ C < 0).any(axis=1)] = 0.0
            s0 += nb
            out[:, k] = np.where(u < t["w_meas"], t["phi"] * self._test_loglik(u, t["w_meas"]), 0.0)
        return out

    def _loglik_cols(self, W: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(N x len(cols)) per-test terms ``phi_s l_s`` of the candidates' wrenches ``W`` (0 for phi = 0)."""
        by_col = {t["i"]: t for t in self.tests}
        out = np.zeros((len(W), len(cols)))
        for k, c in enumerate(cols):
            t = by_col.get(int(c))
            if t is not None and t["phi"] > 0:
                out[:, k] = t["phi"] * self._test_loglik(W[:, c], t["w_meas"])
        return out

    def _loglik_all_for(self, W: np.ndarray) -> np.ndarray:
        out = np.zeros(len(W))
        for t in self.tests:
            if t["phi"] > 0:
                out += t["phi"] * self._test_loglik(W[:, t["i"]], t["w_meas"])
        return out

    # -- criteria
    def _heavy(self) -> tuple[np.ndarray, np.ndarray]:
        w = self.weights()
        o = np.argsort(w)[::-1]
        c = np.cumsum(w[o])
        n = min(int(np.searchsorted(c, 1.0 - 1e-4)) + 1, self.settings.max_particles, len(w))
        sel = o[:n]
        return sel, w[sel] / w[sel].sum()

    def propose(self, criterion: str, rng: np.random.Generator) -> tuple[str, pd.DataFrame]:
        """Score every remaining direction; returns the choice and a table (direction, score[, dS per muscle])."""
        rem = self.remaining
        if not rem:
            raise ValueError("every direction has been tested")
        idx = [self.directions.index(d) for d in rem]
        if criterion == "random":
            choice = rem[int(rng.integers(len(rem)))]
            return choice, pd.DataFrame({"direction": rem, "score": np.nan})
        sel, w = self._heavy()
        if criterion == "joint_eig":
            score = np.array([self._eig(self.W[sel, i], w) for i in idx])
            df = pd.DataFrame({"direction": rem, "score": score})
        elif criterion == "marginal_entropy":
            dS = np.stack([self._marginal_dS(sel, w, i, rng) for i in idx])
            df = pd.DataFrame(dS, columns=list(self.model.muscle_names))
            df.insert(0, "direction", rem)
            df["score"] = dS.mean(axis=1)
        else:
            raise ValueError(f"unknown criterion {criterion!r}; known: {CRITERIA}")
        return rem[int(np.argmax(df["score"].to_numpy()))], df

    def _eig(self, wi: np.ndarray, w: np.ndarray) -> float:
        """I(f; y) for y = log w_i + N(0, noise_sd^2); a non-producible candidate's outcome is 'zero'."""
        sd = self.settings.noise_sd
        pos = wi > 0
        p0 = float(w[~pos].sum())
        if p0 >= 1.0:
            return 0.0
        y = np.log(wi[pos])
        wp = w[pos] / w[pos].sum()
        lo, hi = y.min() - 5 * sd, y.max() + 5 * sd
        nb = max(self.settings.n_ybins, int(math.ceil((hi - lo) / (sd / 4))))
        h = (hi - lo) / nb
        hist = np.bincount(np.clip(((y - lo) / h).astype(int), 0, nb - 1), weights=wp, minlength=nb)
        kx = np.arange(-int(math.ceil(5 * sd / h)), int(math.ceil(5 * sd / h)) + 1) * h
        ker = np.exp(-0.5 * (kx / sd) ** 2)
        p = np.convolve(hist, ker / ker.sum(), mode="same")
        p = p[p > 0] / p.sum()
        H_y = float(-(p * np.log(p)).sum() + math.log(h))
        H_noise = 0.5 * math.log(2 * math.pi * math.e * sd ** 2)
        H_b = 0.0 if p0 <= 0 else float(-(p0 * math.log(p0) + (1 - p0) * math.log(1 - p0)))
        return H_b + (1.0 - p0) * (H_y - H_noise)

    def _marginal_dS(self, sel: np.ndarray, w: np.ndarray, i: int, rng: np.random.Generator) -> np.ndarray:
        """Eq. 6.6 on the joint posterior: entropy drop per muscle, mean over N_S predictive measurements."""
        from scipy.sparse import csr_matrix

        s = self.settings
        wi = self.W[sel, i]
        m, nb = self.model.m, self.grid.n_bins
        fb = self.grid.index(self.F[sel]).astype(np.int64)
        onehot = csr_matrix((np.ones(fb.size), (np.repeat(np.arange(len(sel)), m), (np.arange(m) * nb + fb).ravel())),
                            shape=(len(sel), m * nb))
        cur = (w @ onehot).reshape(m, nb)
        S_c = pdf_entropy(cur, self.grid)
        wpos = w * (wi > 0)
        if wpos.sum() <= 0:
            return np.zeros(m)
        k = rng.choice(len(sel), size=s.n_sim, p=wpos / wpos.sum())
        y = wi[k] * np.exp(s.noise_sd * rng.standard_normal(s.n_sim))
        D = np.exp(-(s.epsilon * (wi[None, :] - y[:, None]) / y[:, None]) ** 2) * w[None, :]
        D /= D.sum(axis=1, keepdims=True)
        P = np.asarray((onehot.T @ D.T).T).reshape(s.n_sim, m, nb)
        return S_c - pdf_entropy(P, self.grid).mean(axis=0)


def run_joint(post: JointPosterior, measure: Callable[[str], tuple[float, object]], criterion: str,
              rng: np.random.Generator, order: Sequence[str] | None = None, f_true: np.ndarray | None = None,
              n_max: int | None = None, progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """Algorithm 7 on the joint posterior: propose by ``criterion`` (or follow ``order``), measure, update.

    Returns one row per iteration (0 = prior) and muscle: direction, E, Var, entropy, ESS share, resamples,
    and the relative error when ``f_true`` is given.
    """
    rows = []

    def record(t, d, score):
        est = post.estimate()
        est.insert(0, "iteration", t)
        est.insert(1, "direction", d)
        est["score"] = score
        est["ess_share"] = post.ess_share()
        est["n_resamples"] = post.n_resamples
        if f_true is not None:
            est["f_true"] = f_true
            est["rel_error"] = np.abs(est["f_c"] - f_true) / f_true
        rows.append(est)

    record(0, "", np.nan)
    n_max = n_max or len(post.directions)
    while post.remaining and len(post.tests) < n_max:
        if order is None:
            d, tab = post.propose(criterion, rng)
            score = float(tab.loc[tab["direction"] == d, "score"].iloc[0])
        else:
            d, score = order[len(post.tests)], np.nan
        force, act = measure(d)
        post.update(d, force, act)
        record(len(post.tests), d, score)
        if progress:
            progress(f"[{criterion}] iteration {len(post.tests)}: {d}; mean entropy "
                     f"{rows[-1]['entropy'].mean():.3f}, ESS share {post.ess_share():.3f}, resamples "
                     f"{post.n_resamples}")
    return pd.concat(rows, ignore_index=True)
