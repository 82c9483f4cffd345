"""Truths for the user-facing gap benchmark, made the way tests go wrong, apart from the diagnosis's effects.

Every case is a participant of the fitted model's kind (individual group strengths around the baseline) whose
test forces come from one of these truths, computed here from the full model, the posture tables and the
max-wrench LP (:func:`neckstrength.wrench.solve`) only. This module does not import the diagnosis's effects
(:mod:`neckstrength.gap.effects`), its fits or its window (a test checks this), so a case is not made by the
code that later explains it.

=========================  =============================================================================
truth                      how the forces are made (one case: parameters drawn once; per test where said)
=========================  =============================================================================
none                       the fitted model's max force along each target wrench (noise-only control)
rich96                     96 elements at the model's joints, each with its own strength (group factor x
                           element factor exp(N(0, element_spread))): the finer truth, no effect injected
direction_error            per test a push direction drawn uniformly within a cone of ``cone`` deg around the
                           intended one (angle sqrt-uniform, azimuth uniform); the force is the model's true
                           maximum along the wrench of a force in that direction at the test point
asymmetry                  left group strengths x exp(a/2), right x exp(-a/2)
origin_offset              every joint centre displaced by (dx, dy) in the sagittal plane
submaximal_effort          effort field e(n) = 1 - (1 - e_min) ((1 + n.v) / 2)^2 over the push directions n
                           (one lobe around a random direction v: pain, fear, unfamiliarity), force x e
posture_drift              per test the head drifts by ``drift`` deg from neutral in the direction of the
                           torque the test demands (sagittal, lateral, axial shares); the model in that posture
                           is interpolated linearly between neutral and the shipped posture tables
anthropometric_scaling     head size: test points radially from the head centre x (1 + h); neck length: joint
                           centres from the top joint x (1 + n); moment arms as in the model
=========================  =============================================================================

Measurement: ``repeats`` trials per test, log-normal scatter ``noise`` (drawn per case); the recorded force is
the largest trial (Appendix A keeps the largest), and the case's measured noise is the pooled within-test log SD
of the trials with its chi-square 95% interval, as a trial import writes it (what a lab that keeps repeats has).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np
import pandas as pd
from scipy.stats import chi2

from neckstrength.model.full import COORDINATES, FullModel
from neckstrength.model.geometry import PLANAR_INDEX, jacobian_transpose
from neckstrength.model.reduction import ReducedModel
from neckstrength.wrench import BasisCache, solve

#: truth -> the registry name of the candidate effect a correct diagnosis names ('none': nothing named).
#: A direction error drawn per test is random aiming scatter: the diagnosis names it ``direction_scatter`` (a
#: variance signature, :mod:`neckstrength.gap.scatter`), not ``direction_tolerance`` (the largest force inside the
#: window, which raises every test; until 2026-11-28 the target, never named: 0 of 11).
TARGET = {"none": "none", "rich96": "none", "direction_error": "direction_scatter", "asymmetry": "asymmetry",
          "origin_offset": "origin_offset", "submaximal_effort": "submaximal_effort",
          "posture_drift": "posture_drift", "anthropometric_scaling": "anthropometric_scaling"}
CONTROLS = ("none", "rich96")
EFFECT_TRUTHS = tuple(t for t in TARGET if t not in CONTROLS)

#: posture table per (axis, sign of the joint angle) and its angle (deg), as data/model/postures/postures.csv
_POSTURE_OF = {("pitch", -1): ("flex20", 20.0), ("pitch", 1): ("ext20", 20.0), ("roll", -1): ("bendL15", 15.0),
               ("roll", 1): ("bendR15", 15.0), ("yaw", 1): ("rotL30", 30.0), ("yaw", -1): ("rotR30", 30.0)}


@dataclass(frozen=True)
class TruthSetup:
    """What the truths are made from: the full model, the fitted (reduced) model, the test directions (rows of
    the geometry direction table in data order), the head centre (m), whether the fit ties left and right, and
    the posture tables (name -> :class:`neckstrength.postures.PostureTable`; needed for ``posture_drift``)."""

    full: FullModel
    model: ReducedModel
    directions: pd.DataFrame
    head_centre: np.ndarray
    tie_sides: bool = False
    postures: Mapping[str, object] = field(default_factory=dict)

    @classmethod
    def of(cls, ctx) -> "TruthSetup":
        """The truths' set-up of a diagnosis context (:class:`neckstrength.gap.effects.GapContext`: its models,
        directions, head centre, side tying and posture tables)."""
        return cls(ctx.full, ctx.model, ctx.directions, ctx.head_centre, ctx.tie_sides, dict(ctx.postures or {}))


@dataclass(frozen=True)
class CaseSettings:
    """Design: ``replicates`` cases per truth in ``truths``, ``controls`` base-model and ``rich_controls``
    96-element controls. Ranges are drawn uniformly per case (signs at random where a parameter has two)."""

    truths: tuple[str, ...] = EFFECT_TRUTHS
    replicates: int = 12
    controls: int = 24
    rich_controls: int = 12
    noise: tuple[float, float] = (0.03, 0.06)
    repeats: int = 3
    strength_spread: float = 0.3
    element_spread: float = 0.3
    cone_deg: tuple[float, float] = (5.0, 15.0)
    log_lr_ratio: tuple[float, float] = (0.3, 0.7)
    offset_m: tuple[float, float] = (0.01, 0.02)
    effort_min: tuple[float, float] = (0.6, 0.8)
    drift_deg: tuple[float, float] = (8.0, 15.0)
    head_scale: tuple[float, float] = (0.05, 0.15)
    neck_scale: tuple[float, float] = (0.05, 0.15)
    min_force_ratio: float = 0.2
    max_tries: int = 100


@dataclass
class TruthCase:
    """One generated participant (generator side: the truth and its parameters are withheld from the diagnosis)."""

    name: str
    truth: str
    params: dict
    strengths: np.ndarray
    forces_clean: np.ndarray
    trials: np.ndarray
    noise: float
    noise_sd: float = np.nan          # measured: pooled within-test log SD of the trials
    noise_df: int = 0
    noise_low: float = np.nan
    noise_high: float = np.nan

    @property
    def target(self) -> str:
        return TARGET[self.truth]

    @property
    def forces(self) -> np.ndarray:
        """The recorded force per test: the largest trial."""
        return self.trials.max(axis=1)

    def repeats_row(self) -> tuple:
        """``(name, log SD, df, ci_low, ci_high)`` as the diagnosis takes a trial import's noise table."""
        return (self.name, self.noise_sd, self.noise_df, self.noise_low, self.noise_high)


