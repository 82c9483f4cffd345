"""Is this patient's deep extensor weak? The deficit decision as a clinic makes it (issue 31).

Two hypotheses about the strength vector ``f`` of a reduced model (muscle ``j`` of the group ``G``, both sides):

- **normal** ``H_N``: every muscle varies as the population does, ``f_j ~ N(f0_j, (s f0_j)^2)`` truncated to
  ``f_j > 0``, and the group's muscles at least ``hi f0_j`` (truncated to ``[hi f0_j, inf)``);
- **deficit** ``H_D``: the group's muscles ``f_j ~ U(lo f0_j, hi f0_j)`` each (the stated prior on the deficit's
  size, default 20-60% of normal), every other muscle as under ``H_N``.

Both priors are proper and normalised, so their evidences are comparable. The likelihood of the forces is the
Gaussian measurement error of the relative force with sd ``noise`` (the kernel of
:class:`~neckstrength.sequential.joint.JointPosterior` with ``noise_rel = noise``, i.e. the kernel width *is* the
measurement noise, not twice it), the same under both hypotheses, so its normalising constant cancels.

Each hypothesis has its own sampler, a :class:`HypothesisPosterior` (the joint posterior's adaptive sequential
Monte Carlo: tempering, resample-move, restricted to that hypothesis's prior), so the deficit region is
represented by as many candidates as the normal one whatever the forces say. The evidence ``Z_h = p(y | H_h)`` is
the product of the samplers' incremental weights (:attr:`JointPosterior.log_evidence`), the Bayes factor
``BF = Z_D / Z_N``, and with the clinician's prior prevalence ``pi``

    P(deficit | y) = pi BF / (pi BF + 1 - pi).

The decision: "deficit" when ``P >= p_decide``, "no deficit" when ``P <= 1 - p_decide``, "undecided" otherwise;
a session stops when decided or when the test budget is spent. The Monte Carlo error of ``log BF`` is the sum of the
samplers' evidence variances (a heuristic; compared with independent candidate sets in docs/clinician.md).
How well the rule decides (ROC, sensitivity at a 5% false-alarm rate, reliability) is measured on simulated
participants by :func:`neckstrength.sequential.decision_study.run_decision_study`.

The next test (``decision_eig``): the mutual information between the hypothesis and the next measurement,
``I(H; y_i) = H(y_i) - sum_h P(h) H(y_i | h)``, each predictive a weighted histogram of the candidates' log forces
convolved with the noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import pandas as pd
from scipy.special import log_ndtr, ndtr, ndtri

from neckstrength.model.reduction import ReducedModel
from neckstrength.postures.sequential import PostureWrenches
from neckstrength.seeds import child_generators
from neckstrength.sequential.joint import JointPosterior, JointSettings

DECISIONS = ("deficit", "no deficit", "undecided", "model misfit")


@dataclass(frozen=True)
class DecisionSettings:
    """The deficit decision's choices (config ``clinician.decision``; none of them is in the thesis)."""

    group: tuple[str, ...] = ("mf",)            # the deep extensors of s3m24 (multifidus, both sides)
    deficit_range: tuple[float, float] = (0.2, 0.6)   # H_D: each side U(lo, hi) x normal
    population_sd: float = 0.3                  # population variation of every muscle (sd / normal; Chapter 6's prior)
    noise: float = 0.05                         # measurement noise: sd of the relative force error
    noise_source: str = "stated default, test-retest literature"   # where ``noise`` comes from (printed)
    prevalence: float = 0.5                     # prior P(deficit) the clinician sets
    p_decide: float = 0.95                      # decide when P >= p_decide (deficit) or P <= 1 - p_decide (none)
    min_tests: int = 5                          # ... but not before this many tests
    misfit_factor: float = 3.0                  # "model misfit" when no candidate fits within this x noise (RMS)
    n_candidates: int = 1000                    # per hypothesis
    # each hypothesis's sampler (benchmarks/bench_decision.py: log BF of 'weak' over seeds against these)
    resample_ess: float = 0.3                   # resample-move when the ESS falls below this share
    n_moves: int = 10                           # Metropolis-Hastings steps per resample
    max_resamples: int = 50                     # tempering steps per test
    sampler: str = "resample_move"              # or "fresh_draws": JointPosterior's resampling (for comparison only)
    n_ybins: int = 128                          # predictive histogram of decision_eig
    calibration: "DecisionCalibration | None" = None   # recalibration of the Bayes factor measured on simulated
    #                                             patients (config clinician.decision.calibration, a file); None: the
    #                                             model's P(deficit), labelled heuristic
    misfit_guard: "MisfitGuard | None" = None   # the misfit guard calibrated on simulated patients (config
    #                                             clinician.decision.misfit_guard, a file); None or where it does not
    #                                             hold: misfit_factor x noise, labelled heuristic

    def __post_init__(self):
        lo, hi = self.deficit_range
        if not 0 < lo < hi < 1:
            raise ValueError(f"clinician.decision.deficit_range must be 0 < low < high < 1, got {self.deficit_range}")
        if not 0 < self.prevalence < 1:
            raise ValueError(f"clinician.decision.prevalence must be in (0, 1), got {self.prevalence}")
        if not 0.5 < self.p_decide < 1:
            raise ValueError(f"clinician.decision.p_decide must be in (0.5, 1), got {self.p_decide}")
        if self.noise <= 0 or self.population_sd <= 0:
            raise ValueError("clinician.decision.noise and population_sd must be positive")
        if self.sampler not in ("resample_move", "fresh_draws"):
            raise ValueError(f"clinician.decision.sampler: resample_move or fresh_draws, not {self.sampler!r}")
        if not 0 < self.resample_ess <= 1 or self.n_moves < 1 or self.max_resamples < 1:
            raise ValueError("clinician.decision: resample_ess in (0, 1], n_moves >= 1, max_resamples >= 1")
        if self.misfit_factor <= 0:
            raise ValueError(f"clinician.decision.misfit_factor must be positive, got {self.misfit_factor}")
        if self.min_tests < 1:
            raise ValueError(f"clinician.decision.min_tests must be >= 1, got {self.min_tests}")
        if self.n_candidates < 100:
            raise ValueError(f"clinician.decision.n_candidates must be >= 100, got {self.n_candidates}")
        if not self.group:
            raise ValueError("clinician.decision.group is empty")

    def label(self) -> str:
        lo, hi = self.deficit_range
        return (f"deficit = each side of {'+'.join(self.group)} at {lo:.0%}-{hi:.0%} of normal (uniform); normal = "
                f"at least {hi:.0%}, every muscle with population sd {self.population_sd:.0%}; noise "
                f"{self.noise:.0%} ({self.noise_source}); prior prevalence {self.prevalence:.0%}")

    def group_indices(self, muscle_names: Sequence[str]) -> np.ndarray:
        keep = set(self.group)
        return np.array([j for j, n in enumerate(muscle_names)
                         if n in keep or (n.endswith(("-R", "-L")) and n[:-2] in keep)], dtype=int)


