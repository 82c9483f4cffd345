"""Calibrated decision, remainder test and power of the gap diagnosis (issue 17, items 1-3).

**Null.** For each data set, noise-only data sets are simulated from its own fitted base model (the fit on
all directions; strengths drawn from the fit's Laplace uncertainty, :func:`truth_strengths`) with log-normal
noise of SD ``sigma`` (:func:`estimate_noise`): the participant's trial-to-trial scatter measured from repeat
trials (``repeats``), else a literature prior for the test-retest variability of maximal isometric neck strength
(``prior``; 'auto' picks the first that exists), a number, or 'heldout' = the root mean square of the log
held-out residuals of the best single candidate (the misfit counted as noise: the size of the remaining gap
cannot then be tested). The truths have the fitted model's own structure (``null_truth`` 'base'), or a finer one
(``null_truth`` 'elements', :class:`ElementNull`: each full-model element its own strength around its group's, so
the false-alarm rate also holds for data with element-level variation, at a cost in power measured in
docs/gap_diagnosis.md). The measured data set and its simulated ones are *screened*
alike, in one batch: the base model and every single effect on its grid, fitted from the same start point with
the calibration's ``starts`` and ``max_iter`` on the data set's fold split, each fold choosing its grid point by
training loss, scored by the held-out gap ``1 - D_cv``. With ``cv`` 'one_step' (the config's default) the folds are
not refitted: each takes guarded Gauss-Newton step(s) from the data set's all-direction fit
(:meth:`neckstrength.gap.engine.Engine.evaluate_one_step`; approximate CV, valid here because the null and the
power data sets are screened the same way). The decision uses the measured data set's screen scores,
so that its statistic and the null's come from the same procedure (fitting the simulated data from their truth,
or with other settings than the data, would make the test anti-conservative: an effect would "improve" the
data merely by reaching a better optimum). The full diagnosis (more starts, pairs, refinement) gives the
ranking, the fitted sizes and the "where" tables.

**Decision (maxT).** Per effect ``e`` the improvement ``delta_e = gap_none - gap_e``; standardised by its
null mean and SD, ``z_e = (delta_e - mu_e) / sd_e``; ``T = max_e z_e``. The adjusted p-value of the data set is
``(1 + #{null replicates with T >= T_obs}) / (R + 1)`` (Westfall-Young max-statistic: it accounts for choosing
the best of the effects, so the false-alarm rate of the decision is ``alpha`` over the whole candidate set).
The effect with the largest ``z`` is named when the adjusted p-value is at most ``alpha``, its improvement is
positive and its fitted size (fit on all directions) is not neutral; otherwise "no effect detectable".
The raw per-effect p-value ``(1 + #{delta_e^null >= delta_e}) / (R + 1)`` is reported in the ranking.

**Remainder.** After the named effect (or the base model), the held-out log residuals are tested for
structure by plane of the 3 x 3 grid (Fig. 4.2 / A.3): ``S`` = share of their sum of squares explained by plane
means (least squares on plane indicators; scale-free, so valid with an estimated noise level), against the same
effect's ``S`` in the null replicates. When the noise level is not estimated from these residuals (any source but
'heldout') the held-out gap itself is tested too, against the same candidate's held-out gap in the noise-only
replicates at that noise. Either significant: "the remaining gap is not explained by any candidate". Neither:
"consistent with noise" only where the gap was tested and the p-value can reach ``alpha`` (``replicates`` >=
1 / alpha - 1); else the verdict says what could not be tested (:func:`remainder_verdict`).

**Sensitivity.** Where the noise has a range (the prior's low and high, or the repeats' 95% interval), the
decision and the remainder are made again with ``replicates`` noise-only data sets at each end, screened in the
same batch (the measured data set's screen does not depend on the noise).

**Power.** For each effect and size in ``power_sizes`` (share of the way from neutral to the far bound, both
bounds alternating over replicates for two-sided parameters), ``power_replicates`` data sets are simulated from
the fitted base model with the effect at that size and noise ``sigma``, screened and decided exactly as the data;
power = share in which that effect is named. The smallest size with power >= ``power_target`` is the data set's
detectable size for the effect; none: undetectable at every size within its bound.

All simulated data sets of all data sets are fitted in one engine (shared solver calls). Every draw derives
from the seed and the data set's name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.gap.effects import Effect, GapContext, available_effects, base_instance, compose
from neckstrength.gap.engine import (
    BlindData,
    CalibrationSettings,
    DiagnosisSettings,
    Engine,
    _d,
    cv_predictions,
    direction_folds,
    single_effect_grids,
)
from neckstrength.gap.fit import FitSettings, Simulator
from neckstrength.seeds import derive_rng


def plane_indicators(directions: pd.DataFrame) -> np.ndarray:
    """(K x planes) membership of each direction in the planes of the 3 x 3 grid (column ``planes``)."""
    sets = [set(str(p).split(";")) for p in directions["planes"]]
    names = sorted(set().union(*sets) - {"", "nan"})
    return np.array([[n in s for n in names] for s in sets], float).reshape(len(sets), len(names))


def plane_structure(logres: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Share of the sum of squares of log residuals (n x K) explained by plane means (least squares on X)."""
    r = np.atleast_2d(logres)
    if X.shape[1] == 0:
        return np.zeros(len(r))
    B, *_ = np.linalg.lstsq(X, r.T, rcond=None)
    fit = (X @ B).T
    ss = (r ** 2).sum(axis=1)
    return np.where(ss > 0, (fit ** 2).sum(axis=1) / np.maximum(ss, 1e-300), 0.0)


