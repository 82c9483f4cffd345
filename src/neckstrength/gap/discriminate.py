"""Which further measurements would tell the leading explanations apart (issue 17, item 5).

When the diagnosis cannot separate its best candidates (bootstrap P(best) of the best below
``p_best_below``), this module takes the top ``candidates`` of the ranking (their effect parameters as
fitted on all directions), refits their free strengths on the measured directions and predicts the force of
every possible additional measurement in a *pool*: each of the measured test directions again (a repeat:
it halves nothing in the model, but adds an independent noisy observation) and further test points on the
reconstructed head surface (:func:`surface_points`, the cranial ellipsoid of ``docs/geometry.md``).

**Predictive distribution.** Under candidate ``a`` the log force of a set of new measurements is normal with
mean ``log F_a`` (the candidate's all-direction fit) and covariance ``sigma^2 I + G_a Cov_a G_a^T``:
log-normal measurement noise ``sigma`` (the calibration's noise level, or the smaller RMS log held-out
residual of the base model and the chosen candidate, or a number from repeat trials) plus the candidate's parameter uncertainty (Laplace:
``Cov_a = (J'J / sigma^2 + Prior)^-1`` over its log free strengths and effect parameters, ``J`` the Jacobian
of the log forces of the measured directions - exact for the strengths, forward differences for the
effect parameters - ``Prior`` the population spread of log strengths and a uniform-variance prior on each
effect parameter over its range; ``G_a`` the same Jacobian on the pool). Parameter uncertainty is shared
by repeated measurements, so repeats have diminishing returns.

**Expected discrimination.** For a pair ``(a, b)`` the expected log Bayes factor of the new measurements in
favour of ``a`` when ``a`` is true is the Kullback-Leibler divergence ``KL(N_a || N_b)``
(:func:`expected_log_bf`); it is 0 when both predict the same and grows with the squared difference of
their predictions in units of the predictive SD. A pair's value is the smaller of its two directions (the
measurements should favour whichever candidate is true); the proposal maximises, greedily one measurement
at a time (repeats of a pool entry allowed), the **sum over pairs of 1 - exp(-L)** with ``L`` the pair's
expected log BF (config ``objective: saturating``: a pair already told apart, or one that no measurement can
separate, adds little either way, so neither dominates the choice; ``exp(-L)`` is a Chernoff-type proxy of
the chance of preferring the wrong candidate of the pair, a heuristic, not calibrated). ``min`` (the worst
pair) and ``sum`` (plain sum) are the alternatives; ties are broken by the plain sum. Pairs whose
candidates predict the same force everywhere in the pool (e.g. an effect fitted at its neutral value vs
``none``) cannot be told apart by any force measurement; they are reported and left out of the objective.

Deterministic (no random draws). Imports the fit and effect primitives only, never the diagnosis engine.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.gap.effects import EFFECTS, GapContext, base_instance, compose, parse_label
from neckstrength.gap.fit import FitSettings, Simulator, fit_strengths, start_point
from neckstrength.gap.forked import fork_map
from neckstrength.model.geometry import HeadEllipsoid, assign_planes, direction_table
from neckstrength.postures.model import pair_label


@dataclass(frozen=True)
class DiscriminateSettings:
    """Config ``gap.discriminate`` (docs/gap_diagnosis.md, "Which tests would tell them apart").

    ``p_best_below``: propose only when the best candidate's bootstrap P(best) is below this;
    ``candidates``: how many of the top-ranked candidates are compared (all pairs among them);
    ``measurements``: how many additional measurements are proposed (greedy); ``objective``: 'saturating',
    'min' or 'sum' over the pairs' expected log Bayes factors (:data:`OBJECTIVES`); ``noise``: 'auto'
    (the calibration's noise level, else the smaller RMS log held-out residual of the base model and the
    chosen candidate) or a log-normal SD (e.g. from repeat trials);
    ``parameter_uncertainty``: add the candidates' Laplace parameter uncertainty to the predictive;
    ``strength_spread``: prior SD of log strengths for it; ``repeats`` / ``surface``: which measurements
    make up the pool; ``azimuth_step_deg``, ``elevation_deg``: the surface grid; points with |azimuth| <=
    ``face_max_abs_azimuth_deg`` and elevation <= ``face_max_elevation_deg`` are on the face, where the
    cranial ellipsoid does not apply, and are left out; ``postures``: the measured directions again in these
    postures (where the context has their tables); ``fit``: the refit of each candidate's strengths."""

    p_best_below: float = 0.7
    candidates: int = 3
    measurements: int = 3
    objective: str = "saturating"
    noise: str | float = "auto"
    parameter_uncertainty: bool = True
    strength_spread: float = 0.3
    repeats: bool = True
    surface: bool = True
    azimuth_step_deg: float = 30.0
    elevation_deg: tuple[float, ...] = (-30.0, 0.0, 30.0, 60.0)
    postures: tuple[str, ...] = ("flex20", "ext20")
    face_max_abs_azimuth_deg: float = 30.0
    face_max_elevation_deg: float = 0.0
    fit: FitSettings = field(default_factory=FitSettings)


