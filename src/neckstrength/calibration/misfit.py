"""Model discrepancy in the kernel width, and coverage under misspecification (issue 18 item 2).

The joint posterior's kernel (:class:`~neckstrength.sequential.joint.JointSettings` ``noise_rel``) reads every
measured force as the model's force times a log-normal measurement error. When the model cannot fit every
direction (a participant; data from a richer truth) the posterior then narrows around a wrong answer. Here the
width includes the model's own misfit, estimated from held-out directions:

1. the directions are split into ``folds``; for each fold the joint posterior is built from the other directions
   (in a fixed random order) and predicts the held-out ones: ``z_k = log w_k^meas - E log w_k`` and the predictive
   variance ``v_k = Var log w_k`` over the weighted candidates;
2. ``misfit^2 = max(0, mean_k(z_k^2) - mean_k(v_k) - noise_rel^2)``: what the held-out errors show beyond the
   posterior's own spread and the assumed measurement noise;
3. the final posterior, on every direction, uses ``noise_rel' = sqrt(noise_rel^2 + misfit^2)``.

A well-specified model gives misfit near 0 (the kernel is unchanged); a misfit of 0.3 widens the kernel six-fold.

:func:`misfit_coverage` checks it: simulated participants from the fitted model's prior ('well-specified') and
from a richer truth (the 96 muscle elements of the same kinematics, each element's strength varied on its own
around its baseline, so the groups' moment arms change with the individual), forces with log-normal noise, the
joint posterior on all directions with the nominal kernel and with the misfit-aware one, coverage of the 50% and
90% intervals of the group strengths (the truth of a group is its reduction, Sec. 4.2.1.3:
``||f_e S(:, i)||``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from neckstrength.calibration.sbc import LEVELS, muscle_group, weighted_pit, weighted_quantiles
from neckstrength.model.reduction import ReducedModel
from neckstrength.sequential.algorithms import producible_truth, sample_prior
from neckstrength.sequential.joint import JointPosterior, JointSettings


@dataclass(frozen=True)
class MisfitSettings:
    """Sizes of the misspecification check (config ``calibration.misfit``; none of this is in the thesis)."""

    n_participants: int = 20        # per truth
    folds: int = 5                  # held-out folds over the directions
    noise: float = 0.05             # log-normal force noise (sd of log force)
    element_sd: float = 0.3         # richer truth: each element's strength = baseline x exp(element_sd z)
    truths: tuple[str, ...] = ("well", "rich")

    def __post_init__(self):
        if self.folds < 2:
            raise ValueError("folds must be >= 2")
        bad = [t for t in self.truths if t not in ("well", "rich")]
        if bad:
            raise ValueError(f"unknown truths {bad}; known: well, rich")


def heldout_misfit(model: ReducedModel, directions: Sequence[str], U: np.ndarray, force_scale: np.ndarray,
                   forces: np.ndarray, f0: np.ndarray, settings: JointSettings, folds: int,
                   rng: np.random.Generator) -> tuple[float, pd.DataFrame]:
    """The model misfit (sd of log force beyond noise and posterior spread) from held-out directions, and the
    per-direction table (direction, fold, z, predictive variance)."""
    directions = list(directions)
    K = len(directions)
    perm = rng.permutation(K)
    rows = []
    for j, hold in enumerate(np.array_split(perm, min(folds, K))):
        post = JointPosterior(model, directions, U, force_scale, f0, settings, rng)
        for k in perm:
            if k not in hold:
                post.update(directions[k], float(forces[k]))
        w = post.weights()
        for k in hold:
            col = post.W[:, k]
            pos = col > 0
            if not pos.any():
                continue
            y = np.log(col[pos])
            wp = w[pos] / w[pos].sum()
            m = float(wp @ y)
            rows.append({"direction": directions[k], "fold": j, "z": math.log(forces[k] * force_scale[k]) - m,
                         "v": float(wp @ (y - m) ** 2)})
    tab = pd.DataFrame(rows)
    s2 = float((tab["z"] ** 2).mean() - tab["v"].mean() - settings.noise_rel ** 2)
    return math.sqrt(max(0.0, s2)), tab


def rich_truth(full_strengths: np.ndarray, S: np.ndarray, element_sd: float,
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Element strengths ``f_e = f_base exp(element_sd z)`` and the group strengths they reduce to."""
    fe = np.asarray(full_strengths, float) * np.exp(element_sd * rng.standard_normal(len(full_strengths)))
    return fe, np.sqrt(((fe[:, None] * S) ** 2).sum(axis=0))


