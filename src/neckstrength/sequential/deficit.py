"""Probability of a deep-extensor deficit, and the clinician-loop study that asks how many tests find it (issue 18).

The thesis's motivating case (Chapter 5, Table 5.3 'weak') is a participant whose deep cervical extensors
(multifidus, 'mf' in s3m24) are at a quarter of normal. A clinician does not need 24 means; they need the
probability that the deep extensors are weak. Here a *deficit* is

    (sum of the group's strengths) < threshold x (sum of their baseline strengths)          (default mf, 0.6)

with both sides summed (the thesis's sampler assumed R = L; a one-sided deficit of the same size counts half) and
the baseline the prior mean ``f_0`` of the session (``a f'_base``). On the joint posterior (weighted candidates,
:class:`~neckstrength.sequential.joint.JointPosterior`) the probability is the weight of the candidates below the
threshold; on the thesis's per-muscle scheme (:class:`~neckstrength.sequential.SequentialState`) the group's
marginal PDFs are convolved as that scheme treats them, independent.

:func:`run_deficit_study` simulates participants with the group at ``deficit_range`` of its baseline (the other
muscles from the prior) and normal ones (the group at ``normal_range``), measures them in the order each strategy
picks (the joint expected information gain, random orders, the thesis's Eq. 6.7 on its own scheme, optionally the
joint EIG with simulated EMG bounds of the recorded muscles, or choosing among further points on the head surface as
well as the test directions), and records P(deficit) after every test on the joint posterior;
:func:`detection_summary` gives the tests until P > ``p_alarm`` and the false-alarm rate.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from neckstrength.model.reduction import ReducedModel
from neckstrength.sequential.algorithms import (
    SequentialSettings,
    SequentialState,
    SimulatedSet,
    StrengthGrid,
    producible_truth,
    sample_prior,
)
from neckstrength.sequential.joint import JointPosterior, JointSettings
from neckstrength.wrench.problem import STATUS_CODES


@dataclass(frozen=True)
class DeficitDefinition:
    """A deficit of a muscle group: its summed strength below ``threshold`` x its summed baseline."""

    group: tuple[str, ...] = ("mf",)       # group names (both sides) or muscle names
    threshold: float = 0.6

    def __post_init__(self):
        if not 0 < self.threshold < 1:
            raise ValueError(f"deficit threshold must be in (0, 1), got {self.threshold}")
        if not self.group:
            raise ValueError("deficit group is empty")

    def indices(self, muscle_names: Sequence[str]) -> np.ndarray:
        """Muscles of the group in ``muscle_names`` (a group name matches both sides, 'mf' -> mf-R, mf-L)."""
        keep = set(self.group)
        idx = [j for j, n in enumerate(muscle_names)
               if n in keep or (n.endswith(("-R", "-L")) and n[:-2] in keep)]
        return np.array(idx, dtype=int)

    def applies(self, muscle_names: Sequence[str]) -> bool:
        return len(self.indices(muscle_names)) > 0

    def label(self) -> str:
        return f"{'+'.join(self.group)} < {self.threshold:.0%} of baseline"

    def ratio(self, F: np.ndarray, f_base: np.ndarray, muscle_names: Sequence[str]) -> np.ndarray:
        """Summed group strength / summed baseline of every row of ``F``."""
        idx = self.indices(muscle_names)
        if not len(idx):
            raise ValueError(f"deficit group {self.group} has no muscle in {list(muscle_names)}")
        return np.atleast_2d(F)[:, idx].sum(axis=1) / float(np.asarray(f_base)[idx].sum())

    def probability(self, F: np.ndarray, w: np.ndarray, f_base: np.ndarray, muscle_names: Sequence[str]) -> float:
        """P(deficit) of weighted candidates (the joint posterior)."""
        w = np.asarray(w, float)
        return float(w[self.ratio(F, f_base, muscle_names) < self.threshold].sum() / w.sum())

    def probability_marginal(self, pdf: np.ndarray, grid: StrengthGrid, f_base: np.ndarray,
                             muscle_names: Sequence[str]) -> float:
        """P(deficit) from per-muscle PDFs (m, n_bins) on ``grid``, the group's muscles taken as independent (the
        thesis's scheme): the distribution of the sum by repeated convolution, mass at the bin centres."""
        idx = self.indices(muscle_names)
        if not len(idx):
            raise ValueError(f"deficit group {self.group} has no muscle in {list(muscle_names)}")
        thr = self.threshold * float(np.asarray(f_base)[idx].sum())
        vals, prob = np.zeros(1), np.ones(1)
        for j in idx:
            p = np.asarray(pdf[j], float) * grid.widths[j]
            p = p / p.sum()
            v = (vals[:, None] + grid.centres[j][None, :]).ravel()
            q = (prob[:, None] * p[None, :]).ravel()
            if len(v) > 4096:                # re-bin the running sum onto 2048 points
                edges = np.linspace(v.min(), v.max(), 2049)
                k = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, 2047)
                qb = np.bincount(k, weights=q, minlength=2048)
                vb = np.bincount(k, weights=q * v, minlength=2048)
                v = np.where(qb > 0, vb / np.where(qb > 0, qb, 1.0), 0.5 * (edges[1:] + edges[:-1]))
                q = qb
            vals, prob = v, q
        return float(prob[vals < thr].sum())