@dataclass
class Screen:
    """Held-out gap and plane structure of every candidate ('none' and each single effect) per data set."""

    names: list[str]
    candidates: list[str]
    gap: np.ndarray          # (data sets x candidates)
    structure: np.ndarray    # (data sets x candidates)
    rms: np.ndarray          # (data sets x candidates) RMS log held-out residual


def screen_scores(ctx: GapContext, T: np.ndarray, preds: dict[str, np.ndarray], eps: float,
                  X: np.ndarray, names: list[str]) -> Screen:
    cands = list(preds)
    gap = np.column_stack([1 - _d(preds[c], T, eps).mean(axis=1) for c in cands])
    lr = {c: np.log(np.maximum(preds[c], 1e-12) / T) for c in cands}
    st = np.column_stack([plane_structure(lr[c], X) for c in cands])
    rms = np.column_stack([np.sqrt((lr[c] ** 2).mean(axis=1)) for c in cands])
    return Screen(names, cands, gap, st, rms)


def screen(ctx: GapContext, data: list[BlindData], folds: np.ndarray, effects: list[Effect],
           s: DiagnosisSettings, say=None, workers: int = 1, checkpoints=None) -> Screen:
    """Base model and every single effect on its grid, cross-validated on ``folds`` (data sets x K), all data
    sets fitted alike (the diagnosis's start point, the calibration's ``starts`` and ``max_iter``).
    ``workers`` > 1: the effects are shared out over that many processes (this one and forked workers), each
    screening every data set (:func:`single_effect_grids`): larger batches cost less per data set than the
    data sets split into groups (before 2026-11-24 evening); a data set's scores do not depend on either.
    ``checkpoints``: each effect's fits stored as they finish (:func:`single_effect_grids`)."""
    cs = s.calibration
    s2 = DiagnosisSettings(**{**s.__dict__, "starts": cs.starts,
                              "fit": FitSettings(**{**s.fit.__dict__, "max_iter": cs.max_iter})})
    one = int(cs.cv_steps) if cs.cv == "one_step" else 0
    eng = Engine(ctx, data, s2, folds, {e.name: e for e in effects}, full=bool(one))
    if one:
        eng.evaluate_one_step((), eng.prior, one)
    else:
        eng.evaluate((), eng.prior)
    keys = single_effect_grids(eng, effects, say, tag="  simulated data: ", one_step=one, workers=workers,
                               checkpoints=checkpoints)
    preds = {c: cv_predictions(eng, k) for c, k in keys.items()}
    T = np.array([d.forces for d in data], float)
    return screen_scores(ctx, T, preds, s.epsilon, plane_indicators(ctx.directions), [d.name for d in data])


def size_theta(e: Effect, u: float, sign: int) -> np.ndarray:
    """Parameters ``u`` of the way from neutral to a bound (the upper one for ``sign`` > 0 where both exist); a shape
    parameter (:attr:`neckstrength.gap.effects.Param.shape`) stays neutral."""
    th = []
    for p in e.params():
        if p.shape:
            th.append(p.neutral)
            continue
        up, down = p.hi - p.neutral, p.neutral - p.lo
        if up > 1e-12 and down > 1e-12:
            far = p.hi if sign > 0 else p.lo
        else:
            far = p.hi if up >= down else p.lo
        th.append(p.neutral + u * (far - p.neutral))
    return np.array(th)


#: Ties of an observed statistic with a noise-only replicate's, within this share of the statistic's size (at least
#: 1), count as the replicate's exceeding it (the conservative Monte Carlo p-value). A data set where no effect
#: improves anything has T = max_e(-mu_e / sd_e), exactly the value of every replicate where none improves either;
#: with an absolute 1e-12 the fits' rounding (1e-10) decided those ties, so a solver change moved a p-value by 0.2.
TIE_REL = 1e-9


def at_least(null: np.ndarray, obs) -> np.ndarray:
    """``null >= obs`` with ties within :data:`TIE_REL` counted (broadcasting as numpy does)."""
    obs = np.asarray(obs, float)
    return null >= obs - TIE_REL * np.maximum(1.0, np.abs(obs))


def maxt(delta: np.ndarray, mu: np.ndarray, sd: np.ndarray, t_null: np.ndarray):
    """Standardised improvements z (n x E), the best effect per row, T = max z and its adjusted p-value."""
    z = (delta - mu[None]) / sd[None]
    t = z.max(axis=1)
    p = (1 + at_least(t_null[None, :], t[:, None]).sum(axis=1)) / (len(t_null) + 1)
    return z, z.argmax(axis=1), t, p