# ----------------------------------------------------------------------------- the pool of measurements

def surface_points(head: HeadEllipsoid, s: DiscriminateSettings = DiscriminateSettings()) -> pd.DataFrame:
    """Test points on the cranial ellipsoid (a grid of azimuth x elevation; force along the outward normal,
    as for the reconstructed test points), without the face region. Names ``az+030_el+30``."""
    rows = []
    step = float(s.azimuth_step_deg)
    azs = np.arange(-180.0, 180.0 - 1e-9, step)
    for el in s.elevation_deg:
        for az in azs:
            if abs(az) <= s.face_max_abs_azimuth_deg + 1e-9 and el <= s.face_max_elevation_deg + 1e-9:
                continue
            p, n = head.point(float(az), float(el))
            if abs(p[2]) < 1e-12:
                p[2], n[2] = 0.0, 0.0          # exactly sagittal at azimuth 0 / 180
            rows.append({"name": f"az{az:+04.0f}_el{el:+03.0f}", "px": p[0], "py": p[1], "pz": p[2],
                         "nx": n[0], "ny": n[1], "nz": n[2], "method": "ellipsoid"})
    return pd.DataFrame(rows)


def measurement_pool(ctx: GapContext, head: HeadEllipsoid, s: DiscriminateSettings = DiscriminateSettings(),
                     plane_bands: dict | None = None) -> pd.DataFrame:
    """Possible additional measurements: the measured directions again (``kind`` 'repeat', named
    ``<name>#2``), the surface grid (``kind`` 'new') and the measured directions in each of ``s.postures`` whose
    table the context has (``kind`` 'posture', named ``<posture>:<name>``, column ``posture``; the pads move with
    the head, so the skull-frame wrench is the direction's); planar models keep sagittal points only. Columns as
    the geometry direction table (points, normals, unit wrenches, force scale, planes)."""
    parts = []
    cols = ["name", "px", "py", "pz", "nx", "ny", "nz"]
    if s.repeats:
        rep = ctx.directions[cols].copy()
        rep["source"] = ctx.directions["name"].to_numpy()
        rep["name"] = [f"{n}#2" for n in ctx.directions["name"]]
        rep["kind"] = "repeat"
        parts.append(rep)
    if s.surface:
        sp = surface_points(head, s)[cols]
        sp["source"] = sp["name"]
        sp["kind"] = "new"
        if ctx.model.planar:
            sp = sp[(sp["pz"].abs() < 1e-9) & (sp["nz"].abs() < 1e-9)]
        parts.append(sp)
    for q in s.postures if ctx.postures else ():
        if q not in ctx.postures:
            continue
        rows = ctx.directions[cols].copy()
        rows["source"] = ctx.directions["name"].to_numpy()
        rows["name"] = [pair_label(q, n) for n in ctx.directions["name"]]
        rows["kind"] = "posture"
        rows["posture"] = q
        parts.append(rows)
    if not parts:
        raise ValueError("gap.discriminate: the pool is empty (repeats, surface and postures all off)")
    pool = pd.concat(parts, ignore_index=True)
    pool["posture"] = pool["posture"].fillna("neutral") if "posture" in pool else "neutral"
    d = direction_table(pool, head)
    bands = dict(plane_bands or {})
    d = assign_planes(d, **{k: v for k, v in (("elevation_bands", bands.get("elevation_deg")),
                                              ("azimuth_bands", bands.get("azimuth_deg"))) if v is not None})
    return d.reset_index(drop=True)


def extended_context(ctx: GapContext, extra: pd.DataFrame) -> GapContext:
    """``ctx`` with the directions of ``extra`` appended (same columns as ``ctx.directions`` where present)."""
    keep = [c for c in ctx.directions.columns if c in extra.columns]
    d = pd.concat([ctx.directions, extra[keep]], ignore_index=True)
    return replace(ctx, directions=d)


# ----------------------------------------------------------------------------- predictive of a candidate

@dataclass
class CandidatePrediction:
    label: str
    theta: dict                   # effect -> parameters (fixed at the diagnosis's all-direction fit)
    phi: np.ndarray               # refitted log free strengths
    loss: float                   # training loss of the refit on the measured directions
    log_force: np.ndarray         # (K + pool,) predicted log force (N); -inf where unproducible
    cov: np.ndarray               # (K + pool, K + pool) parameter-uncertainty covariance of the log forces