def joint_deficit_probability(post: JointPosterior, definition: DeficitDefinition) -> float:
    """P(deficit) on a joint posterior, baseline = its prior mean ``f0``."""
    return definition.probability(post.F, post.weights(), post.f0, post.model.muscle_names)


@dataclass(frozen=True)
class StudySettings:
    """Sizes of the deficit-detection study (config ``clinician.study``; none of this is in the thesis)."""

    n_deficit: int = 50
    n_normal: int = 25
    deficit_range: tuple[float, float] = (0.25, 0.5)     # group strength / baseline, each side drawn uniformly
    normal_range: tuple[float, float] = (0.8, 1.2)
    noise: float = 0.05                                  # log-normal force noise (sd of log force)
    n_max: int = 25                                      # tests per run (capped at the model's directions)
    p_alarm: float = 0.9
    strategies: tuple[str, ...] = ("joint_eig", "random", "thesis")
    n_random: int = 1
    emg_groups: tuple[str, ...] = ()                     # strategy 'joint_eig+emg': bounds of these groups
    emg_band: float = 0.05
    # strategy 'joint_eig+surface': the test directions plus points on the cranial ellipsoid (azimuth step x
    # elevations, face left out, force along the outward normal), chosen from by the same criterion
    surface_azimuth_step_deg: float = 30.0
    surface_elevation_deg: tuple[float, ...] = (-30.0, 0.0, 30.0, 60.0)

    def __post_init__(self):
        bad = [s for s in self.strategies if s not in STRATEGIES]
        if bad:
            raise ValueError(f"unknown strategies {bad}; known: {STRATEGIES}")
        for name, (lo, hi) in (("deficit_range", self.deficit_range), ("normal_range", self.normal_range)):
            if not 0 < lo <= hi:
                raise ValueError(f"{name} must be 0 < low <= high, got {(lo, hi)}")
        if "joint_eig+emg" in self.strategies and not self.emg_groups:
            raise ValueError("strategy 'joint_eig+emg' needs emg_groups (the recorded muscle groups)")
        if self.n_random < 1 and "random" in self.strategies:
            raise ValueError("strategy 'random' needs n_random >= 1")


_OPT = {v: k for k, v in STATUS_CODES.items()}["optimal"]


STRATEGIES = ("joint_eig", "random", "thesis", "joint_eig+emg", "joint_eig+emg+deep", "joint_eig+surface")


def draw_participant(f0: np.ndarray, prior_sd_rel: float, group_idx: np.ndarray, low: float, high: float,
                     rng: np.random.Generator) -> np.ndarray:
    """Strengths from the prior ``N(f0, (sd f0)^2)`` (truncated at 0) with the group's muscles at U(low, high) x f0."""
    f = sample_prior(f0, prior_sd_rel, 1, rng)[0]
    f[group_idx] = f0[group_idx] * rng.uniform(low, high, len(group_idx))
    return f