@dataclass
class Calibration:
    """Per data set: noise level, null summaries, decision inputs and the power table."""

    sigma: float
    noise_source: str
    effects: list[str]
    delta_null: np.ndarray       # (R x E)
    mu: np.ndarray
    sd: np.ndarray
    t_null: np.ndarray           # (R,)
    gap_null: np.ndarray         # (R x (1 + E)), 'none' first
    structure_null: np.ndarray   # (R x (1 + E))
    power: pd.DataFrame
    gap_obs: np.ndarray          # (1 + E) the measured data set's screen: held-out gaps
    structure_obs: np.ndarray    # (1 + E) and plane structure of its held-out log residuals
    phi_fit: np.ndarray | None = None   # the base fit on all directions (log free strengths) the null is drawn
    f_fit: np.ndarray | None = None     # around, and its forces
    noise: "NoiseLevel | None" = None   # where sigma comes from, and its range
    rms_null: np.ndarray | None = None  # (R x (1 + E)) RMS log held-out residual of the null replicates
    rms_obs: np.ndarray | None = None   # (1 + E) and of the measured data set
    sensitivity: list = None            # [(label, Calibration at the range's end)], without power
    null: str = "base"                  # where the null's truths come from (NULL_TRUTHS)
    null_note: str = ""                 # the report's sentence about it (NULL_NOTES)
    selection: str = "largest_improvement"   # which significant effect is named (SELECTIONS)
    alpha: float = 0.05                 # the level at which an effect counts as significant for ``selection``

    def decide(self, gap: np.ndarray) -> dict:
        """``gap``: held-out gaps ('none' first, then the effects in ``effects`` order) of one data set.

        The maxT test: some effect is named when the largest standardised improvement z has adjusted p <= alpha.
        Which one (``selection``): 'max_z', that effect; 'largest_improvement', among the effects whose own z
        passes the same test (adjusted p <= ``alpha``) with a positive improvement, the one with the largest
        improvement of the held-out gap (the cross-validated fit decides, as the ranking does). Whether an effect
        is named, and so the false-alarm rate, is the same under both. 'p_adjusted': the named (or best) effect's
        own adjusted p-value."""
        delta = gap[0] - gap[1:]
        z, best, t, p_adj = maxt(delta[None], self.mu, self.sd, self.t_null)
        R = len(self.delta_null)
        p_raw = (1 + at_least(self.delta_null, delta[None]).sum(axis=0)) / (R + 1)
        b = int(best[0])
        p_each = (1 + at_least(self.t_null[None, :], z[0][:, None]).sum(axis=1)) / (len(self.t_null) + 1)
        if self.selection == "largest_improvement":
            ok = np.flatnonzero((p_each <= self.alpha) & (delta > 0))
            if ok.size:
                b = int(ok[np.argmax(delta[ok])])
        elif self.selection != "max_z":
            raise ValueError(f"gap.calibration.selection: one of {', '.join(SELECTIONS)}, not {self.selection!r}")
        return {"delta": delta, "z": z[0], "best": self.effects[b], "T": float(t[0]),
                "p_adjusted": float(p_each[b]), "p_raw": p_raw, "best_z": self.effects[int(best[0])]}

    def remainder(self, j: int, gap: float, structure: float) -> dict:
        """Tests of candidate ``j`` (0 = none)'s remaining held-out gap against the same null."""
        R = len(self.gap_null)
        p_s = (1 + at_least(self.structure_null[:, j], structure).sum()) / (R + 1)
        p_g = ((1 + at_least(self.gap_null[:, j], gap).sum()) / (R + 1)) if self.noise_source != "heldout" \
            else np.nan
        return {"p_structure": float(p_s), "p_gap": float(p_g)}


#: which of the significant effects the calibrated decision names (``gap.calibration.selection``;
#: :meth:`Calibration.decide`)
SELECTIONS = ("max_z", "largest_improvement")

#: where the noise-only replicates' truths come from (``gap.calibration.null_truth``): 'base' = the fitted model's own
#: structure (its groups, tied sides), 'elements' = a finer one (every full-model element its own strength, drawn
#: per replicate: :class:`ElementNull`)
NULL_TRUTHS = ("base", "elements")

#: the report's sentence per null source (docs/gap_diagnosis.md, "Calibration")
NULL_NOTES = {
    "base": "the fitted model's own structure (its muscle groups, sides tied as in the fit) plus noise; a finer "
            "muscle structure (e.g. each of the 96 elements its own strength) can be named as an effect",
    "elements": "a finer structure than the model's (each full-model element its own strength: the fitted group "
                "strength x exp(N(0, {spread:g})) per element, left and right apart) plus noise; such element-level "
                "variation is not named as an effect",
}