def _instance(ctx: GapContext, label: str, theta: dict):
    names = parse_label(label)
    effs = [EFFECTS[n](ctx) for n in names]
    return compose(ctx, effs, [np.asarray(theta[n], float) for n in names]) if effs else base_instance(ctx)


def _fit_run(sim: Simulator, T: np.ndarray, W: np.ndarray, phi0: np.ndarray, prior: np.ndarray,
             fs: FitSettings):
    sim.refresh(sim.muscles(phi0))
    grad = sim.forces_grad_phi if fs.exact_gradient else None
    res = fit_strengths(sim.forces_phi, T, W, phi0, prior, fs, grad)
    for _ in range(4):                  # active set of candidate wrenches (direction_tolerance)
        if not sim.refresh(sim.muscles(res.phi)):
            break
        res = fit_strengths(sim.forces_phi, T, W, res.phi, prior, fs, grad)
    return res


def fit_candidate(ctx: GapContext, T: np.ndarray, label: str, theta: dict, fit: FitSettings | None = None,
                  starts: Sequence[np.ndarray] = ()) -> tuple[np.ndarray, float]:
    """Log free strengths and training loss of candidate ``label`` (effect parameters ``theta`` fixed) fitted to
    the forces ``T`` on all directions of ``ctx``; starts: the baseline scaled to the data (Eq. 5.3 idea) and
    ``starts``; the best is kept."""
    T = np.asarray(T, float)
    sim = Simulator(ctx, _instance(ctx, label, theta))
    base = Simulator(ctx, base_instance(ctx), sim.cache)
    W = np.ones((1, ctx.K))
    prior = start_point(base, T[None], W)
    P0 = np.array([prior[0]] + [np.asarray(p, float) for p in starts if p is not None])
    res = _fit_run(sim, np.repeat(T[None], len(P0), 0), np.repeat(W, len(P0), 0), P0,
                   np.repeat(prior, len(P0), 0), fit or FitSettings())
    b = int(np.argmin(res.loss))
    return res.phi[b], float(res.loss[b])


def predict_candidate(ctx: GapContext, T: np.ndarray, label: str, theta: dict, pool: pd.DataFrame,
                      sigma: float, s: DiscriminateSettings = DiscriminateSettings(),
                      starts: Sequence[np.ndarray] = ()) -> CandidatePrediction:
    """Refit the free strengths of candidate ``label`` (effect parameters ``theta`` fixed) on the measured
    forces ``T`` (K), then its predicted log forces and their parameter-uncertainty covariance on the K
    measured directions followed by the ``pool``."""
    T = np.asarray(T, float)
    K = ctx.K
    phi, loss = fit_candidate(ctx, T, label, theta, s.fit, starts)
    ext = extended_context(ctx, pool)
    names = parse_label(label)
    sim_e = Simulator(ext, _instance(ext, label, theta))
    sim_e.refresh(sim_e.muscles(phi[None]))
    F, dphi = sim_e.forces_grad_phi(phi[None])
    F, dphi = F[0], dphi[0]
    with np.errstate(divide="ignore"):
        logF = np.log(F)
    ok = F > 0
    n_ext = len(F)
    p = len(phi)
    if not s.parameter_uncertainty:
        if "posture" in pool and (pool["posture"] != "neutral").any():
            logF, _, _ = _posture_rows(ctx, pool, label, theta, phi, logF, None, ok, sim_e)
        return CandidatePrediction(label, theta, phi, loss, logF, np.zeros((n_ext, n_ext)))
    G = [np.where(ok[:, None], dphi / np.where(ok, F, 1.0)[:, None], 0.0)]
    prec = [np.full(p, 1.0 / max(s.strength_spread, 1e-6) ** 2)]
    fm = sim_e.muscles(phi[None])
    for n in names:
        e = EFFECTS[n](ext)
        th = np.asarray(theta[n], float)
        for j, prm in enumerate(e.params()):
            span = prm.hi - prm.lo
            h = 1e-3 * span
            step = h if th[j] + h <= prm.hi else -h
            th2 = th.copy()
            th2[j] = th[j] + step
            th_all = {**theta, n: th2}
            F2 = Simulator(ext, _instance(ext, label, th_all), sim_e.cache).forces(fm)[0]
            with np.errstate(divide="ignore", invalid="ignore"):
                g = np.where(ok & (F2 > 0), (np.log(np.maximum(F2, 1e-300)) - logF) / step, 0.0)
            G.append(g[:, None])
            prec.append(np.array([12.0 / span ** 2]))            # variance of a uniform prior over the range
    G = np.hstack(G)
    if "posture" in pool and (pool["posture"] != "neutral").any():
        logF, G, ok = _posture_rows(ctx, pool, label, theta, phi, logF, G, ok, sim_e)
    Jm = G[:K][ok[:K]]
    H = Jm.T @ Jm / max(sigma, 1e-6) ** 2 + np.diag(np.concatenate(prec))
    cov_par = np.linalg.inv(H)
    return CandidatePrediction(label, theta, phi, loss, logF, G @ cov_par @ G.T)