def pooled_log_sd(trials: np.ndarray, level: float = 0.95) -> tuple[float, int, float, float]:
    """Pooled within-test SD of the log trials (K x R), its degrees of freedom and chi-square ``level`` interval."""
    lt = np.log(np.asarray(trials, float))
    df = lt.shape[0] * (lt.shape[1] - 1)
    if df < 1:
        raise ValueError("the measured noise needs at least 2 trials per test")
    s = float(np.sqrt(((lt - lt.mean(axis=1, keepdims=True)) ** 2).sum() / df))
    a = (1 - level) / 2
    return s, int(df), s * float(np.sqrt(df / chi2.ppf(1 - a, df))), s * float(np.sqrt(df / chi2.ppf(a, df)))


class TruthForces:
    """Max force (N) of the individual along each test under a (possibly changed) model and geometry: the truths' own
    max-wrench evaluation (:func:`make_forces`, :func:`draw_params`), with a basis cache, so one instance per
    :class:`TruthSetup` serves many cases."""

    def __init__(self, setup: TruthSetup):
        self.s = setup
        m = setup.model
        self.rows = [COORDINATES.index(c) for c in m.coordinates]
        d = setup.directions
        self.P = d[["px", "py", "pz"]].to_numpy(float)
        N = d[["nx", "ny", "nz"]].to_numpy(float)
        self.N = N / np.linalg.norm(N, axis=1, keepdims=True)
        self.cache = BasisCache()

    def _jt(self, centres: np.ndarray, axes: np.ndarray) -> np.ndarray:
        JT = jacobian_transpose(centres, axes)
        return JT[:, PLANAR_INDEX] if self.s.model.planar else JT

    def along(self, model: ReducedModel, f: np.ndarray, P: np.ndarray, N: np.ndarray,
              lb=None, ub=None) -> np.ndarray:
        """Largest force magnitude (N) of a force along unit ``N[k]`` at point ``P[k]``, for each test k."""
        W = np.hstack([np.cross(P, N), N])
        s = np.linalg.norm(W, axis=1)
        U = model.task_direction(W / s[:, None])
        w, _, _ = solve(model, np.asarray(f, float)[None, :], U, lb, ub, return_alpha=False, cache=self.cache)
        return w[0] / s

    def base(self, f: np.ndarray) -> np.ndarray:
        return self.along(self.s.model, f, self.P, self.N)

    def with_centres(self, f: np.ndarray, centres: np.ndarray, P: np.ndarray | None = None) -> np.ndarray:
        full = self.s.full
        m = replace(self.s.model, JT=self._jt(centres, full.axes[self.rows]))
        return self.along(m, f, self.P if P is None else P, self.N)