class ElementNull:
    """Forces of the element null's truths (``gap.calibration.null_truth: elements``).

    Every element of the full model that belongs to a fitted group is its own LP column (moment arms of the full
    model at the model's joints; the rows, test directions and force scales of the fitted model's instance), with
    strength ``f_el = full strength x f_g / model strength_g x c_el``: the group strength ``f_g`` of the
    replicate's truth (:func:`truth_strengths`) and a factor ``c_el = exp(N(0, spread))`` drawn per element and
    replicate, normalised so that the strength-weighted mean factor of each free parameter's elements (a group,
    both sides where the fit ties them) is 1: the fitted group totals keep their meaning, while elements within a
    group and the two sides of a tied group vary apart (as individuals' muscles do: the finer structure, not an
    effect). Made here from :func:`neckstrength.gap.effects.base_instance` and the solver, apart from the user
    benchmark's 96-element truth (:mod:`neckstrength.gap.truths`)."""

    def __init__(self, ctx: GapContext, spread: float):
        from dataclasses import replace

        from neckstrength.estimation.parameters import free_parameters
        from neckstrength.model.full import COORDINATES

        if not spread >= 0:
            raise ValueError(f"gap.calibration.element_spread: a log SD >= 0, not {spread!r}")
        full, model = ctx.full, ctx.model
        inst = base_instance(ctx)
        S = np.asarray(model.S, float)
        el = np.array([i for i in range(full.m) if full.strengths[i] > 0 and S[i].max() > 0], int)
        grp = S[el].argmax(axis=1)
        ok = model.strengths[grp] > 0
        el, grp = el[ok], grp[ok]
        rows = [COORDINATES.index(c) for c in model.coordinates]
        A = np.zeros((len(el), model.m))
        A[np.arange(len(el)), grp] = full.strengths[el] / model.strengths[grp]
        elem = np.zeros((full.m, len(el)))
        elem[el, np.arange(len(el))] = 1.0
        K = inst.lb.shape[0]
        R = full.moment_arms[rows][:, el]
        R = np.vstack([R, np.zeros((inst.R.shape[0] - R.shape[0], R.shape[1]))])
        self.inst = replace(inst, R=R, A=A, a0=np.zeros(len(el)), cols=tuple(full.names[i] for i in el),
                            col_group=grp, elem=elem, lb=np.zeros((K, len(el))), ub=np.ones((K, len(el))))
        self.sim = Simulator(ctx, self.inst)
        pidx, _ = free_parameters(model, ctx.tie_sides)
        self.owner = np.asarray(pidx)[grp]                 # free parameter of each element column
        self.weight = full.strengths[el]
        self.spread = float(spread)

    def factors(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n x elements) strength factors, normalised per free parameter (strength-weighted mean 1)."""
        c = np.exp(rng.normal(0.0, self.spread, (n, len(self.weight))))
        for q in np.unique(self.owner):
            s = self.owner == q
            c[:, s] /= (c[:, s] @ self.weight[s] / self.weight[s].sum())[:, None]
        return c

    def forces(self, F: np.ndarray, factors: np.ndarray) -> np.ndarray:
        """Max force (N, n x K) of group strengths ``F`` (n x m) with element factors (n x elements)."""
        from neckstrength.wrench import solve

        F = np.atleast_2d(F)
        if len(F) == 0:
            return np.zeros((0, self.sim.K))
        Fa = self.inst.strengths(F) * factors
        w, _, _ = solve(self.sim.model, Fa, self.sim.U, self.sim.lb, self.sim.ub, return_alpha=False,
                        cache=self.sim.cache)
        return np.nan_to_num(np.asarray(w, float), nan=0.0) * self.sim.fmul[None, :, 0]


def truth_strengths(sim: Simulator, phi_fit: np.ndarray, T: np.ndarray, sigma: float, spread: float, n: int,
                    rng: np.random.Generator) -> np.ndarray:
    """``n`` log strength vectors for simulated data sets: the fit plus a draw from its Laplace uncertainty,
    ``N(phi_fit, (J'J / sigma^2 + I / spread^2)^-1)`` with ``J`` the exact Jacobian of the relative forces at
    the fit (all directions) and ``spread`` the individual spread of log strengths. Strengths the directions
    determine vary by their estimation error; strengths they leave open vary like individuals do, so the
    simulated data are as hard to predict held out as real ones (the fit alone, pulled to the prior by the
    ridge where the directions say nothing, would make them easier and the test anti-conservative)."""
    if n == 0:
        return np.zeros((0, len(phi_fit)))
    _, G = sim.forces_grad_phi(phi_fit[None])
    J = G[0] / T[:, None]
    p = len(phi_fit)
    prec = J.T @ J / max(sigma, 1e-6) ** 2 + np.eye(p) / max(spread, 1e-6) ** 2
    L = np.linalg.cholesky(np.linalg.inv(prec) + 1e-12 * np.eye(p))
    return phi_fit[None] + rng.normal(0.0, 1.0, (n, p)) @ L.T


#: Literature prior for the trial-to-trial (test-retest) log SD of maximal isometric neck strength where a
#: participant has no repeats: (low, central, high). Sources and reasoning: docs/gap_diagnosis.md ("Noise").
PRIOR_NOISE = (0.05, 0.08, 0.15)

NOISE_SETTINGS = ("auto", "repeats", "prior", "heldout")


@dataclass(frozen=True)
class NoiseLevel:
    """The noise SD of the simulated data sets, its source ('repeats', 'prior', 'given', 'heldout'), the range
    the sensitivity table spans (nan: none) and a sentence for the report."""

    sigma: float
    source: str
    low: float = np.nan
    high: float = np.nan
    note: str = ""

    def __iter__(self):                  # (sigma, source), as before issue 32
        return iter((self.sigma, self.source))


def estimate_noise(rms_heldout: np.ndarray, setting, name: str = "", repeats=(),
                   prior: tuple[float, float, float] = PRIOR_NOISE) -> NoiseLevel:
    """Log-normal noise SD of data set ``name``'s simulated data (``setting``: 'auto', 'repeats', 'prior',
    'heldout' or a number; ``repeats``: ``(name, sd, df, ci_low, ci_high)`` per data set with repeat trials)."""
    if isinstance(setting, (int, float)) and not isinstance(setting, bool):
        if not setting > 0:
            raise ValueError(f"gap.calibration.noise: a positive log SD, not {setting!r}")
        return NoiseLevel(float(setting), "given", note="given in the config")
    if setting not in NOISE_SETTINGS:
        raise ValueError(f"gap.calibration.noise: one of {', '.join(NOISE_SETTINGS)} or a number, not {setting!r}")
    if setting == "heldout":
        return NoiseLevel(float(np.nanmin(rms_heldout)), "heldout",
                          note="the smallest RMS log held-out residual over the candidates: the misfit counts as "
                               "noise, so the size of the remaining gap cannot be tested")
    rep = {str(r[0]): r for r in repeats}
    if setting in ("repeats", "auto") and name in rep:
        _, sd, df, lo, hi = rep[name]
        return NoiseLevel(float(sd), "repeats", float(lo), float(hi),
                          f"this participant's trial-to-trial scatter, pooled over the repeat trials (df {int(df)}, "
                          f"95% interval {lo:.3f}-{hi:.3f})")
    if setting == "repeats":
        raise ValueError(f"gap.calibration.noise 'repeats': no repeat-trial noise for data set {name!r} "
                         f"(gap.calibration.noise_table has {', '.join(sorted(rep)) or 'none'})")
    lo, c, hi = (float(x) for x in prior)
    return NoiseLevel(c, "prior", lo, hi,
                      f"no repeat trials{' for this participant' if setting == 'auto' else ''}: the literature "
                      f"prior for the test-retest variability of maximal isometric neck strength (central {c:g}, "
                      f"range {lo:g}-{hi:g}; not measured here)")


def remainder_verdict(rem: dict, cal: "Calibration", alpha: float, where: str) -> tuple[str, bool | None]:
    """The remainder's sentence and whether it is unexplained (None: could not be tested)."""
    gap_tested = np.isfinite(rem["p_gap"])
    if rem["p_structure"] <= alpha or (gap_tested and rem["p_gap"] <= alpha):
        return f"the remaining gap is not explained by any candidate: it lies in {where}", True
    resolution = 1.0 / (len(cal.gap_null) + 1)
    if resolution > alpha:
        return (f"the remainder cannot be tested: {len(cal.gap_null)} noise-only replicates give p-values of at "
                f"least {resolution:.2g} > alpha {alpha:g}"), None
    if not gap_tested:
        return ("the size of the remaining gap cannot be tested (the noise level was estimated from the held-out "
                "residuals themselves, gap.calibration.noise 'heldout'); its plane structure is within the "
                "noise-only replicates'"), None
    return "the remaining held-out gap is consistent with noise", False


#: The power replicates screened after the null in two stages (:func:`_power_hits`); False: with the null, every
#: effect at once (before 2026-11-28; the same power table at about 1.5x the screen's CPU), kept as the reference
#: of ``benchmarks/bench_gap.py --staged``.
POWER_IN_TWO_STAGES = True


def sensitivity_replicates(cs: CalibrationSettings) -> int:
    """Noise-only replicates at each end of the noise's range (``cs.sensitivity_replicates``, default
    ``cs.replicates``)."""
    return int(cs.replicates if cs.sensitivity_replicates is None else cs.sensitivity_replicates)


def _truth_phis(sim_base: Simulator, phi_fit: np.ndarray, T: np.ndarray, sigma: float, cs: CalibrationSettings,
                name: str, seed: int, tag: str = "") -> np.ndarray:
    """Truth log strengths of a data set's simulated data sets: rows ``0..R-1`` the noise-only ones, then
    ``power_replicates`` per power size. Drawn row by row from one stream, so the first rows do not depend on
    how many power replicates follow (a diagnosis without power draws the same null)."""
    n_pow = len(cs.power_sizes) * cs.power_replicates
    if tag:                                                # a sensitivity null: its own stream, no power rows
        return truth_strengths(sim_base, phi_fit, T, sigma, cs.strength_spread, sensitivity_replicates(cs),
                               derive_rng(seed, f"gap/truth/{name}/{tag}"))
    return truth_strengths(sim_base, phi_fit, T, sigma, cs.strength_spread, int(cs.replicates) + n_pow,
                           derive_rng(seed, f"gap/truth/{name}"))


def _power_sets(ctx: GapContext, names: list[str], phis: dict, f_fit: np.ndarray, sigmas: list[float],
                effects_of: list[list[Effect]], cs: CalibrationSettings, seed: int):
    """Simulated data sets with an effect: per data set ``i`` and effect in ``effects_of[i]``, per size in
    ``power_sizes``, ``power_replicates`` data sets from the data set's truth strengths (rows after the null's)
    with the effect at that size (upper and lower bound alternating) and log-normal noise ``sigmas[i]``.
    Returns the data sets and, per draw, (data set, 'power' or 'skip' (a direction the truth cannot produce),
    effect, size)."""
    R, K, P = int(cs.replicates), ctx.K, cs.power_replicates
    sims, meta = [], []
    union = list({e.name: e for es in effects_of for e in es}.values())
    for e in union:
        who = [i for i in range(len(names)) if any(x.name == e.name for x in effects_of[i])]
        for a, u in enumerate(cs.power_sizes):
            truth = {}
            for sign in (1, -1):
                sim = Simulator(ctx, compose(ctx, [e], [size_theta(e, u, sign)]))
                truth[sign] = {i: sim.forces(sim.muscles(phis[i][R + a * P:R + (a + 1) * P])) if P
                               else np.zeros((0, K)) for i in who}
            for i in who:
                n = names[i]
                z = derive_rng(seed, f"gap/power/{n}/{e.name}/{u:.6g}").normal(0.0, 1.0, (P, K))
                for r in range(P):
                    f = truth[1 if r % 2 == 0 else -1][i][r]
                    ok = bool(np.all(f > 0.05 * np.median(f_fit[i])))
                    meta.append((i, "power", e.name, float(u)) if ok else (i, "skip", e.name, float(u)))
                    if ok:
                        sims.append(BlindData(f"{n}/power/{e.name}/{u:.6g}/{r}", f * np.exp(sigmas[i] * z[r])))
    return sims, meta


def _hit(cal: Calibration, gap: np.ndarray, effect: str, alpha: float) -> bool:
    """Whether ``cal`` names ``effect`` for a simulated data set with screen gaps ``gap`` ('none' first)."""
    d = cal.decide(gap)
    return bool(d["p_adjusted"] <= alpha and d["best"] == effect and d["delta"][cal.effects.index(effect)] > 0)


def _power_table(cal: Calibration, i: int, effects: list[Effect], cs: CalibrationSettings, meta: list,
                 gaps: np.ndarray | None = None, hits: np.ndarray | None = None) -> pd.DataFrame:
    """Power per effect and size of data set ``i``: share of its simulated data sets (``meta`` rows that were
    screened; 'skip' rows counted) in which ``cal`` names the effect: from ``gaps`` (their screen gaps in the
    same order) or, where the caller decided already, from ``hits`` (one boolean per screened row)."""
    ok = [m for m in meta if m[1] != "skip"]
    prow = []
    for e in effects:
        for u in cs.power_sizes:
            rr = [j for j, m in enumerate(ok) if m[0] == i and m[1] == "power" and m[2] == e.name
                  and m[3] == float(u)]
            skipped = sum(1 for m in meta if m[0] == i and m[1] == "skip" and m[2] == e.name and m[3] == float(u))
            n_hit = sum(int(hits[j]) if hits is not None else int(_hit(cal, gaps[j], e.name, cs.alpha)) for j in rr)
            prow.append({"effect": e.name, "size_share": u, "theta": e.describe(size_theta(e, u, 1)),
                         "replicates": len(rr), "skipped_unproducible": skipped, "identified": n_hit,
                         "power": n_hit / len(rr) if rr else np.nan})
    return pd.DataFrame(prow)


def calibrate(ctx: GapContext, names: list[str], folds: np.ndarray, T: np.ndarray, f_fit: np.ndarray,
              phi_fit: np.ndarray, rms_obs: np.ndarray, effects: list[Effect], s: DiagnosisSettings,
              say=None, workers: int = 1, checkpoints=None, noises: Sequence[NoiseLevel] | None = None
              ) -> list[Calibration]:
    """Null and power replicates for every data set (``names``, fold splits, measured forces ``T``, base fit
    forces ``f_fit`` and log strengths ``phi_fit``, held-out RMS log residuals per candidate ``rms_obs``).
    With ``power_replicates`` 0 there is no power table (the decision is the same: every data set is screened
    on its own, whatever else is screened with it); :func:`power_for` adds one later. The power replicates are
    screened after the null in two stages (:func:`_power_hits`: each with its own effect first, with every effect
    only if it passes that effect's necessary test), the same table as screening each with every effect at once
    (before 2026-11-28) at about half the cost. ``noises``: each data set's noise level where the caller has it
    already (else :func:`estimate_noise` of ``rms_obs`` and the settings)."""
    say = say or (lambda msg: None)
    cs: CalibrationSettings = s.calibration
    R, nd, K = int(cs.replicates), len(names), ctx.K
    E = [e.name for e in effects]
    sig = list(noises) if noises is not None else [estimate_noise(rms_obs[i], cs.noise, n, cs.repeats,
                                                                  cs.noise_prior) for i, n in enumerate(names)]
    sims, meta = [], []                                    # simulated data sets and (data set, kind, effect, size)
    sim_base = Simulator(ctx, base_instance(ctx))
    if cs.null_truth not in NULL_TRUTHS:
        raise ValueError(f"gap.calibration.null_truth: one of {', '.join(NULL_TRUTHS)}, not {cs.null_truth!r}")
    el_null = ElementNull(ctx, cs.element_spread) if cs.null_truth == "elements" and R else None
    phis = {}                                              # truth log strengths per data set: (R + power reps) x p
    sens = {i: ([("low", sig[i].low), ("high", sig[i].high)] if cs.sensitivity and np.isfinite(sig[i].low)
                else []) for i in range(nd)}

    R_sens = sensitivity_replicates(cs)

    def add_null(i, n, sigma, ph, kind, tag, R=R):
        if el_null is not None:                            # the finer structure: element factors per replicate
            fac = el_null.factors(R, derive_rng(s.seed, f"gap/elements/{n}" + (f"/{tag}" if tag else "")))
            f_null = el_null.forces(sim_base.muscles(ph[:R]), fac)
        else:
            f_null = sim_base.forces(sim_base.muscles(ph[:R])) if R else np.zeros((0, K))
        f_null = np.maximum(f_null, 1e-3 * np.median(f_fit[i]))       # a direction the draw cannot produce
        z = derive_rng(s.seed, f"gap/null/{n}" + (f"/{tag}" if tag else "")).normal(0.0, 1.0, (R, K))
        for r in range(R):
            sims.append(BlindData(f"{n}/{kind}{r}", f_null[r] * np.exp(sigma * z[r])))
            meta.append((i, kind, "", 0.0))

    for i, n in enumerate(names):
        phis[i] = _truth_phis(sim_base, phi_fit[i], T[i], sig[i].sigma, cs, n, s.seed)
        add_null(i, n, sig[i].sigma, phis[i], "null", "")
        for lab, sg in sens[i]:
            tag = f"noise{sg:.6g}"
            add_null(i, n, sg, _truth_phis(sim_base, phi_fit[i], T[i], sg, cs, n, s.seed, tag), f"null_{lab}", tag,
                     R_sens)
    ps, pm = [], []
    if cs.power_replicates > 0:      # screened after the null, in two stages (:func:`_power_hits`)
        ps, pm = _power_sets(ctx, names, phis, f_fit, [sg.sigma for sg in sig], [list(effects)] * nd, cs, s.seed)
        if not POWER_IN_TWO_STAGES:  # the reference: screened with the null, every effect at once
            sims, meta, ps = sims + ps, meta + pm, []
    for i, n in enumerate(names):                          # the measured data sets, screened alike
        sims.append(BlindData(n, T[i]))
        meta.append((i, "observed", "", 0.0))
    meta_ok = [m for m in meta if m[1] != "skip"]
    say(f"calibration: {len(sims) + len(ps) - nd} simulated data sets ({R} noise-only per data set, "
        f"{len(effects)} effects x {len(cs.power_sizes)} sizes x {cs.power_replicates} with an effect); null "
        f"truths: {cs.null_truth}"
        + (f" (element spread {cs.element_spread:g})" if cs.null_truth == "elements" else "") + "; noise "
        + ", ".join(f"{n} {sg.sigma:.3f} ({sg.source})" for n, sg in zip(names, sig))
        + (f"; sensitivity: {R_sens} more at each end of the noise's range" if any(sens.values()) else ""))
    if sims:
        idx = [m[0] for m in meta_ok]
        sc = screen(ctx, sims, folds[idx], effects, s, say, workers, checkpoints)
    out = []

    def null_cal(i, kind, sigma, source, jo):
        rows = [j for j, m in enumerate(meta_ok) if m[0] == i and m[1] == kind]
        gap_null = sc.gap[rows]
        delta_null = gap_null[:, :1] - gap_null[:, 1:]
        mu = delta_null.mean(axis=0)
        sd = np.maximum(delta_null.std(axis=0, ddof=1) if len(rows) > 1 else np.zeros(len(E)), cs.sd_floor)
        _, _, t_null, _ = maxt(delta_null, mu, sd, np.zeros(0))
        return Calibration(sigma, source, E, delta_null, mu, sd, t_null, gap_null, sc.structure[rows],
                           pd.DataFrame(), sc.gap[jo], sc.structure[jo], np.asarray(phi_fit[i], float).copy(),
                           np.asarray(f_fit[i], float).copy(), rms_null=sc.rms[rows], rms_obs=sc.rms[jo],
                           null=cs.null_truth,
                           null_note=NULL_NOTES[cs.null_truth].format(spread=cs.element_spread),
                           selection=cs.selection, alpha=cs.alpha)

    for i, n in enumerate(names):
        jo = next(j for j, m in enumerate(meta_ok) if m[0] == i and m[1] == "observed")
        cal = null_cal(i, "null", sig[i].sigma, sig[i].source, jo)
        cal.noise = sig[i]
        cal.sensitivity = [(lab, null_cal(i, f"null_{lab}", sg, f"{sig[i].source} {lab}", jo))
                           for lab, sg in sens[i]]
        if cs.power_replicates > 0 and not POWER_IN_TWO_STAGES:
            cal.power = _power_table(cal, i, effects, cs, meta, sc.gap)
        out.append(cal)
    if cs.power_replicates > 0 and POWER_IN_TWO_STAGES:
        pm_ok = [m for m in pm if m[1] != "skip"]
        hits = _power_hits(ctx, ps, [(m[0], m[2]) for m in pm_ok], folds, out, {e.name: e for e in effects},
                           effects, s, say, workers, checkpoints)
        for i, cal in enumerate(out):
            cal.power = _power_table(cal, i, effects, cs, pm, hits=hits)
    return out


def power_for(ctx: GapContext, data: list[BlindData], cals: list[Calibration], effects_of: list[list[str]],
              s: DiagnosisSettings, say=None, workers: int = 1, checkpoints=None) -> list[pd.DataFrame]:
    """The power table of each data set for the effects ``effects_of[i]`` only, with the calibration ``cals[i]``
    of its diagnosis (made with ``power_replicates`` 0 and otherwise the settings ``s``): the same simulated
    data sets and decision as :func:`calibrate` with the power, so equal to that table's rows of these effects;
    screened in two stages (:func:`_power_hits`: a data set that fails its own effect's necessary test is not
    screened with the other effects). (The withheld-effect benchmark needs the power of the injected effect
    only.) ``workers``: processes sharing out the screens (the answers do not depend on it); ``checkpoints``:
    the screens' effects stored as they finish."""
    cs = s.calibration
    names = [d.name for d in data]
    reg = {e.name: e for e in available_effects(ctx, s.effects)}
    sim_base = Simulator(ctx, base_instance(ctx))
    phis = {i: _truth_phis(sim_base, c.phi_fit, np.asarray(d.forces, float), c.sigma, cs, d.name, s.seed)
            for i, (d, c) in enumerate(zip(data, cals))}
    f_fit = np.array([c.f_fit for c in cals])
    eff_of = [[reg[n] for n in ns] for ns in effects_of]
    sims, meta = _power_sets(ctx, names, phis, f_fit, [c.sigma for c in cals], eff_of, cs, s.seed)
    ok = [m for m in meta if m[1] != "skip"]
    folds = np.array([direction_folds(ctx.K, s.folds, derive_rng(s.seed, f"gap/folds/{n}")) for n in names]
                     ).reshape(len(names), ctx.K)
    if say:
        say(f"power: {len(sims)} simulated data sets with an effect for {len(names)} data set(s)")
    eff = [reg[n] for n in cals[0].effects]
    hits = _power_hits(ctx, sims, [(m[0], m[2]) for m in ok], folds, cals, reg, eff, s, say, workers, checkpoints)
    return [_power_table(c, i, eff_of[i], cs, meta, hits=hits) for i, c in enumerate(cals)]


def _power_hits(ctx: GapContext, sims: list[BlindData], owner: list[tuple[int, str]], folds: np.ndarray,
                cals: list[Calibration], reg: dict[str, Effect], eff: list[Effect], s: DiagnosisSettings, say,
                workers: int, checkpoints=None) -> np.ndarray:
    """Whether the decision names the simulated data set's own effect, for each of ``sims`` (``owner``: its data
    set and effect), in two stages that give the same answers as screening every data set with every effect.

    A data set counts only if its effect ``e`` is named, i.e. ``e`` has the largest z, that z's adjusted p-value is
    at most alpha and its improvement is positive; the largest z is at least ``z_e``, so ``p(z_e) <= alpha`` and
    ``delta_e > 0`` are necessary. Stage 1 screens each data set with the base model and its own effect only (the
    effects' groups in ``workers`` forked processes, the most expensive first); the data sets that fail the
    necessary condition are not named. Stage 2 screens the others with every effect and decides exactly as the
    diagnosis does. (Equal up to the solver's rounding, which depends on what is fitted together; a data set
    within that rounding of the threshold could differ.)"""
    from neckstrength.gap.engine import grid_cost
    from neckstrength.gap.forked import fork_map

    cs = s.calibration
    hits = np.zeros(len(sims), bool)
    if not sims:
        return hits
    groups: dict[str, list[int]] = {}
    for j, (_, e) in enumerate(owner):
        groups.setdefault(e, []).append(j)
    order = sorted(groups, key=lambda e: -len(groups[e]) * grid_cost(reg[e], s.grid_points))

    def stage1(e: str) -> np.ndarray:
        js = groups[e]
        return screen(ctx, [sims[j] for j in js], folds[[owner[j][0] for j in js]], [reg[e]], s,
                      checkpoints=checkpoints).gap

    if workers > 1 and len(order) > 1:
        gap1 = {order[k]: g for k, g in fork_map(stage1, order, workers)}
    else:
        gap1 = {e: stage1(e) for e in order}
    second = []
    for e, js in groups.items():
        for t, j in enumerate(js):
            cal = cals[owner[j][0]]
            k = cal.effects.index(e)
            delta = gap1[e][t, 0] - gap1[e][t, 1]
            _, _, _, p = maxt(np.array([[delta]]), cal.mu[k:k + 1], cal.sd[k:k + 1], cal.t_null)
            if p[0] <= cs.alpha and delta > 0:
                second.append(j)
    second.sort()
    if say:
        say(f"power: {len(sims)} simulated data sets screened with their own effect; {len(second)} pass its test "
            "and are screened with every effect")
    if second:
        gap2 = screen(ctx, [sims[j] for j in second], folds[[owner[j][0] for j in second]], eff, s, say,
                      workers, checkpoints).gap
        for t, j in enumerate(second):
            hits[j] = _hit(cals[owner[j][0]], gap2[t], owner[j][1], cs.alpha)
    return hits


def power_summary(power: pd.DataFrame, target: float) -> pd.DataFrame:
    """Per effect: the smallest simulated size identified in >= ``target`` of its replicates, or none."""
    rows = []
    if power.empty:
        return pd.DataFrame(columns=["effect", "min_detectable_share", "at", "power_there", "sizes_covered",
                                     "statement"])
    for e, g in power.groupby("effect", sort=False):
        ok = g[(g["replicates"] > 0) & (g["power"] >= target)]
        sizes = ", ".join(f"{u:g}" for u in g["size_share"])
        if len(ok):
            r = ok.sort_values("size_share").iloc[0]
            rows.append({"effect": e, "min_detectable_share": float(r["size_share"]), "at": r["theta"],
                         "power_there": float(r["power"]), "sizes_covered": sizes,
                         "statement": f"detectable from {r['size_share']:g} of its range ({r['theta']})"})
        else:
            rows.append({"effect": e, "min_detectable_share": np.nan, "at": "-", "power_there": np.nan,
                         "sizes_covered": sizes,
                         "statement": f"not told from noise at any simulated size up to its bound ({sizes})"})
    return pd.DataFrame(rows)