def _posture_rows(ctx: GapContext, pool: pd.DataFrame, label: str, theta: dict, phi: np.ndarray,
                  logF: np.ndarray, G: np.ndarray | None, ok: np.ndarray, sim_e: Simulator):
    """``logF``, ``G`` (None: not needed) and ``ok`` with the pool's posture tests predicted in their postures: the
    candidate's instance in the posture's model (:func:`neckstrength.gap.protocols.posture_context`) at the
    neutral strengths times ``rho``; derivatives by forward differences (strengths, then effect parameters)."""
    from neckstrength.gap.protocols import posture_context

    K = ctx.K
    logF = logF.copy()
    ok = ok.copy()
    G = None if G is None else G.copy()
    names = parse_label(label)
    p = len(phi)
    h = 1e-3
    for q in [x for x in dict.fromkeys(pool["posture"]) if x != "neutral"]:
        idx = np.flatnonzero(pool["posture"].to_numpy() == q)
        cq, rho = posture_context(ctx, q)
        keep = [c for c in ctx.directions.columns if c in pool.columns]
        cq = replace(cq, directions=pool.iloc[idx][keep].reset_index(drop=True))

        def fq(ph, th=theta):
            sq = Simulator(cq, _instance(cq, label, th))
            return sq.forces(sim_e.muscles(np.atleast_2d(ph)) * rho[None])

        F0 = fq(phi)[0]
        okq = F0 > 0
        with np.errstate(divide="ignore"):
            lq = np.log(F0)
        logF[K + idx] = lq
        ok[K + idx] = okq
        if G is None:
            continue
        Fh = fq(phi[None] + h * np.eye(p))
        rowsG = [np.where(okq[None], (np.log(np.maximum(Fh, 1e-300)) - np.where(okq, lq, 0.0)[None]) / h, 0.0).T]
        for n in names:
            e = EFFECTS[n](cq)
            th = np.asarray(theta[n], float)
            for j, prm in enumerate(e.params()):
                step = 1e-3 * (prm.hi - prm.lo)
                step = step if th[j] + step <= prm.hi else -step
                th2 = th.copy()
                th2[j] += step
                F2 = fq(phi, {**theta, n: th2})[0]
                rowsG.append(np.where(okq & (F2 > 0), (np.log(np.maximum(F2, 1e-300)) - np.where(okq, lq, 0.0)) / step,
                                      0.0)[:, None])
        G[K + idx] = np.hstack(rowsG)
    return logF, G, ok


# ----------------------------------------------------------------------------- expected log Bayes factor

def expected_log_bf(mu_a: np.ndarray, cov_a: np.ndarray, mu_b: np.ndarray, cov_b: np.ndarray) -> float:
    """``E_a[log p_a(y) / p_b(y)]`` for normal predictives ``N(mu_a, cov_a)``, ``N(mu_b, cov_b)`` of the log
    forces ``y`` of new measurements: the Kullback-Leibler divergence ``KL(N_a || N_b)`` (0 when the two
    predict the same; grows with the squared difference of the means in units of the predictive SD)."""
    mu_a, mu_b = np.atleast_1d(mu_a).astype(float), np.atleast_1d(mu_b).astype(float)
    cov_a, cov_b = np.atleast_2d(cov_a).astype(float), np.atleast_2d(cov_b).astype(float)
    k = len(mu_a)
    d = mu_b - mu_a
    La = np.linalg.cholesky(cov_a)
    Lb = np.linalg.cholesky(cov_b)
    sol = np.linalg.solve(Lb, np.column_stack([La, d]))
    tr = float((sol[:, :k] ** 2).sum())
    maha = float((sol[:, k] ** 2).sum())
    logdet = 2.0 * float(np.log(np.diag(Lb)).sum() - np.log(np.diag(La)).sum())
    return 0.5 * (tr + maha - k + logdet)


def _pair_values(mu: np.ndarray, cov: np.ndarray, sigma: float, idx: Sequence[int], pairs) -> np.ndarray:
    """(pairs, 2) expected log BF of the measurements ``idx`` (pool columns) for each pair, both directions."""
    ix = np.asarray(idx, int)
    noise = sigma ** 2 * np.eye(len(ix))
    out = np.zeros((len(pairs), 2))
    for q, (a, b) in enumerate(pairs):
        Sa = cov[a][np.ix_(ix, ix)] + noise
        Sb = cov[b][np.ix_(ix, ix)] + noise
        out[q, 0] = expected_log_bf(mu[a, ix], Sa, mu[b, ix], Sb)
        out[q, 1] = expected_log_bf(mu[b, ix], Sb, mu[a, ix], Sa)
    return out


