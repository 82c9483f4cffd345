"""What to measure to tell an effect from noise (issue 32, item 4): power per test protocol.

For every candidate effect and size (share of the way from neutral to its far bound, as the calibration's power),
the power of four protocols at the data set's noise level ``sigma``:

- ``directions``: the data set's own tests (one maximum per direction, log-normal noise ``sigma``);
- ``repeats``: the same directions with ``repeats`` trials each, analysed as their mean log force (noise
  ``sigma / sqrt(repeats)``; a modelling choice: the maximum of the trials, the thesis's rule, scatters more);
- ``postures``: the same directions again in the shipped sagittal postures (flex20, ext20; the pads move with
  the head, so each test's skull-frame wrench is unchanged; docs/postures.md), noise ``sigma`` per test;
- ``emg``: the directions plus one surface-EMG reading per test, the mean normalised activation of the
  EMG-recorded groups (the form of Table A.3), with absolute SD ``emg_sd`` (config; the thesis's participant EMG
  band 0.2 read as about 2 SD: a modelling choice);
- ``all``: repeats, postures and EMG together.

**Power (linearised; a heuristic).** Observations ``y`` (log forces, activations) of the base model at the data
set's fitted strengths ``phi`` and of the effect at size ``u``; their difference ``Delta`` in units of each
observation's SD, with the part that refitting the free strengths absorbs projected out (``J`` the base model's
Jacobian in ``phi``, forward differences): noncentrality ``lambda = |(I - P_J) Delta|^2`` (two-sided parameters:
the mean over both bounds' directions). ``power_oracle`` = ``P(chi2_d(lambda) > c)`` with ``d`` the effect's
parameters and ``c`` the ``1 - alpha / E`` quantile of ``chi2_d`` (``E`` effects: Bonferroni for choosing the
best): a likelihood-ratio test that knows the noise and the effect's form. The diagnosis's cross-validated maxT
decision needs more: ``power`` divides ``lambda`` by an *efficiency* ``kappa`` fitted so that the linearised
power of the present tests matches the calibration's simulated power of the same data set (:func:`fit_efficiency`;
not fitted without simulated power or where it is 0 everywhere: then the oracle's power is used, and said so). So the protocols are compared on the scale of the diagnosis's own
decision, but only through one fitted factor per data set: the figures are heuristic, not calibrated
probabilities (docs/gap_diagnosis.md compares them with simulation).

**Advice.** Per effect: if the calibration's simulated power reaches the target at some size, the present tests
suffice; else the protocol whose power reaches the target at the smallest size (cheapest first at equal size:
repeats, EMG, postures, all): "to tell X from noise, add Y"; none: "no listed protocol tells X from noise at this
noise". Without simulated power the present tests' linearised power takes its place.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.gap.effects import POSTURE_ANGLES, Effect, GapContext, base_instance, compose

#: Protocols in the order of their cost at equal power (the advice prefers the earlier).
PROTOCOLS = ("directions", "repeats", "emg", "postures", "all")

PROTOCOL_TEXT = {"directions": "the present tests", "repeats": "{r} trials per direction (mean log force)",
                 "emg": "a surface-EMG reading per test (mean normalised activation of the recorded groups)",
                 "postures": "the tests again in {postures}", "all": "{r} trials per direction, the tests again in "
                 "{postures} and surface EMG"}


@dataclass(frozen=True)
class ProtocolSettings:
    """Config ``gap.protocols``: trials per direction of the ``repeats`` protocol, the postures of ``postures``,
    the SD of one surface-EMG reading, the effect sizes (share of the way to the far bound) at which the power is
    computed (None: the calibration's ``power_sizes``, so that its simulated power calibrates the efficiency), and
    the power that counts as telling the effect from noise (None in the diagnosis: the calibration's
    ``power_target``)."""

    repeats: int = 3
    postures: tuple[str, ...] = ("flex20", "ext20")
    emg_sd: float = 0.1
    sizes: tuple[float, ...] | None = None
    target: float | None = None


# ----------------------------------------------------------------------------- the model in another posture

def posture_context(ctx: GapContext, posture: str) -> tuple[GapContext, np.ndarray]:
    """``ctx`` with the full and reduced model of ``posture`` (same grouping, :mod:`neckstrength.postures.model`)
    and ``rho``: the posture's group strengths per neutral group strength (forces at neutral strengths ``F`` are
    those of the posture model at ``F * rho``)."""
    from neckstrength.postures.model import posture_full_model, reduce_in_posture

    tabs = dict(ctx.postures or {})
    if posture not in tabs or posture not in POSTURE_ANGLES:
        raise ValueError(f"no sagittal posture table {posture!r} (have {sorted(tabs)})")
    full_q = posture_full_model(ctx.full, tabs[posture], ctx.force_length)
    model_q = reduce_in_posture(full_q, ctx.model, tabs[posture], posture)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(ctx.model.strengths > 0, model_q.strengths / np.where(ctx.model.strengths > 0,
                                                                             ctx.model.strengths, 1.0), 0.0)
    return replace(ctx, full=full_q, model=model_q, posture_angle=POSTURE_ANGLES[posture]), rho


def _instance(ctx: GapContext, effects: Sequence[Effect], thetas: Sequence[np.ndarray]):
    if not effects:
        return base_instance(ctx)
    return compose(ctx, [type(e)(ctx, **e.s) for e in effects], thetas)


def emg_mean_activation(ctx: GapContext, sim, F: np.ndarray) -> np.ndarray:
    """(N x K) mean activation of the EMG-recorded groups at the predicted maxima (as Table A.3 reports one value
    per test): element forces from the LP's column activations, per group divided by the group's element
    strengths, then the mean over the groups; nan where the model has no EMG groups."""
    from neckstrength.gap.fit import Simulator  # noqa: F401  (sim is one)

    inst = sim.inst
    full, model = ctx.full, ctx.model
    F = np.atleast_2d(F)
    _, _, _, alpha = sim.run(F, return_alpha=True)
    out = np.full((len(F), sim.K), np.nan)
    groups = []
    for b in ctx.emg_groups:
        members = np.zeros(full.m, bool)
        for g in range(model.m):
            if ctx.group_base(g) == b:
                members |= model.S[:, g] > 0
        if members.any():
            groups.append(members)
    if not groups:
        return out
    for n in range(len(F)):
        fcol = inst.strengths(F[n][None])[0]
        xel = np.nan_to_num(alpha[n]) * fcol[None, :] @ inst.elem.T             # element forces (K x 96)
        scale = np.zeros(full.m)
        for g in range(model.m):
            scale[model.S[:, g] > 0] = F[n, g] / model.strengths[g] if model.strengths[g] > 0 else 0.0
        fel = full.strengths * scale
        vals = [xel[:, mem].sum(axis=1) / fel[mem].sum() for mem in groups if fel[mem].sum() > 0]
        out[n] = np.mean(vals, axis=0)
    return out


# ----------------------------------------------------------------------------- observations per protocol

class _Observer:
    """All observations any protocol uses, for strength vectors: log forces of the directions (block
    'directions'), of the directions in each posture (block = posture name) and the EMG means (block 'emg')."""

    def __init__(self, ctx: GapContext, s: ProtocolSettings, postures: bool, emg: bool):
        self.ctx, self.s = ctx, s
        self.postures = list(s.postures) if postures else []
        self.emg = emg
        self.pctx = {q: posture_context(ctx, q) for q in self.postures}
        self.blocks = ["directions", *self.postures] + (["emg"] if emg else [])

    def observe(self, effects: Sequence[Effect], thetas: Sequence[np.ndarray], F: np.ndarray) -> np.ndarray:
        """(N x blocks x K) observations of the model with ``effects`` at ``thetas`` for model strengths ``F``."""
        from neckstrength.gap.fit import Simulator

        F = np.atleast_2d(F)
        sim = Simulator(self.ctx, _instance(self.ctx, effects, thetas))
        parts = [np.log(np.maximum(sim.forces(F), 1e-9))]
        for q in self.postures:
            cq, rho = self.pctx[q]
            sq = Simulator(cq, _instance(cq, effects, thetas))
            parts.append(np.log(np.maximum(sq.forces(F * rho[None]), 1e-9)))
        if self.emg:
            parts.append(np.nan_to_num(emg_mean_activation(self.ctx, sim, F)))
        return np.stack(parts, axis=1)

    def select(self, protocol: str, sigma: float) -> tuple[list[int], np.ndarray]:
        """The blocks of ``protocol`` and the SD of each of their observations (block-major)."""
        r = self.s.repeats if protocol in ("repeats", "all") else 1
        sf = sigma / np.sqrt(r)
        blocks = ["directions"] + (self.postures if protocol in ("postures", "all") else []) + (
            ["emg"] if protocol in ("emg", "all") else [])
        K = self.ctx.K
        sd = np.concatenate([np.full(K, self.s.emg_sd if b == "emg" else sf) for b in blocks])
        return [self.blocks.index(b) for b in blocks], sd


def available_protocols(ctx: GapContext, s: ProtocolSettings, protocols: Sequence[str] = PROTOCOLS) -> list[str]:
    """The protocols of ``protocols`` that ``ctx`` supports (posture tables for the postures, EMG groups for EMG)."""
    unknown = [p for p in protocols if p not in PROTOCOLS]
    if unknown:
        raise ValueError(f"gap.protocols: unknown protocols {unknown} (one of {', '.join(PROTOCOLS)})")
    have_postures = len(s.postures) > 0 and all(q in (ctx.postures or {}) for q in s.postures)
    return [p for p in protocols if not ((p in ("postures", "all") and not have_postures)
                                         or (p in ("emg", "all") and not ctx.emg_groups))]


def protocol_power(ctx: GapContext, phi: np.ndarray, sigma: float, effects: Sequence[Effect],
                   s: ProtocolSettings = ProtocolSettings(), alpha: float = 0.05, n_effects: int | None = None,
                   protocols: Sequence[str] = PROTOCOLS, fd_step: float = 1e-3,
                   efficiency: float = 1.0) -> pd.DataFrame:
    """Linearised power (module docstring) of every protocol in ``protocols`` that the context supports, for each
    effect and size in ``s.sizes``, at the fitted log free strengths ``phi`` and noise ``sigma``. Columns: effect,
    protocol, size_share, theta, n_obs, noncentrality, power_oracle (the likelihood-ratio test's) and power (with
    the noncentrality divided by ``efficiency``, :func:`fit_efficiency`). ``n_effects``: the E of the Bonferroni
    level (default: ``len(effects)``)."""
    from neckstrength.gap.calibrate import size_theta
    from neckstrength.gap.fit import Simulator

    prots = available_protocols(ctx, s, protocols)
    sim0 = Simulator(ctx, base_instance(ctx))
    phi = np.asarray(phi, float)
    F0 = sim0.muscles(phi[None])
    E = max(1, int(n_effects if n_effects is not None else len(effects)))
    ob = _Observer(ctx, s, any(p in ("postures", "all") for p in prots), any(p in ("emg", "all") for p in prots))
    y0 = ob.observe([], [], F0)[0]
    p = len(phi)
    Yh = ob.observe([], [], sim0.muscles(phi[None] + fd_step * np.eye(p)))
    G = (Yh - y0[None]) / fd_step                                                 # (p x blocks x K)
    sizes = tuple(s.sizes) if s.sizes else (0.5, 1.0)
    obs, unproducible = {}, {}
    nf = len(ob.blocks) - (1 if ob.emg else 0)                 # the blocks of log forces
    floor = np.log(0.05) + np.log(np.median(np.exp(y0[:nf]), axis=1))
    for e in effects:
        two = any(q.lo < q.neutral < q.hi for q in e.params())
        for u in sizes:
            ys = [ob.observe([e], [size_theta(e, u, sign)], F0)[0] for sign in ((1, -1) if two else (1,))]
            # as the calibration's power sets: a truth that cannot produce a test (force below 5% of the median)
            # is not simulated; here the size is marked unproducible
            unproducible[e.name, u] = any(bool(np.any(y[:nf] < floor[:, None])) for y in ys)
            obs[e.name, u] = [y - y0 for y in ys]
    rows = []
    for prot in prots:
        bl, sd = ob.select(prot, sigma)
        J = G[:, bl].reshape(p, -1).T / sd[:, None]
        Uj, Sj, _ = np.linalg.svd(J, full_matrices=False)       # the span of the strengths' effects
        Q = Uj[:, Sj > 1e-9 * max(Sj.max(initial=0.0), 1e-300)]
        for e in effects:
            d = e.n_params
            for u in sizes:
                row = {"effect": e.name, "protocol": prot, "size_share": float(u),
                       "theta": e.describe(size_theta(e, u, 1)), "n_obs": len(sd), "unproducible": unproducible[e.name, u]}
                if row["unproducible"]:
                    rows.append({**row, "noncentrality": np.nan, "power_oracle": np.nan, "power": np.nan})
                    continue
                lam = []
                for dlt in obs[e.name, u]:
                    x = dlt[bl].ravel() / sd
                    r = x - Q @ (Q.T @ x)
                    lam.append(float(r @ r))
                lm = float(np.mean(lam))
                rows.append({**row, "noncentrality": lm, "power_oracle": _power(lm, d, alpha / E, 1.0),
                             "power": _power(lm, d, alpha / E, efficiency)})
    return pd.DataFrame(rows, columns=POWER_COLUMNS)


POWER_COLUMNS = ["effect", "protocol", "size_share", "theta", "n_obs", "unproducible", "noncentrality", "power_oracle",
                 "power"]


def _power(lam: float, d: int, level: float, efficiency: float) -> float:
    """``P(chi2_d(lam / efficiency) > chi2_d quantile 1 - level)``."""
    from scipy.stats import chi2, ncx2

    if not np.isfinite(lam):
        return np.nan
    crit = chi2.ppf(1 - level, d)
    return float(ncx2.sf(crit, d, lam / efficiency)) if lam > 1e-12 else float(level)


def with_efficiency(power: pd.DataFrame, efficiency: float, alpha: float, n_effects: int,
                    n_params: dict[str, int]) -> pd.DataFrame:
    """``power`` (:func:`protocol_power`) with its ``power`` column recomputed for ``efficiency``."""
    E = max(1, int(n_effects))
    out = power.copy()
    k = efficiency if np.isfinite(efficiency) else 1.0
    out["power"] = [_power(r.noncentrality, n_params[r.effect], alpha / E, k) for r in out.itertuples()]
    return out


def fit_efficiency(power: pd.DataFrame, simulated: pd.DataFrame, alpha: float, n_effects: int,
                   n_params: dict[str, int]) -> float:
    """The factor by which the diagnosis's decision needs more noncentrality than the likelihood-ratio test: the
    value on a log grid (1 to 10^4) that best matches the linearised power of the present tests to the
    calibration's simulated power (its ``power`` table: effect, size_share, replicates, power), weighted by the
    replicates; nan when there is no simulated power or it is 0 everywhere (then any large factor fits: e.g. when
    the p-value's resolution cannot reach alpha, nothing is ever named)."""
    if simulated is None or not len(simulated):
        return np.nan
    d = power[(power["protocol"] == "directions") & power["noncentrality"].notna()].set_index(
        ["effect", "size_share"])["noncentrality"]
    pairs = [(float(d[(r.effect, float(r.size_share))]), n_params[r.effect], float(r.power), int(r.replicates))
             for r in simulated.itertuples() if (r.effect, float(r.size_share)) in d.index and r.replicates > 0
             and np.isfinite(r.power)]
    if not pairs or not any(pw > 0 for _, _, pw, _ in pairs):
        return np.nan
    grid = np.logspace(0, 4, 81)
    E = max(1, int(n_effects))
    err = [sum(n * (_power(lam, k, alpha / E, g) - pw) ** 2 for lam, k, pw, n in pairs) for g in grid]
    return float(grid[int(np.argmin(err))])


def protocol_text(protocol: str, s: ProtocolSettings) -> str:
    return PROTOCOL_TEXT[protocol].format(r=s.repeats, postures=" and ".join(s.postures))


def advice(power: pd.DataFrame, simulated: pd.DataFrame | None, s: ProtocolSettings, sigma: float,
           effects: Sequence[str], oracle: bool = False, simulated_table: pd.DataFrame | None = None) -> list[dict]:
    """One line per effect (module docstring, "Advice"): ``{'effect', 'protocol', 'size_share', 'power',
    'basis', 'line'}``. ``power``: :func:`protocol_power`; ``simulated``: the calibration's power summary
    (:func:`neckstrength.gap.calibrate.power_summary`, its ``min_detectable_share``) or None; ``oracle``: the
    power is the likelihood-ratio test's (no efficiency fitted), and the lines say so; ``simulated_table``: the
    calibration's power table (effect, size_share, power): where the present tests' linearised power exceeds their
    simulated power by more than 0.25 at some size, the line says that the heuristic overstates this effect."""
    tag = "oracle linearised power, no efficiency fitted" if oracle else "linearised power"
    if s.target is None:
        s = replace(s, target=0.8)
    out = []
    sim = {} if simulated is None or not len(simulated) else dict(
        zip(simulated["effect"], simulated["min_detectable_share"]))
    order = {p: i for i, p in enumerate(PROTOCOLS)}
    for name in effects:
        u_sim = sim.get(name, np.nan)
        if np.isfinite(u_sim):
            out.append({"effect": name, "protocol": "directions", "size_share": float(u_sim), "power": np.nan,
                        "basis": "simulated", "line": f"`{name}`: the present tests tell it from noise from "
                        f"{u_sim:g} of its range (simulated power >= {s.target:g})"})
            continue
        mine = power[power["effect"] == name]
        if len(mine) and "unproducible" in mine and mine["unproducible"].astype(bool).all():
            out.append({"effect": name, "protocol": "-", "size_share": np.nan, "power": np.nan, "basis": "-",
                        "line": f"`{name}`: at every simulated size it leaves some test unproducible at this data "
                        "set's fitted strengths, so no protocol's power is computed (the calibration skips such "
                        "truths too)"})
            continue
        g = power[(power["effect"] == name) & (power["power"] >= s.target)]
        if sim:
            g = g[g["protocol"] != "directions"]
        if len(g):
            g = g.assign(_o=g["protocol"].map(order)).sort_values(["size_share", "_o"])
            r = g.iloc[0]
            what = ("the present tests suffice" if r["protocol"] == "directions"
                    else f"add {protocol_text(r['protocol'], s)}")
            out.append({"effect": name, "protocol": r["protocol"], "size_share": float(r["size_share"]),
                        "power": float(r["power"]), "basis": "linearised",
                        "line": f"to tell `{name}` from noise, {what} (from {r['size_share']:g} of its range, "
                        f"{r['theta']}; {tag} {r['power']:.2f}, heuristic)" + _overstates(power, simulated_table,
                                                                                           name)})
        else:
            out.append({"effect": name, "protocol": "-", "size_share": np.nan, "power": np.nan, "basis": "-",
                        "line": f"no listed protocol tells `{name}` from noise at this noise (log SD {sigma:.3f}; "
                        f"{tag} < {s.target:g} at every size up to its bound)"})
    return out


def _overstates(power: pd.DataFrame, simulated_table: pd.DataFrame | None, name: str) -> str:
    """A caveat when the present tests' linearised power of effect ``name`` exceeds their simulated power by more
    than 0.25 at some size (the efficiency is one factor for all effects; a flexible effect can need more)."""
    if simulated_table is None or not len(simulated_table):
        return ""
    lin = power[(power["effect"] == name) & (power["protocol"] == "directions")].set_index("size_share")["power"]
    sim = simulated_table[simulated_table["effect"] == name].set_index("size_share")["power"]
    both = [(u, float(lin[u]), float(sim[u])) for u in lin.index if u in sim.index and np.isfinite(lin[u])
            and np.isfinite(sim[u])]
    worst = max(both, key=lambda t: t[1] - t[2], default=None)
    if worst is None or worst[1] - worst[2] <= 0.25:
        return ""
    return (f"; caution: for the present tests the heuristic gives {worst[1]:.2f} at {worst[0]:g} of the range where "
            f"the simulation gives {worst[2]:.2f}, so it overstates this effect's power")