def _rot(v: np.ndarray, axis: np.ndarray, ang: float) -> np.ndarray:
    """Rodrigues rotation of ``v`` about unit ``axis`` by ``ang`` (rad)."""
    return v * np.cos(ang) + np.cross(axis, v) * np.sin(ang) + axis * np.dot(axis, v) * (1 - np.cos(ang))


def _perp(n: np.ndarray) -> np.ndarray:
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e = a - np.dot(a, n) * n
    return e / np.linalg.norm(e)


def _interp_posture(tables: Mapping[str, object], weights: dict[str, float]):
    """A posture table interpolated linearly from neutral towards the named postures by ``weights``."""
    from neckstrength.postures.tables import PostureTable

    t0 = tables["neutral"]
    out = {k: np.array(getattr(t0, k), float) for k in ("moment_arms", "centres", "axes", "JT", "factor",
                                                          "factor_rel")}
    for p, w in weights.items():
        tp = tables[p]
        for k in out:
            out[k] = out[k] + w * (np.asarray(getattr(tp, k), float) - np.asarray(getattr(t0, k), float))
    out["axes"] = out["axes"] / np.linalg.norm(out["axes"], axis=1, keepdims=True)
    return PostureTable("drift", out["moment_arms"], out["centres"], out["axes"], out["JT"], out["factor"],
                        out["factor_rel"], tuple(t0.names))


def drift_weights(JT_row_axes: Sequence[str], tau: np.ndarray, drift_deg: float) -> dict[str, float]:
    """Posture weights of a drift of ``drift_deg`` along the demanded torque ``tau`` (one value per model
    coordinate, named by ``JT_row_axes``: pitch, roll, yaw), summed per axis over the joints."""
    per = {a: float(sum(t for ax, t in zip(JT_row_axes, tau) if ax == a)) for a in ("pitch", "roll", "yaw")}
    norm = float(np.sqrt(sum(v * v for v in per.values())))
    if norm < 1e-12:
        return {}
    w: dict[str, float] = {}
    for a, v in per.items():
        ang = drift_deg * v / norm
        if abs(ang) < 1e-9:
            continue
        p, full_angle = _POSTURE_OF[(a, 1 if ang > 0 else -1)]
        w[p] = abs(ang) / full_angle
    return w