#: Aggregates over pairs of their expected log BF ``L`` (each the smaller of its two directions).
OBJECTIVES = ("saturating", "min", "sum")


def _objective(per_pair: np.ndarray, objective: str) -> float:
    """'saturating': sum of ``1 - exp(-L)`` (a pair already told apart, or one no measurement separates, adds
    little either way; ``exp(-L)`` is a Chernoff-type proxy of the chance of preferring the wrong one of the
    pair, heuristic, not calibrated); 'min': the worst pair; 'sum': the plain sum."""
    if not len(per_pair):
        return 0.0
    if objective == "min":
        return float(per_pair.min())
    if objective == "sum":
        return float(per_pair.sum())
    return float((1.0 - np.exp(-np.maximum(per_pair, 0.0))).sum())


def greedy_design(mu: np.ndarray, cov: np.ndarray, sigma: float, n: int, objective: str = "saturating",
                  usable: np.ndarray | None = None, pairs: Sequence[tuple[int, int]] | None = None
                  ) -> tuple[list[int], list[np.ndarray]]:
    """Greedy choice of ``n`` measurements (pool columns of ``mu`` (C x N) and ``cov`` (C x N x N); a column
    may be chosen again: an independent repeat) maximising the expected log Bayes factor of the chosen set,
    per pair the smaller of its two directions, then the ``objective`` (:data:`OBJECTIVES`) over ``pairs``
    (default: all pairs of the C candidates); ties by the sum. Returns the chosen columns and, after each
    step, the (pairs x 2) expected log BF of the set so far."""
    C, N = mu.shape
    pairs = list(pairs) if pairs is not None else list(itertools.combinations(range(C), 2))
    usable = np.ones(N, bool) if usable is None else np.asarray(usable, bool)
    if objective not in OBJECTIVES:
        raise ValueError(f"gap.discriminate.objective must be one of {OBJECTIVES}, not {objective!r}")
    chosen: list[int] = []
    trace: list[np.ndarray] = []
    for _ in range(int(n)):
        best, best_key, best_val = -1, (-np.inf, -np.inf), None
        for j in np.nonzero(usable)[0]:
            v = _pair_values(mu, cov, sigma, chosen + [int(j)], pairs)
            per_pair = v.min(axis=1)
            key = (_objective(per_pair, objective), float(per_pair.sum()))
            if key > best_key:
                best, best_key, best_val = int(j), key, v
        if best < 0:
            break
        chosen.append(best)
        trace.append(best_val)
    return chosen, trace


# ----------------------------------------------------------------------------- proposal for one diagnosis

def noise_level(diag, s: DiscriminateSettings) -> tuple[float, str]:
    """Measurement noise (log-normal SD) of the predictive, and where it comes from."""
    if not isinstance(s.noise, str):
        return float(s.noise), "given in the config (e.g. repeat trials)"
    sm = diag.summary
    if sm.get("calibrated") and np.isfinite(sm.get("noise_sigma", np.nan)):
        return float(sm["noise_sigma"]), f"the calibration's noise level ({sm.get('noise_source')})"
    res = diag.residuals
    T = res["measured_N"].to_numpy(float)
    rms = [float(np.sqrt(np.mean(np.log(np.maximum(res[c].to_numpy(float), 1e-12) / T) ** 2)))
           for c in ("heldout_N", "chosen_heldout_N") if c in res]
    return min(rms), "the smaller RMS log held-out residual of the base model and the chosen candidate"


def _strength_starts(ctx: GapContext, diag) -> list[np.ndarray]:
    """Log free strengths of the diagnosis's stored fits (base and chosen candidate), as extra starts."""
    st = diag.strengths
    if st is None or not len(st):
        return []
    from neckstrength.estimation.parameters import free_parameters

    pidx, _ = free_parameters(ctx.model, ctx.tie_sides)
    out = []
    for c in dict.fromkeys(st["candidate"]):
        f = st[st["candidate"] == c].set_index("muscle").loc[list(ctx.model.muscle_names), "f_fit_N"].to_numpy(float)
        p = int(pidx.max()) + 1
        phi = np.array([np.log(f[pidx == q].mean()) for q in range(p)])
        if np.all(np.isfinite(phi)):
            out.append(phi)
    return out