def run_deficit_study(model: ReducedModel, directions: Sequence[str], U: np.ndarray, force_scale: np.ndarray,
                      f0: np.ndarray, definition: DeficitDefinition, study: StudySettings, joint: JointSettings,
                      thesis: SequentialSettings | None, rng_for: Callable[[str, int], np.random.Generator],
                      progress: Callable[[str], None] | None = None, first: int = 0,
                      on_participant: Callable[[pd.DataFrame], None] | None = None,
                      participants: Sequence[int] | None = None,
                      skip: Callable[[int], bool] | None = None, n_threads: int = 1,
                      surface: tuple[Sequence[str], np.ndarray, np.ndarray] | None = None) -> pd.DataFrame:
    """One row per participant, strategy run and test count t (0 = prior): P(deficit) on the joint posterior,
    the group's posterior mean, ESS share. Participant ``i`` draws from ``rng_for('truth', i)``; every run of a
    participant starts from the same candidates (``rng_for('candidates', i)``). Participants before ``first`` are
    skipped (resume); ``participants`` restricts the run to these indices (a chunk of a split run); ``skip(i)`` is
    asked just before participant ``i`` (done by another process); ``on_participant`` receives each participant's
    rows when they are complete; ``n_threads``: directions solved concurrently (same numbers). ``surface``:
    (names, U, force scale) of the further head-surface directions of strategy 'joint_eig+surface' (its runs choose
    from ``directions`` and these; a surface direction the participant's truth cannot push in is left out of that
    participant's run, as a clinician would find it untestable)."""
    from neckstrength.wrench import solve
    from neckstrength.wrench.batched import BasisCache

    directions = list(directions)
    names = list(model.muscle_names)
    gidx = definition.indices(names)
    if not len(gidx):
        raise ValueError(f"deficit group {definition.group} has no muscle in {model.name}")
    n_max = min(study.n_max, len(directions))
    cache = BasisCache()
    base = [n[:-2] if n.endswith(("-R", "-L")) else n for n in names]
    emg_mask = np.array([b in set(study.emg_groups) for b in base])
    deep_mask = emg_mask.copy()
    deep_mask[gidx] = True                  # 'joint_eig+emg+deep': the deficit group recorded too (fine-wire EMG)
    sim = None
    if "thesis" in study.strategies:
        if thesis is None:
            raise ValueError("strategy 'thesis' needs the Chapter 6 settings")
        F = sample_prior(f0, thesis.prior_sd_rel, thesis.n_candidates, rng_for("thesis_candidates", 0))
        grid = StrengthGrid.around(f0, thesis.prior_sd_rel, thesis.n_bins, thesis.bin_range_sd)
        sim, = SimulatedSet.build(model, directions, U, F, [grid], thesis.n_wbins, cache=cache)
    rows = []
    t_start = time.time()
    kinds = ["deficit"] * study.n_deficit + ["normal"] * study.n_normal
    todo = range(first, len(kinds)) if participants is None else [i for i in participants if first <= i < len(kinds)]
    for i in todo:
        if skip is not None and skip(i):
            continue
        kind = kinds[i]
        lo, hi = study.deficit_range if kind == "deficit" else study.normal_range
        rt = rng_for("truth", i)

        def draw(rt=rt, lo=lo, hi=hi):  # a truth that cannot produce every direction is redrawn (same stream)
            fa = draw_participant(f0, joint.prior_sd_rel, gidx, lo, hi, rt)
            w, alpha, st = solve(model, fa[None], U, cache=cache)
            return fa, w, alpha, st[0]

        fa, w, alpha, _ = producible_truth(draw, f"participant {i}")
        forces = w[0] * np.exp(study.noise * rt.standard_normal(len(directions))) / force_scale
        if "joint_eig+surface" in study.strategies:
            if surface is None:
                raise ValueError("strategy 'joint_eig+surface' needs the surface directions")
            # drawn after the test directions' noise (nothing else reads rt): the other strategies are unchanged
            ws, _, sts = solve(model, fa[None], surface[1], cache=cache)
            fs_surf = ws[0] * np.exp(study.noise * rt.standard_normal(len(surface[0]))) / surface[2]
            ok = (sts[0] == _OPT) & (ws[0] > 0)
            surf = ([n for n, k in zip(surface[0], ok) if k], surface[1][ok], surface[2][ok], fs_surf[ok])
        bounds = {}
        for key, mask in (("joint_eig+emg", emg_mask), ("joint_eig+emg+deep", deep_mask)):
            lb, ub = np.zeros((len(directions), model.m)), np.ones((len(directions), model.m))
            lb[:, mask] = np.clip(alpha[0][:, mask] - study.emg_band, 0, 1)
            ub[:, mask] = np.clip(alpha[0][:, mask] + study.emg_band, 0, 1)
            bounds[key] = (lb, ub)
        true_ratio = float(definition.ratio(fa[None], f0, names)[0])
        n_before = len(rows)
        runs = []
        for s in study.strategies:
            if s == "random":
                runs += [("random", f"random {r + 1}") for r in range(study.n_random)]
            else:
                runs.append((s, s))
        # the posteriors' bases: one cache per participant (its runs share the region of strength space). A cache
        # shared with earlier participants fills with their bases, which rank first and then fail: up to 2.7x the
        # dual simplex solves at N 20000 (docs/clinician.md); the answers are the same either way (exact solver)
        pcache = BasisCache()
        for strategy, label in runs:
            t0 = time.time()
            if strategy == "joint_eig+surface":
                dirs_run = directions + surf[0]
                post = JointPosterior(model, dirs_run, np.vstack([U, surf[1]]), np.r_[force_scale, surf[2]], f0,
                                      joint, rng_for("candidates", i), cache=pcache, n_threads=n_threads)
                forces_run = np.r_[forces, surf[3]]
            else:
                dirs_run, forces_run = directions, forces
                post = JointPosterior(model, directions, U, force_scale, f0, joint, rng_for("candidates", i),
                                      cache=pcache, n_threads=n_threads)
            prop_rng = rng_for(f"propose/{label}", i)
            state = SequentialState(model, sim, force_scale, thesis) if strategy == "thesis" else None
            emg = bounds.get(strategy)

            base = {"participant": i, "kind": kind, "true_ratio": true_ratio, "strategy": strategy, "run": label}
            rows.append(_record(post, definition, f0, names, base, 0, ""))
            for t in range(1, n_max + 1):
                if strategy == "random":
                    rem = post.remaining
                    d = rem[int(prop_rng.integers(len(rem)))]
                elif strategy == "thesis":
                    d = state.propose(prop_rng).choice
                else:
                    d, _ = post.propose("joint_eig", prop_rng)
                k = dirs_run.index(d)
                act = None if emg is None else (emg[0][k], emg[1][k])
                post.update(d, float(forces_run[k]), act)
                if state is not None:
                    state.update(d, float(forces_run[k]))
                rows.append(_record(post, definition, f0, names, base, t, d))
            if progress:
                last = rows[-1]
                progress(f"participant {i + 1}/{len(kinds)} ({kind}, group at {true_ratio:.0%}) {label}: "
                         f"P(deficit) after {n_max} tests {last['p_deficit']:.2f}; {time.time() - t0:.1f} s "
                         f"(total {time.time() - t_start:.0f} s)")
        if on_participant:
            on_participant(pd.DataFrame(rows[n_before:]))
    return pd.DataFrame(rows)