def misfit_coverage(model: ReducedModel, element_model: ReducedModel, full_strengths: np.ndarray,
                    directions: Sequence[str], U: np.ndarray, U_elements: np.ndarray, force_scale: np.ndarray,
                    settings: MisfitSettings, joint: JointSettings, rng_for: Callable[[str, int], np.random.Generator],
                    progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """One row per truth, participant, kernel ('nominal', 'misfit') and group: truth, PIT, mean, 50/90% bounds,
    covered, and the kernel width used. ``element_model``: the same kinematics with one group per element
    (e.g. 's3-independent'), whose max wrenches simulate the richer truth."""
    from neckstrength.wrench import solve

    directions = list(directions)
    f0 = model.strengths
    rows = []
    t0 = time.time()
    for truth_kind in settings.truths:
        for i in range(settings.n_participants):
            rt = rng_for(f"truth/{truth_kind}", i)

            def draw(rt=rt, truth_kind=truth_kind):
                if truth_kind == "well":
                    fg = sample_prior(f0, joint.prior_sd_rel, 1, rt)[0]
                    w, _, st = solve(model, fg[None], U, return_alpha=False)
                else:
                    fe, fg = rich_truth(full_strengths, model.S, settings.element_sd, rt)
                    f_el = np.sqrt(((fe[:, None] * element_model.S) ** 2).sum(axis=0))   # planar: sides merged
                    w, _, st = solve(element_model, f_el[None], U_elements, return_alpha=False)
                return fg, w, st[0]

            fg, w, _ = producible_truth(draw, f"{truth_kind} participant {i}")
            forces = w[0] * np.exp(settings.noise * rt.standard_normal(len(directions))) / force_scale
            misfit, _ = heldout_misfit(model, directions, U, force_scale, forces, f0, joint, settings.folds,
                                       rng_for(f"heldout/{truth_kind}", i))
            order = rng_for(f"order/{truth_kind}", i).permutation(len(directions))
            for kernel, width in (("nominal", joint.noise_rel), ("misfit", math.hypot(joint.noise_rel, misfit))):
                post = JointPosterior(model, directions, U, force_scale, f0, replace(joint, noise_rel=width),
                                      rng_for(f"posterior/{truth_kind}/{kernel}", i))
                for k in order:
                    post.update(directions[k], float(forces[k]))
                wts = post.weights()
                u = weighted_pit(post.F, wts, fg)
                Q = weighted_quantiles(post.F, wts, [q for L in LEVELS for q in (0.5 - L / 2, 0.5 + L / 2)])
                mean = wts @ post.F
                for j, name in enumerate(model.muscle_names):
                    r = {"truth_kind": truth_kind, "participant": i, "kernel": kernel, "noise_rel": width,
                         "misfit": misfit, "muscle": name, "group": muscle_group(name), "truth": float(fg[j]),
                         "pit": float(u[j]), "mean": float(mean[j]), "ess_share": post.ess_share()}
                    for n_l, L in enumerate(LEVELS):
                        k_ = int(round(100 * L))
                        r[f"lower{k_}"], r[f"upper{k_}"] = float(Q[2 * n_l, j]), float(Q[2 * n_l + 1, j])
                        r[f"covered{k_}"] = bool(Q[2 * n_l, j] <= fg[j] <= Q[2 * n_l + 1, j])
                    rows.append(r)
            if progress:
                progress(f"{truth_kind} participant {i + 1}/{settings.n_participants}: held-out misfit {misfit:.3f} "
                         f"({time.time() - t0:.0f} s)")
    return pd.DataFrame(rows)


def misfit_summary(df: pd.DataFrame) -> pd.DataFrame:
    """Coverage of the 50% / 90% intervals per truth and kernel, with binomial standard errors, the median
    estimated misfit and relative 90% width, mean |relative error|."""
    out = []
    for (tk, kern), g in df.groupby(["truth_kind", "kernel"], sort=False):
        n = len(g)
        r = {"truth": tk, "kernel": kern, "n_participants": int(g["participant"].nunique()), "n_values": n,
             "median_misfit": float(g.groupby("participant")["misfit"].first().median()),
             "median_noise_rel": float(g.groupby("participant")["noise_rel"].first().median())}
        for L in LEVELS:
            k = int(round(100 * L))
            c = float(g[f"covered{k}"].mean())
            r[f"coverage{k}"], r[f"se{k}"] = c, math.sqrt(max(c * (1 - c), 1e-12) / n)
        r["mean_abs_rel_error"] = float(np.mean(np.abs(g["mean"] - g["truth"]) / g["truth"]))
        r["median_rel_width90"] = float(np.median((g["upper90"] - g["lower90"]) / g["truth"]))
        r["calibrated90"] = bool(0.85 <= r["coverage90"] <= 0.95)
        out.append(r)
    return pd.DataFrame(out)