PROPOSAL_COLUMNS = ["step", "measurement", "kind", "repeat_of", "planes", "azimuth_deg", "elevation_deg", "px",
                    "py", "pz", "nx", "ny", "nz", "candidate_a", "candidate_b", "force_a_N", "force_b_N",
                    "elbf_if_a", "elbf_if_b", "cum_elbf_if_a", "cum_elbf_if_b", "sigma"]


def candidate_predictions(ctx: GapContext, forces: np.ndarray, diag, s: DiscriminateSettings,
                          pool: pd.DataFrame, workers: int = 1) -> tuple[list[CandidatePrediction], float, str]:
    """The predictives (:func:`predict_candidate`) of the top ``s.candidates`` of ``diag``'s ranking (at least 2)
    on the measured directions followed by ``pool``, with the measurement noise and its source. ``workers`` > 1:
    the candidates are shared out over that many forked processes (each candidate's predictive is computed
    alone either way, so the answer does not depend on it)."""
    top = diag.effects.sort_values("rank").reset_index(drop=True).head(max(2, int(s.candidates)))
    sigma, src = noise_level(diag, s)
    starts = _strength_starts(ctx, diag)
    jobs = [(r.candidate, json.loads(r.theta_values)) for r in top.itertuples()]
    workers = max(1, min(int(workers), len(jobs)))
    if workers == 1:
        return [predict_candidate(ctx, forces, c, th, pool, sigma, s, starts) for c, th in jobs], sigma, src
    preds: list = [None] * len(jobs)
    for i, pr in fork_map(lambda job: predict_candidate(ctx, forces, job[0], job[1], pool, sigma, s, starts), jobs,
                          workers):
        preds[i] = pr
    return preds, sigma, src


def predictive_logpdf(preds: Sequence[CandidatePrediction], K: int, idx: Sequence[int], log_forces: np.ndarray,
                      sigma: float) -> np.ndarray:
    """Log density of the new log forces ``log_forces`` at the pool columns ``idx`` under each candidate's normal
    predictive (mean its prediction, covariance ``sigma^2 I + G Cov G'``); -inf where a candidate cannot produce
    a measured test."""
    ix = K + np.asarray(idx, int)
    y = np.asarray(log_forces, float)
    logp = np.zeros(len(preds))
    for a, pr in enumerate(preds):
        mu = pr.log_force[ix]
        if not np.all(np.isfinite(mu)):
            logp[a] = -np.inf
            continue
        L = np.linalg.cholesky(pr.cov[np.ix_(ix, ix)] + sigma ** 2 * np.eye(len(ix)))
        z = np.linalg.solve(L, y - mu)
        logp[a] = -0.5 * float(z @ z) - float(np.log(np.diag(L)).sum()) - 0.5 * len(ix) * np.log(2 * np.pi)
    return logp


def predictive_choice(preds: Sequence[CandidatePrediction], K: int, idx: Sequence[int], log_forces: np.ndarray,
                      sigma: float, prior: Sequence[float] | None = None) -> tuple[str, np.ndarray]:
    """Which of the candidates the new measurements favour: the candidate with the highest posterior
    ``prior_a x p_a(y)``, ``p_a`` its normal predictive of the new log forces ``log_forces`` at the pool
    columns ``idx`` (a column may repeat: independent trials), mean its prediction and covariance
    ``sigma^2 I + G Cov G'`` - the same predictive whose expected log Bayes factors the proposal maximises,
    so the decision matches the design. Equal prior by default. Returns the label and the posterior
    probabilities over ``preds`` (these assume that one of the candidates is true and the Laplace predictive;
    a heuristic, not calibrated). A candidate that cannot produce a measured test (predicted force 0) gets
    probability 0."""
    logp = predictive_logpdf(preds, K, idx, log_forces, sigma)
    pri = np.full(len(preds), 1.0 / len(preds)) if prior is None else np.asarray(prior, float)
    with np.errstate(divide="ignore"):
        lp = logp + np.log(pri)
    if not np.isfinite(lp).any():
        return preds[int(np.argmax(pri))].label, pri / pri.sum()
    w = np.exp(lp - lp.max())
    w /= w.sum()
    return preds[int(np.argmax(w))].label, w