def make_forces(setup: TruthSetup, truth: str, f: np.ndarray, params: dict, fc: TruthForces | None = None,
                element_f: np.ndarray | None = None) -> np.ndarray:
    """Noiseless max force (N) per test of the individual with group strengths ``f`` under ``truth``."""
    fc = fc or TruthForces(setup)
    model, full = setup.model, setup.full
    if truth == "none":
        return fc.base(f)
    if truth == "rich96":
        m96 = replace(model, name=model.name + "@96", muscle_names=tuple(full.names),
                      strengths=np.asarray(element_f, float), moment_arms=full.moment_arms[fc.rows],
                      S=np.eye(full.m))
        return fc.along(m96, element_f, fc.P, fc.N)
    if truth == "direction_error":
        return fc.along(model, f, fc.P, np.asarray(params["push_direction"], float))
    if truth == "asymmetry":
        a = float(params["log_LR_ratio"])
        side = np.array([n[-2:] for n in model.muscle_names])
        g = np.where(side == "-L", np.exp(a / 2), np.where(side == "-R", np.exp(-a / 2), 1.0))
        return fc.base(f * g)
    if truth == "origin_offset":
        c = full.centres[fc.rows] + np.array([params["dx_m"], params["dy_m"], 0.0])
        return fc.with_centres(f, c)
    if truth == "submaximal_effort":
        return fc.base(f) * effort_field(fc.N, np.asarray(params["v"], float), float(params["effort_min"]))
    if truth == "anthropometric_scaling":
        c = full.centres[fc.rows]
        top = c[[k for k, n in enumerate(model.coordinates) if n.startswith("C0-C1")][0]]
        c2 = top + (1.0 + float(params["neck_scale"])) * (c - top)
        hc = np.asarray(setup.head_centre, float)
        P2 = hc + (1.0 + float(params["head_scale"])) * (fc.P - hc)
        return fc.with_centres(f, c2, P2)
    if truth == "posture_drift":
        from neckstrength.postures.model import posture_full_model, reduce_in_posture

        if not setup.postures or "neutral" not in setup.postures:
            raise ValueError("posture_drift truths need the posture tables (data/model/postures)")
        U = model.task_direction(np.hstack([np.cross(fc.P, fc.N), fc.N]))
        U = U / np.linalg.norm(U, axis=1, keepdims=True)
        axes = [c.rsplit("_", 1)[1] for c in model.coordinates]
        out = np.zeros(len(U))
        rho_den = model.strengths
        for k in range(len(U)):
            w = drift_weights(axes, model.JT @ U[k], float(params["drift_deg"]))
            tab = _interp_posture(setup.postures, w)
            mq = reduce_in_posture(posture_full_model(full, tab), model, tab, "drift")
            rho = np.where(rho_den > 0, mq.strengths / np.where(rho_den > 0, rho_den, 1.0), 0.0)
            out[k] = fc.along(mq, f * rho, fc.P[k:k + 1], fc.N[k:k + 1])[0]
        return out
    raise ValueError(f"unknown truth {truth!r}; one of {', '.join(TARGET)}")


def effort_field(N: np.ndarray, v: np.ndarray, effort_min: float) -> np.ndarray:
    """Effort per push direction: 1 - (1 - e_min) ((1 + n.v) / 2)^2, in [e_min, 1]."""
    return 1.0 - (1.0 - effort_min) * ((1.0 + N @ v) / 2.0) ** 2


def _signed(rng: np.random.Generator, lo_hi: tuple[float, float]) -> float:
    return float(rng.uniform(*lo_hi)) * (1.0 if rng.random() < 0.5 else -1.0)


def _unit(rng: np.random.Generator, planar: bool) -> np.ndarray:
    v = rng.normal(size=3)
    if planar:
        v[2] = 0.0
    return v / np.linalg.norm(v)


def draw_params(setup: TruthSetup, truth: str, s: CaseSettings, rng: np.random.Generator, fc: TruthForces) -> dict:
    """The case's effect parameters (JSON-friendly, arrays as lists)."""
    planar = setup.model.planar
    if truth in CONTROLS:
        return {}
    if truth == "direction_error":
        cone = float(rng.uniform(*s.cone_deg))
        dirs, angs = [], []
        for n in fc.N:
            ang = np.radians(cone) * np.sqrt(rng.random())
            if planar:
                axis, ang = np.array([0.0, 0.0, 1.0]), ang * (1 if rng.random() < 0.5 else -1)
            else:
                e1 = _perp(n)
                axis = _rot(e1, n, rng.uniform(0, 2 * np.pi))
            dirs.append(_rot(n, axis, ang))
            angs.append(float(np.degrees(abs(ang))))
        return {"cone_deg": cone, "push_direction": np.array(dirs).tolist(), "angle_deg": angs}
    if truth == "asymmetry":
        return {"log_LR_ratio": _signed(rng, s.log_lr_ratio)}
    if truth == "origin_offset":
        r, t = float(rng.uniform(*s.offset_m)), float(rng.uniform(0, 2 * np.pi))
        return {"dx_m": r * np.cos(t), "dy_m": r * np.sin(t)}
    if truth == "submaximal_effort":
        return {"effort_min": float(rng.uniform(*s.effort_min)), "v": _unit(rng, planar).tolist()}
    if truth == "posture_drift":
        return {"drift_deg": float(rng.uniform(*s.drift_deg))}
    if truth == "anthropometric_scaling":
        return {"head_scale": _signed(rng, s.head_scale), "neck_scale": _signed(rng, s.neck_scale)}
    raise ValueError(f"unknown truth {truth!r}; one of {', '.join(TARGET)}")