def _record(post: JointPosterior, definition: DeficitDefinition, f0: np.ndarray, names: Sequence[str], base: dict,
            t: int, direction: str) -> dict:
    w = post.weights()
    below = definition.ratio(post.F, f0, names) < definition.threshold
    return {**base, "t": t, "direction": direction, "p_deficit": definition.probability(post.F, w, f0, names),
            "p_deficit_mc_se": post.mc_se(below),
            "ratio_mean": float(w @ definition.ratio(post.F, f0, names)), "ess_share": post.ess_share(),
            "n_resamples": post.n_resamples}


def detection_summary(df: pd.DataFrame, p_alarm: float = 0.9) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per run: the first t with P(deficit) > ``p_alarm`` (NaN if none); per strategy and kind: the share of runs
    that reach it, median / quartiles of t among the deficit participants (runs that never reach it count as
    beyond the last test), false-alarm rate on normal participants, mean P(deficit) at t = 5, 10, last."""
    per = []
    for (i, run), g in df.groupby(["participant", "run"], sort=False):
        g = g.sort_values("t")
        hit = g.loc[g["p_deficit"] > p_alarm, "t"]
        per.append({"participant": i, "run": run, "strategy": g["strategy"].iloc[0], "kind": g["kind"].iloc[0],
                    "true_ratio": g["true_ratio"].iloc[0], "t_max": int(g["t"].max()),
                    "t_detect": float(hit.iloc[0]) if len(hit) else np.nan,
                    "p_final": float(g["p_deficit"].iloc[-1])})
    per = pd.DataFrame(per)
    out = []
    for (strategy, kind), g in per.groupby(["strategy", "kind"], sort=False):
        tmax = int(g["t_max"].max())
        t = g["t_detect"].fillna(np.inf).to_numpy()
        row = {"strategy": strategy, "kind": kind, "n_runs": len(g), "n_participants": g["participant"].nunique(),
               "share_reached": float(np.isfinite(t).mean())}
        if kind == "deficit":
            q = np.quantile(t, [0.25, 0.5, 0.75], method="inverted_cdf")
            row.update({"t_detect_q25": q[0], "t_detect_median": q[1], "t_detect_q75": q[2],
                        "t_detect_mean_reached": float(t[np.isfinite(t)].mean()) if np.isfinite(t).any() else np.nan})
        else:
            row["false_alarm_rate"] = float(np.isfinite(t).mean())
        sub = df[(df["strategy"] == strategy) & (df["kind"] == kind)]
        for tt in sorted({x for x in (5, 10) if x < tmax} | {tmax}):
            row[f"p_mean_t{tt}"] = float(sub.loc[sub["t"] == tt, "p_deficit"].mean())
        row["t_max"] = tmax
        out.append(row)
    return per, pd.DataFrame(out)