class _FittedOnPatients:
    """What :class:`DecisionCalibration` and :class:`MisfitGuard` share: both are fitted by the decision study on
    simulated patients, hold only for the settings they were measured with, and are kept as one CSV row."""

    _what = ""                                   # the name in error messages
    _compared: tuple[str, ...] = ()              # DecisionSettings fields that must equal the measured ones

    def _differences(self, model_name: str, settings: "DecisionSettings", n_directions: int,
                     with_emg: bool) -> list[str]:
        diff = []
        if model_name != self.model:
            diff.append(f"model {model_name}, measured on {self.model}")
        for name in self._compared:
            a, b = getattr(settings, name), getattr(self, name)
            if (tuple(a) != tuple(b)) if isinstance(a, tuple) else not (a == b or (isinstance(a, float)
                                                                                  and math.isclose(a, b))):
                diff.append(f"{name} {a}, measured at {b}")
        if n_directions != self.n_directions:
            diff.append(f"{n_directions} test directions, measured with {self.n_directions}")
        if with_emg:
            diff.append("EMG entries, measured on forces only")
        return diff

    def _frame(self, **columns) -> pd.DataFrame:
        from dataclasses import asdict

        d = asdict(self)
        d.update(columns)
        return pd.DataFrame([d])

    @classmethod
    def _one_row(cls, df: pd.DataFrame, source: str) -> pd.Series:
        from dataclasses import fields

        need = [f.name for f in fields(cls) if f.name != "source"]
        miss = [c for c in need if c not in df.columns]
        if miss or len(df) != 1:
            raise ValueError(f"{source or cls._what}: needs one row with columns {need}; missing {miss}, "
                             f"rows {len(df)}")
        return df.iloc[0]