def describe(truth: str, params: dict) -> str:
    """Short description of a case's truth for the tables."""
    if truth == "direction_error":
        a = np.asarray(params["angle_deg"])
        return f"cone {params['cone_deg']:.1f} deg (per test {a.min():.1f}-{a.max():.1f}, median {np.median(a):.1f})"
    if truth == "submaximal_effort":
        return f"effort {params['effort_min']:.2f}-1"
    return ", ".join(f"{k}={v:.3g}" for k, v in params.items() if isinstance(v, (int, float))) or "-"


def stratified_plan(s: CaseSettings) -> list[str]:
    """Truth of each case in an order whose every prefix samples each group in proportion (controls first in
    each round), so that a run stopped early leaves a balanced subset."""
    groups = [("none", s.controls), ("rich96", s.rich_controls)] + [(t, s.replicates) for t in s.truths]
    keyed = [((r + 0.5) / n, gi, t) for gi, (t, n) in enumerate(groups) for r in range(n)]
    return [t for *_, t in sorted(keyed)]


def generate_truth_cases(setup: TruthSetup, s: CaseSettings, rng: np.random.Generator,
                         limit: int | None = None) -> list[TruthCase]:
    """The design's cases in stratified order (:func:`stratified_plan`), named ``u001``, ``u002``, ...;
    ``limit``: only the first cases (the draws of the first ``limit`` cases do not depend on it)."""
    unknown = [t for t in s.truths if t not in EFFECT_TRUTHS]
    if unknown:
        raise ValueError(f"unknown truths {unknown}; one of {', '.join(EFFECT_TRUTHS)}")
    model = setup.model
    fc = TruthForces(setup)
    # free strength factors: one per group, or per base group where the fit ties the sides
    base = [n[:-2] if (setup.tie_sides and n.endswith(("-R", "-L"))) else n for n in model.muscle_names]
    free = list(dict.fromkeys(base))
    pidx = np.array([free.index(b) for b in base])
    grp = np.argmax(setup.model.S, axis=1)
    plan = stratified_plan(s)[:limit]
    cases = []
    for k, truth in enumerate(plan):
        for _ in range(s.max_tries):
            f = model.strengths * np.exp(rng.normal(0.0, s.strength_spread, len(free)))[pidx]
            ef = None
            if truth == "rich96":
                ef = setup.full.strengths * (f / np.where(model.strengths > 0, model.strengths, 1.0))[grp] \
                     * np.exp(rng.normal(0.0, s.element_spread, setup.full.m))
            params = draw_params(setup, truth, s, rng, fc)
            clean = make_forces(setup, truth, f, params, fc, ef)
            typical = np.median(fc.base(f))
            if np.all(np.isfinite(clean)) and clean.min() >= s.min_force_ratio * typical:
                break
        else:
            raise RuntimeError(f"could not draw a producible {truth} case in {s.max_tries} tries")
        nz = float(rng.uniform(*s.noise))
        trials = clean[:, None] * np.exp(rng.normal(0.0, nz, (len(clean), s.repeats)))
        sd, df, lo, hi = pooled_log_sd(trials)
        cases.append(TruthCase(f"u{k + 1:03d}", truth, params, f, clean, trials, nz, sd, df, lo, hi))
    return cases