def propose_measurements(ctx: GapContext, forces: np.ndarray, diag, head: HeadEllipsoid,
                         s: DiscriminateSettings = DiscriminateSettings(), plane_bands: dict | None = None,
                         pool: pd.DataFrame | None = None, preds: Sequence[CandidatePrediction] | None = None,
                         workers: int = 1) -> tuple[pd.DataFrame, dict]:
    """The proposal table for one :class:`~neckstrength.gap.diagnose.DatasetDiagnosis` (empty when the best
    candidate's P(best) is not below ``s.p_best_below``) and a summary dict.

    Table: one row per proposed measurement (``step`` 1..n, in the greedy order) and candidate pair: the
    measurement (a repeat of a measured direction or a new surface point; point, normal, planes), the
    pair's predicted forces, the expected log Bayes factor of this measurement alone if ``candidate_a``
    (``elbf_if_a``) or ``candidate_b`` (``elbf_if_b``) is true, and of all proposed measurements up to this
    step (``cum_*``). ``preds``: the candidates' predictives on ``pool`` (:func:`candidate_predictions`), if
    already computed; ``workers``: processes that compute them."""
    ef = diag.effects.sort_values("rank").reset_index(drop=True)
    p_best = float(ef["p_best"].iloc[0])
    info = {"p_best_top": p_best, "threshold": s.p_best_below, "proposed": False}
    if not (p_best < s.p_best_below) or len(ef) < 2:
        info["note"] = ("only one candidate" if len(ef) < 2 else
                        "no bootstrap P(best) (gap.bootstrap = 0)" if not np.isfinite(p_best) else
                        f"not needed: P(best) of `{ef['candidate'].iloc[0]}` = {p_best:.2f} >= {s.p_best_below:g}")
        return pd.DataFrame(columns=PROPOSAL_COLUMNS), info
    pool = measurement_pool(ctx, head, s, plane_bands) if pool is None else pool
    if preds is None:
        preds, sigma, src = candidate_predictions(ctx, forces, diag, s, pool, workers)
    else:
        sigma, src = noise_level(diag, s)
    diag._predictions = (s, pool, preds, sigma, src)   # for update_with_trials (not stored with the diagnosis)
    K = ctx.K
    mu = np.array([pr.log_force[K:] for pr in preds])
    cov = np.array([pr.cov[K:, K:] for pr in preds])
    usable = np.all(np.isfinite(mu), axis=0)              # a test some candidate cannot produce is not proposed
    all_pairs = list(itertools.combinations(range(len(preds)), 2))
    spread = np.array([np.nanmax(np.abs(mu[a, usable] - mu[b, usable])) if usable.any() else 0.0
                       for a, b in all_pairs])
    same = [pq for pq, d in zip(all_pairs, spread) if d < 1e-6]
    pairs = [pq for pq in all_pairs if pq not in same]
    chosen, trace = greedy_design(mu, cov, sigma, s.measurements, s.objective, usable, pairs)
    rows = []
    for step, (j, cum) in enumerate(zip(chosen, trace), start=1):
        single = _pair_values(mu, cov, sigma, [j], pairs)
        r = pool.iloc[j]
        for q, (a, b) in enumerate(pairs):
            rows.append({"step": step, "measurement": r["name"], "kind": r["kind"],
                         "repeat_of": r["source"] if r["kind"] == "repeat" else "-", "planes": r["planes"],
                         "azimuth_deg": r.get("azimuth_deg", np.nan), "elevation_deg": r.get("elevation_deg", np.nan),
                         "px": r["px"], "py": r["py"], "pz": r["pz"], "nx": r["nx"], "ny": r["ny"], "nz": r["nz"],
                         "candidate_a": preds[a].label, "candidate_b": preds[b].label,
                         "force_a_N": float(np.exp(mu[a, j])), "force_b_N": float(np.exp(mu[b, j])),
                         "elbf_if_a": single[q, 0], "elbf_if_b": single[q, 1],
                         "cum_elbf_if_a": cum[q, 0], "cum_elbf_if_b": cum[q, 1], "sigma": sigma})
    tab = pd.DataFrame(rows, columns=PROPOSAL_COLUMNS)
    info.update({"proposed": bool(len(chosen)), "candidates": [pr.label for pr in preds], "sigma": sigma,
                 "noise_source": src, "parameter_uncertainty": s.parameter_uncertainty, "objective": s.objective, "pool_size": len(pool),
                 "pool_usable": int(usable.sum()),
                 "measurements": [str(pool["name"].iloc[j]) for j in chosen],
                 "indistinguishable_pairs": [f"{preds[a].label} / {preds[b].label}" for a, b in same],
                 "expected_log_bf": {f"{preds[a].label} vs {preds[b].label}": [float(trace[-1][q, 0]),
                                                                              float(trace[-1][q, 1])]
                                     for q, (a, b) in enumerate(pairs)} if trace else {}})
    return tab, info



UPDATE_COLUMNS = ["candidate", "posterior", "log_predictive", "trials", "measurements"]