@dataclass(frozen=True)
class DecisionCalibration(_FittedOnPatients):
    """A recalibration of the Bayes factor measured on simulated patients (Platt scaling, Platt 1999, with a bend).

    The decision study (:func:`neckstrength.sequential.decision_study.recalibrate`) fits, on a cohort whose truths are
    made apart from the priors, ``logit P(deficit | x) = slope x + intercept + bend tanh(x / 2)`` with ``x = log BF``,
    monotone in ``x``, at the cohort's share of deficits ``cohort_share``; the calibrated likelihood ratio is then
    ``log LR = slope x + intercept + bend tanh(x / 2) - logit(cohort_share)``, and for a clinician's prevalence
    ``pi``

        P(deficit) = 1 / (1 + exp(-(log LR + logit(pi)))).

    It holds for the settings it was measured with (model, group, deficit range, population sd, noise, candidates,
    sampler, number of test directions, forces only) and for patients like the cohort's (its population, its 5%
    noise): :meth:`applies` says when it does not, and the decision then reports the model's own P, labelled
    heuristic. ``check`` names the held-out check (cross-fitted reliability) and its result.
    """

    model: str
    group: tuple[str, ...]
    deficit_range: tuple[float, float]
    population_sd: float
    noise: float
    n_candidates: int
    sampler: str
    n_directions: int
    cohort_share: float
    n_patients: int
    t_from: int                                 # fitted on the patients' P after t >= t_from tests
    slope: float
    intercept: float
    bend: float
    check: str
    source: str = ""

    _what = "decision calibration"
    _compared = ("group", "deficit_range", "population_sd", "noise", "n_candidates", "sampler")

    def log_lr(self, log_bf: float) -> float:
        s = self.cohort_share
        return self.slope * log_bf + self.intercept + self.bend * math.tanh(log_bf / 2) - math.log(s / (1 - s))

    def d_log_lr(self, log_bf: float) -> float:
        """d log LR / d log BF (for the delta-method Monte Carlo error)."""
        return self.slope + self.bend / 2 / math.cosh(log_bf / 2) ** 2

    def applies(self, model_name: str, settings: "DecisionSettings", n_directions: int,
                with_emg: bool = False, n_tests: int | None = None) -> str:
        """'' when this recalibration holds for a decision with these settings (and, given ``n_tests``, at this
        many tests: it was fitted from the ``t_from``-th on), else the reason it does not."""
        diff = []
        if n_tests is not None and n_tests < self.t_from:
            diff.append(f"{n_tests} tests, recalibrated from the {self.t_from}th")
        return "; ".join(diff + self._differences(model_name, settings, n_directions, with_emg))

    def label(self) -> str:
        return (f"recalibrated on {self.n_patients} simulated patients ({self.model}, forces only, noise "
                f"{self.noise:.0%}); check: {self.check}")

    def to_frame(self) -> pd.DataFrame:
        return self._frame(group="+".join(self.group),
                           deficit_range=f"{self.deficit_range[0]:g}-{self.deficit_range[1]:g}")

    @classmethod
    def from_frame(cls, df: pd.DataFrame, source: str = "") -> "DecisionCalibration":
        r = cls._one_row(df, source)
        lo, hi = (float(x) for x in str(r["deficit_range"]).split("-"))
        return cls(model=str(r["model"]), group=tuple(str(r["group"]).split("+")), deficit_range=(lo, hi),
                   population_sd=float(r["population_sd"]), noise=float(r["noise"]),
                   n_candidates=int(r["n_candidates"]), sampler=str(r["sampler"]),
                   n_directions=int(r["n_directions"]), cohort_share=float(r["cohort_share"]),
                   n_patients=int(r["n_patients"]), t_from=int(r["t_from"]), slope=float(r["slope"]),
                   intercept=float(r["intercept"]),
                   bend=float(r["bend"]), check=str(r["check"]), source=source or str(r.get("source", "")))


@dataclass(frozen=True)
class MisfitGuard(_FittedOnPatients):
    """The misfit guard calibrated on simulated patients (issue 31): is this best fit worse than the model's own
    patients' best fits at the stated noise?

    The statistic after ``t`` tests is the best candidate's RMS relative force error (:meth:`DeficitDecision.
    misfit_rms`), standardised on its log scale by the decision study's patients (forces made by the model itself,
    with 5% noise: the reference distribution of the best fit *under the model*): ``z_t = (log rms - log_median_t) /
    log_sd_t``, with the median and the MAD-based sd of log rms over those patients at that t. A patient is flagged
    "model misfit" at the first ``t >= t_from`` at which ``z_t`` exceeds ``factor``, the ``1 - level`` quantile over
    the study's patients of their largest ``z_t`` over the session: so the guard flags a share ``level`` of the
    model's own patients over a whole session (the looks at every t counted), by construction on the patients it
    was fitted on and checked held out (``check``: two folds by participant). Standardising per t keeps every t's
    look equally strict (the best fit after 5 tests varies far more than after 25). Like
    :class:`DecisionCalibration` it holds for the settings it was measured with; :meth:`applies` says when it does
    not.
    """

    model: str
    noise: float
    n_candidates: int
    sampler: str
    n_directions: int
    level: float
    t_from: int
    factor: float
    log_median: tuple[float, ...]               # per t = t_from, t_from + 1, ...: median log best-fit RMS
    log_sd: tuple[float, ...]                   # ... and its MAD-based sd over the study's patients
    n_patients: int
    check: str
    source: str = ""

    _what = "misfit guard"
    _compared = ("noise", "n_candidates", "sampler")

    @property
    def t_max(self) -> int:
        return self.t_from + len(self.log_median) - 1

    def threshold(self, t: int) -> float:
        """The best-fit RMS (relative force error) above which ``t`` tests are flagged; NaN before ``t_from`` or
        beyond the tests it was measured at."""
        if t < self.t_from or t > self.t_max:
            return float("nan")
        k = t - self.t_from
        return float(math.exp(self.log_median[k] + self.factor * self.log_sd[k]))

    def applies(self, model_name: str, settings: "DecisionSettings", n_directions: int, with_emg: bool = False,
                several_postures: bool = False) -> str:
        """'' when the guard holds for a decision with these settings, else the reason it does not."""
        diff = self._differences(model_name, settings, n_directions, with_emg)
        if several_postures:
            diff.append("tests in several postures, measured in neutral only")
        return "; ".join(diff)

    def label(self) -> str:
        return (f"calibrated: flags {self.level:.0%} of the model's own simulated patients over a session "
                f"({self.n_patients} patients, {self.model}, noise {self.noise:.0%}); check: {self.check}")

    def to_frame(self) -> pd.DataFrame:
        return self._frame(**{k: " ".join(f"{x:.8g}" for x in getattr(self, k)) for k in ("log_median", "log_sd")})

    @classmethod
    def from_frame(cls, df: pd.DataFrame, source: str = "") -> "MisfitGuard":
        r = cls._one_row(df, source)
        med, sd = (tuple(float(x) for x in str(r[k]).split()) for k in ("log_median", "log_sd"))
        if not med or len(med) != len(sd) or not all(np.isfinite(med + sd)) or min(sd) <= 0:
            raise ValueError(f"{source or 'misfit guard'}: log_median and log_sd must be equally many numbers "
                             "separated by spaces (sd > 0)")
        return cls(model=str(r["model"]), noise=float(r["noise"]), n_candidates=int(r["n_candidates"]),
                   sampler=str(r["sampler"]), n_directions=int(r["n_directions"]), level=float(r["level"]),
                   t_from=int(r["t_from"]), factor=float(r["factor"]), log_median=med, log_sd=sd,
                   n_patients=int(r["n_patients"]), check=str(r["check"]), source=source or str(r.get("source", "")))


@dataclass(frozen=True)
class MisfitCheck:
    """The misfit guard's result after the tests so far: the best fit, the threshold it was held to, flagged or
    not, whether the threshold is calibrated (:class:`MisfitGuard`) or the heuristic ``misfit_factor x noise``, and
    a line that says so (printed with the decision)."""

    rms: float
    threshold: float
    flagged: bool
    calibrated: bool
    label: str


class HypothesisPrior:
    """The prior of one hypothesis: per muscle a normal ``N(f0, (s f0)^2)`` truncated to ``[a_j, inf)`` (``a_j`` =
    0, or ``hi f0_j`` for the group under H_N), or for the group under H_D a uniform on ``[lo f0_j, hi f0_j]``."""

    def __init__(self, f0: np.ndarray, sd_rel: float, group_idx: np.ndarray, deficit_range: tuple[float, float],
                 deficit: bool):
        self.f0 = np.asarray(f0, float)
        self.sd = sd_rel * self.f0
        m = len(self.f0)
        lo, hi = deficit_range
        self.uniform = np.zeros(m, bool)
        self.low = np.zeros(m)
        if deficit:
            self.uniform[group_idx] = True
            self.low[group_idx] = lo * self.f0[group_idx]
            self.high = np.where(self.uniform, hi * self.f0, np.inf)
        else:
            self.low[group_idx] = hi * self.f0[group_idx]
            self.high = np.full(m, np.inf)
        self.a = (self.low - self.f0) / self.sd              # standardised lower bound of the normal muscles
        self.log_tail = log_ndtr(-self.a)                   # log P(z >= a)
        self.log_norm = np.where(self.uniform, -np.log(np.where(self.uniform, self.high - self.low, 1.0)),
                                 -0.5 * math.log(2 * math.pi) - np.log(self.sd) - self.log_tail)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        u = rng.random((n, len(self.f0)))
        p0 = ndtr(self.a)
        z = ndtri(p0 + u * (1.0 - p0))
        F = np.where(self.uniform, self.low + u * (np.where(self.uniform, self.high, 0.0) - self.low),
                     self.f0 + self.sd * z)
        return np.maximum(F, np.where(self.uniform, self.low, np.nextafter(self.low, np.inf)))

    def log_pdf(self, F: np.ndarray) -> np.ndarray:
        F = np.atleast_2d(F)
        z = (F - self.f0) / self.sd
        lp = np.where(self.uniform, 0.0, -0.5 * z ** 2) + self.log_norm
        inside = (F >= self.low) & (F <= self.high) & (F > 0)
        return np.where(np.all(inside, axis=1), lp.sum(axis=1), -np.inf)