def read_extra_trials(path, pool: pd.DataFrame) -> pd.DataFrame:
    """The additional trials of a participant: a CSV with one row per trial, columns ``measurement`` (a pool
    name: ``<direction>#2`` for a repeat of a test direction, ``azAAA_elEE`` for a surface point; as in
    ``discrimination.csv``) and ``force_N`` (> 0); lines starting with ``#`` are comments (a ``#`` inside a
    field is part of the name). Errors name the file, line and field."""
    import csv

    from neckstrength.errors import InputError

    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise InputError(f"{path}: cannot read the extra trials ({exc})") from exc
    lines = [(k, ln) for k, ln in enumerate(text.splitlines(), start=1) if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InputError(f"{path}: no header (columns: measurement, force_N)")
    header = [h.strip() for h in next(csv.reader([lines[0][1]]))]
    for c in ("measurement", "force_N"):
        if c not in header:
            raise InputError(f"{path}, line {lines[0][0]}: missing column '{c}' (columns: measurement, force_N)")
    im, jf = header.index("measurement"), header.index("force_N")
    names = set(pool["name"])
    rows = []
    for k, ln in lines[1:]:
        rec = [v.strip() for v in next(csv.reader([ln]))]
        m = rec[im] if im < len(rec) else ""
        if m not in names:
            raise InputError(f"{path}, line {k}, field 'measurement': {m!r} is not a possible measurement (a test "
                             "direction with '#2', or a surface point like 'az+030_el+60')")
        try:
            f = float(rec[jf]) if jf < len(rec) else np.nan
        except ValueError:
            f = np.nan
        if not np.isfinite(f) or f <= 0:
            raise InputError(f"{path}, line {k}, field 'force_N': {rec[jf] if jf < len(rec) else ''!r} is not a "
                             "positive force")
        rows.append((m, f))
    if not rows:
        raise InputError(f"{path}: no trials")
    return pd.DataFrame(rows, columns=["measurement", "force_N"])


def update_with_trials(ctx: GapContext, forces: np.ndarray, diag, head: HeadEllipsoid, trials: pd.DataFrame,
                       s: DiscriminateSettings = DiscriminateSettings(), plane_bands: dict | None = None
                       ) -> tuple[pd.DataFrame, dict]:
    """Which of the top candidates the additional ``trials`` (:func:`read_extra_trials`) favour: their
    posterior probabilities by :func:`predictive_choice` (equal prior over the top ``s.candidates``; the
    predictive of each candidate from the measured directions, as the proposal uses). Simulation
    (docs/gap_diagnosis.md) shows this decision gaining from the proposed measurements; the probabilities
    assume that one of the candidates is true and are not calibrated."""
    pool = measurement_pool(ctx, head, s, plane_bands)
    cached = getattr(diag, "_predictions", None)
    if cached is not None and cached[0] == s and cached[1].equals(pool):
        preds, sigma, src = cached[2:]                    # the proposal's, same settings and pool
    else:
        preds, sigma, src = candidate_predictions(ctx, forces, diag, s, pool)
    names = list(pool["name"])
    idx = [names.index(m) for m in trials["measurement"]]
    y = np.log(trials["force_N"].to_numpy(float))
    label, w = predictive_choice(preds, ctx.K, idx, y, sigma)
    logp = predictive_logpdf(preds, ctx.K, idx, y, sigma)
    tab = pd.DataFrame({"candidate": [p.label for p in preds], "posterior": w, "log_predictive": logp,
                        "trials": len(trials), "measurements": ";".join(trials["measurement"])},
                       columns=UPDATE_COLUMNS).sort_values("posterior", ascending=False).reset_index(drop=True)
    info = {"favoured": label, "posterior": {p.label: float(v) for p, v in zip(preds, w)}, "sigma": sigma,
            "noise_source": src, "trials": len(trials), "measurements": list(trials["measurement"])}
    return tab, info


def attach_update(ctx: GapContext, forces: np.ndarray, diag, head: HeadEllipsoid, trials: pd.DataFrame,
                  s: DiscriminateSettings = DiscriminateSettings(), plane_bands: dict | None = None):
    """Add :func:`update_with_trials` to a diagnosis: ``diag.update`` and ``diag.summary['update']``."""
    tab, info = update_with_trials(ctx, forces, diag, head, trials, s, plane_bands)
    diag.update = tab
    diag.summary["update"] = info
    return diag


def attach_proposal(ctx: GapContext, forces: np.ndarray, diag, head: HeadEllipsoid,
                    s: DiscriminateSettings = DiscriminateSettings(), plane_bands: dict | None = None,
                    workers: int = 1):
    """Add the proposal to a diagnosis: ``diag.discrimination`` (the table of :func:`propose_measurements`)
    and ``diag.summary['discrimination']`` (its summary). Returns ``diag``. ``workers``: processes for the
    candidates' predictives."""
    tab, info = propose_measurements(ctx, forces, diag, head, s, plane_bands, workers=workers)
    diag.discrimination = tab
    diag.summary["discrimination"] = info
    return diag