class HypothesisPosterior(JointPosterior):
    """The joint posterior restricted to one hypothesis's prior (:class:`HypothesisPrior`)."""

    def __init__(self, model: ReducedModel, directions: Sequence[str], U: np.ndarray, force_scale: np.ndarray,
                 f0: np.ndarray, settings: JointSettings, prior: HypothesisPrior, rng: np.random.Generator,
                 n_threads: int = 1, cache=None, fresh_draws: bool = False):
        self.prior = prior
        self.fresh_draws = fresh_draws
        super().__init__(model, directions, U, force_scale, f0, settings, rng, n_threads=n_threads, cache=cache)

    def _draw_prior(self, n: int) -> np.ndarray:
        return self.prior.sample(n, self.rng)

    def log_prior(self, F: np.ndarray) -> np.ndarray:
        return self.prior.log_pdf(F)

    def resample(self) -> None:
        """Standard resample-move (Chopin 2002): multinomial resampling of the current candidates by weight, then
        ``n_moves`` Metropolis-Hastings steps on the current target. Unlike :meth:`JointPosterior.resample` no fresh
        candidates are drawn from a fitted log-normal, which on the narrow, curved posteriors of 5% noise lost
        the high-likelihood region in some runs (log Bayes factors of one data set differing by > 100 between
        seeds); keeping the candidates keeps it. ``fresh_draws`` restores the parent's resampling (comparison)."""
        if self.fresh_draws:
            return super().resample()
        self._move(max(1, self.settings.n_moves))
        self.n_resamples += 1



class PostureHypothesisPosterior(PostureWrenches, HypothesisPosterior):
    """:class:`HypothesisPosterior` with tests in several postures (``test_postures[k]`` of test k): the wrenches of
    :class:`~neckstrength.postures.sequential.PostureJointPosterior` (the neutral group strengths mapped to each
    posture's model), the priors and sampler of the hypothesis."""

    def __init__(self, pset, test_postures: Sequence[str], directions: Sequence[str], U: np.ndarray,
                 force_scale: np.ndarray, f0: np.ndarray, settings: JointSettings, prior: HypothesisPrior,
                 rng: np.random.Generator, **kw):
        if len(test_postures) != len(directions):
            raise ValueError("one posture per test label")
        self.pset = pset
        self.test_postures = list(test_postures)
        super().__init__(pset.neutral, directions, U, force_scale, f0, settings, prior, rng, **kw)


class DeficitDecision:
    """The two hypotheses' samplers for one patient, updated one measurement at a time, with undo.

    ``push(direction, force, activations=None)`` adds a test to both; ``undo()`` removes the last one (both samplers'
    candidates and random states restored: undo-then-measure equals a replay); ``p_deficit()``, ``log_bf()``,
    ``log_bf_se()``, ``decision()``; ``propose()`` scores the remaining tests by ``decision_eig``; ``estimate()`` is
    the posterior mean / sd per muscle of the mixture of the two hypotheses.
    """

    def __init__(self, model: ReducedModel, directions: Sequence[str], U: np.ndarray, force_scale: np.ndarray,
                 f0: np.ndarray, settings: DecisionSettings, joint: JointSettings, rng: np.random.Generator,
                 n_threads: int = 1, cache=None, pset=None, test_postures: Sequence[str] | None = None):
        """``pset`` and ``test_postures`` (one posture per test label; :mod:`neckstrength.postures`): tests in
        several postures; ``U`` and ``force_scale`` then have one row per label."""
        from neckstrength.wrench.batched import BasisCache

        self.model = model
        self.settings = settings
        self.f0 = np.asarray(f0, float)
        self.gidx = settings.group_indices(model.muscle_names)
        if not len(self.gidx):
            raise ValueError(f"deficit group {settings.group} has no muscle in {model.name} "
                             f"({', '.join(model.muscle_names)})")
        js = replace(joint, n_candidates=settings.n_candidates, prior_sd_rel=settings.population_sd,
                     noise_rel=settings.noise, resample_ess=settings.resample_ess, n_moves=settings.n_moves,
                     max_resamples=settings.max_resamples)
        self.joint = js
        rngs = child_generators(rng, 2)
        # with 2 threads or more the two samplers run side by side, each with its own basis cache (a cache is not
        # shared between threads) and half the threads; the numbers are the same (own random streams, exact solver)
        self.parallel = n_threads >= 2
        each = max(1, n_threads // 2) if self.parallel else n_threads
        caches = ([BasisCache() if cache is None else cache, BasisCache()] if self.parallel
                  else [BasisCache() if cache is None else cache] * 2)

        self.postures = None if pset is None else list(dict.fromkeys(test_postures))

        def build(h, r, c):
            prior = HypothesisPrior(self.f0, settings.population_sd, self.gidx, settings.deficit_range,
                                    deficit=(h == "deficit"))
            if pset is not None:
                return PostureHypothesisPosterior(pset, test_postures, directions, U, force_scale, self.f0, js, prior,
                                                  r, n_threads=each, cache=c,
                                                  fresh_draws=settings.sampler == "fresh_draws")
            return HypothesisPosterior(model, directions, U, force_scale, self.f0, js, prior, r, n_threads=each,
                                       cache=c, fresh_draws=settings.sampler == "fresh_draws")

        jobs = list(zip(("normal", "deficit"), rngs, caches))
        self.posts = dict(zip(("normal", "deficit"), self._both(lambda j: build(*j), jobs)))
        self.directions = list(directions)
        self._snaps: list[dict] = []
        self._emg: list[bool] = []                  # per test: EMG bounds given (the recalibration is forces-only)
        self.history: list[dict] = [self.summary()]

    def _both(self, fn, items: list) -> list:
        """``fn`` of both items, side by side in two threads when ``parallel`` (exceptions re-raised)."""
        if not self.parallel:
            return [fn(x) for x in items]
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(2) as ex:
            return [f.result() for f in [ex.submit(fn, x) for x in items]]

    # -- state
    @property
    def tested(self) -> list[str]:
        return self.posts["normal"].tested

    @property
    def remaining(self) -> list[str]:
        return self.posts["normal"].remaining

    def log_bf(self) -> float:
        """log Bayes factor of deficit against normal, ``log Z_D - log Z_N``."""
        return self.posts["deficit"].log_evidence - self.posts["normal"].log_evidence

    def log_bf_se(self) -> float:
        """Monte Carlo error (1 se) of :meth:`log_bf` (heuristic, see the module docstring)."""
        return math.sqrt(self.posts["deficit"].log_evidence_var + self.posts["normal"].log_evidence_var)

    def calibration_note(self) -> str:
        """Why the settings' recalibration does not hold for this decision ('' when it does; 'none' when the
        settings carry none)."""
        cal = self.settings.calibration
        if cal is None:
            return "none"
        note = cal.applies(self.model.name, self.settings, len(self.directions), with_emg=any(self._emg),
                           n_tests=len(self.tested))
        if self.postures is not None and self.postures != ["neutral"]:
            note = "; ".join(x for x in (note, "tests in several postures, measured in neutral only") if x)
        return note

    @property
    def calibrated(self) -> bool:
        """True when :meth:`p_deficit` is the recalibrated probability (see :class:`DecisionCalibration`)."""
        return self.calibration_note() == ""

    def p_label(self) -> str:
        """What the printed P(deficit) is: recalibrated (with its check) or the model's own, heuristic."""
        if self.calibrated:
            return self.settings.calibration.label()
        note = self.calibration_note()
        why = "no recalibration configured" if note == "none" else f"the recalibration does not hold: {note}"
        return f"heuristic, the model's own probability; {why}"

    def p_model(self, prevalence: float | None = None) -> float:
        """P(deficit) from the model's Bayes factor as it stands (conservative on the decision study's cohort)."""
        pi = self.settings.prevalence if prevalence is None else prevalence
        x = self.log_bf() + math.log(pi) - math.log1p(-pi)
        return float(1.0 / (1.0 + math.exp(-x))) if x > -700 else 0.0

    def p_deficit(self, prevalence: float | None = None) -> float:
        """P(deficit): recalibrated when the settings' :class:`DecisionCalibration` holds, else :meth:`p_model`."""
        if not self.calibrated:
            return self.p_model(prevalence)
        pi = self.settings.prevalence if prevalence is None else prevalence
        x = self.settings.calibration.log_lr(self.log_bf()) + math.log(pi) - math.log1p(-pi)
        return float(1.0 / (1.0 + math.exp(-x))) if x > -700 else 0.0

    def p_deficit_se(self) -> float:
        """Monte Carlo error of :meth:`p_deficit` by the delta method from :meth:`log_bf_se` (heuristic)."""
        p = self.p_deficit()
        slope = self.settings.calibration.d_log_lr(self.log_bf()) if self.calibrated else 1.0
        return float(p * (1 - p) * slope * self.log_bf_se())

    def misfit_rms(self) -> float:
        """The best candidate's RMS relative force error over the tests so far, under either hypothesis: how well
        the model can fit these forces at all (NaN before any test)."""
        best = np.inf
        for p in self.posts.values():
            if not p.tests:
                return float("nan")
            cols = np.array([t["i"] for t in p.tests])
            wm = np.array([t["w_meas"] for t in p.tests])
            rel = (p.wrenches_in(cols) - wm) / wm     # the tested columns only (the others stay deferred)
            best = min(best, float(np.sqrt((rel ** 2).mean(axis=1)).min()))
        return best

    def misfit_guard_note(self) -> str:
        """Why the settings' calibrated misfit guard does not hold for this decision ('' when it does; 'none' when
        the settings carry none)."""
        g = self.settings.misfit_guard
        if g is None:
            return "none"
        return g.applies(self.model.name, self.settings, len(self.directions), with_emg=any(self._emg),
                         several_postures=self.postures is not None and self.postures != ["neutral"])

    def misfit_check(self) -> MisfitCheck:
        """The misfit guard after the tests so far. Calibrated (:class:`MisfitGuard`) where it holds: flagged when
        the best fit is worse than the model's own patients' best fits at this many tests by more than the guard's
        standardised threshold (flags ``level`` of them over a session). Elsewhere the heuristic: flagged when the best fit exceeds
        ``misfit_factor x noise`` RMS. Never flagged before ``min_tests`` tests (nothing is decided then)."""
        s = self.settings
        rms = self.misfit_rms()
        t = len(self.tested)
        if t < s.min_tests:
            return MisfitCheck(rms=float(rms), threshold=float("nan"), flagged=False, calibrated=False,
                               label=f"misfit guard: not checked before {s.min_tests} tests")
        note = self.misfit_guard_note()
        thr = s.misfit_guard.threshold(t) if note == "" else float("nan")
        if note == "" and not np.isfinite(thr):
            g = s.misfit_guard
            note = f"{t} tests, measured from the {g.t_from}th to the {g.t_max}th"
        cal = note == ""
        if not cal:
            thr = s.misfit_factor * s.noise
        flagged = bool(np.isfinite(rms) and rms > thr)
        if cal:
            how = s.misfit_guard.label()
        else:
            why = "no calibrated guard configured" if note == "none" else f"the calibrated guard does not hold: {note}"
            how = f"heuristic ({s.misfit_factor:g} x the {s.noise:.0%} noise; {why})"
        word = "FLAGGED, model misfit" if flagged else "not flagged"
        return MisfitCheck(rms=float(rms), threshold=float(thr), flagged=flagged, calibrated=cal,
                           label=f"misfit guard: best fit {rms:.1%} RMS, threshold {thr:.1%}: {word}; {how}")

    def decision(self) -> str:
        """'deficit' / 'no deficit' at the thresholds, 'undecided' between them or before ``min_tests`` tests,
        'model misfit' when the misfit guard (:meth:`misfit_check`) flags the best fit: then the Bayes factor says
        which hypothesis misfits less, not whether the muscle is weak."""
        if len(self.tested) < self.settings.min_tests:
            return "undecided"
        if self.misfit_check().flagged:
            return "model misfit"
        return self._p_decision()

    def _p_decision(self) -> str:
        p = self.p_deficit()
        if p >= self.settings.p_decide:
            return "deficit"
        if p <= 1.0 - self.settings.p_decide:
            return "no deficit"
        return "undecided"

    def summary(self) -> dict:
        mc = self.misfit_check()
        return {"t": len(self.tested), "direction": self.tested[-1] if self.tested else "",
                "log_bf": self.log_bf(), "log_bf_se": self.log_bf_se(), "p_deficit": self.p_deficit(),
                "p_deficit_se": self.p_deficit_se(), "p_model": self.p_model(), "p_calibrated": self.calibrated,
                "decision": "undecided" if len(self.tested) < self.settings.min_tests
                else ("model misfit" if mc.flagged else self._p_decision()),
                "misfit_rms": mc.rms, "misfit_threshold": mc.threshold, "misfit_flagged": mc.flagged,
                "misfit_calibrated": mc.calibrated, "misfit_label": mc.label,
                "ess_normal": self.posts["normal"].ess_share(), "ess_deficit": self.posts["deficit"].ess_share(),
                "ratio_mean_deficit": self.group_ratio_mean("deficit"),
                "ratio_mean_normal": self.group_ratio_mean("normal")}

    def group_ratio_mean(self, h: str) -> float:
        p = self.posts[h]
        r = p.F[:, self.gidx].sum(axis=1) / self.f0[self.gidx].sum()
        return float(p.weights() @ r)

    def estimate(self) -> pd.DataFrame:
        """Posterior mean / sd per muscle of the mixture ``P(D) p(f | y, H_D) + P(N) p(f | y, H_N)``."""
        pd_ = self.p_deficit()
        E, M2 = 0.0, 0.0
        for h, ph in (("deficit", pd_), ("normal", 1.0 - pd_)):
            p = self.posts[h]
            w = p.weights()
            E = E + ph * (w @ p.F)
            M2 = M2 + ph * (w @ p.F ** 2)
        V = np.maximum(M2 - E ** 2, 0.0)
        return pd.DataFrame({"muscle": list(self.model.muscle_names), "f_c": E, "sd_c": np.sqrt(V), "v_c": V})

    # -- updates
    def push(self, direction: str, force: float, activations=None) -> None:
        self._snaps.append({h: p.snapshot() for h, p in self.posts.items()})
        try:
            self._both(lambda p: p.update(direction, force, activations), list(self.posts.values()))
        except Exception:
            s = self._snaps.pop()
            for h, p in self.posts.items():
                p.restore(s[h])
            raise
        self._emg.append(activations is not None)
        self.history.append(self.summary())

    def undo(self) -> None:
        if not self._snaps:
            raise ValueError("nothing to undo")
        s = self._snaps.pop()
        for h, p in self.posts.items():
            p.restore(s[h])
        self._emg.pop()
        self.history.pop()

    # -- the next test
    def scores(self) -> pd.DataFrame:
        """``decision_eig`` of every remaining test: I(H; y_i) in nats."""
        rem = self.remaining
        if not rem:
            raise ValueError("every direction has been tested")
        pD = self.p_deficit()
        out = []
        for d in rem:
            i = self.directions.index(d)
            out.append(self._mi(i, pD))
        return pd.DataFrame({"direction": rem, "score": out})

    def propose(self) -> tuple[str, pd.DataFrame]:
        df = self.scores()
        return str(df["direction"].iloc[int(np.argmax(df["score"].to_numpy()))]), df

    def _mi(self, i: int, pD: float) -> float:
        sd = self.settings.noise
        ys, ws = {}, {}
        for h, p in self.posts.items():
            w = p.weights()
            wi = p.W[:, i]
            pos = wi > 0
            ys[h] = np.log(wi[pos])
            ws[h] = (w[pos], float(w[~pos].sum()))
        allv = np.concatenate([y for y in ys.values() if len(y)]) if any(len(y) for y in ys.values()) else None
        if allv is None:
            return 0.0
        lo, hi = allv.min() - 5 * sd, allv.max() + 5 * sd
        nb = max(self.settings.n_ybins, int(math.ceil((hi - lo) / (sd / 4))))
        step = (hi - lo) / nb
        kx = np.arange(-int(math.ceil(5 * sd / step)), int(math.ceil(5 * sd / step)) + 1) * step
        ker = np.exp(-0.5 * (kx / sd) ** 2)
        ker /= ker.sum()
        dens = {}
        for h in self.posts:
            hist = np.bincount(np.clip(((ys[h] - lo) / step).astype(int), 0, nb - 1), weights=ws[h][0], minlength=nb)
            dens[h] = np.r_[np.convolve(hist, ker, mode="same"), ws[h][1]]     # last cell: not producible
        ph = {"deficit": pD, "normal": 1.0 - pD}

        def ent(q):
            q = q[q > 0]
            q = q / q.sum()
            return float(-(q * np.log(q)).sum())

        mix = ph["deficit"] * dens["deficit"] + ph["normal"] * dens["normal"]
        return max(0.0, ent(mix) - sum(ph[h] * ent(dens[h]) for h in self.posts))


def decide(model: ReducedModel, directions: Sequence[str], U: np.ndarray, force_scale: np.ndarray, f0: np.ndarray,
           forces: Sequence[float], settings: DecisionSettings, joint: JointSettings, rng: np.random.Generator,
           n_threads: int = 1) -> tuple[DeficitDecision, pd.DataFrame]:
    """The decision on a participant's measured forces (N, one per direction, NaN = not measured), the tests in
    the given order (a table's order: the answer after all of them does not depend on it beyond Monte Carlo
    error). Returns the decision object and its history (one row per test, 0 = before any)."""
    dec = DeficitDecision(model, directions, U, force_scale, f0, settings, joint, rng, n_threads=n_threads)
    for d, f in zip(directions, forces):
        if np.isfinite(f):
            dec.push(d, float(f))
    return dec, pd.DataFrame(dec.history)
