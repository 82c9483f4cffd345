"""What postures buy (issue 20): neutral-only vs neutral + postures at equal numbers of tests.

Simulated participants per model: ``f_a = f'_base exp(spread z)`` per group (left and right drawn apart), with the
deep-extensor groups further scaled by U(deficit_low, deficit_high) in the 'deficit' condition. Each participant is
estimated twice with the joint sequential estimator (same prior candidates, same seeds): (a) the criterion picks
among the neutral directions only, (b) among every (posture, direction) pair. After t tests (``t_values``): per
muscle group the relative error of the posterior mean and the relative posterior sd; whether the deep-extensor
deficit is identified (posterior probability that the group is below ``threshold`` x baseline >= ``p_identify``);
and the posture of every pick.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from neckstrength.postures.datasets import posture_dataset, posture_grid
from neckstrength.postures.model import PostureSet
from neckstrength.postures.sequential import PostureJointPosterior
from neckstrength.sequential.joint import JointSettings
from neckstrength.seeds import generator


@dataclass(frozen=True)
class ComparisonSettings:
    n_deficit: int = 3
    n_normal: int = 2
    deficit_low: float = 0.25
    deficit_high: float = 0.50
    spread: float = 0.10            # log-sd of the participant's other groups around f'_base
    noise_rel: float = 0.05         # log-normal measurement noise of every simulated force
    t_values: tuple[int, ...] = (10, 25)
    threshold: float = 0.75         # deficit = group below 0.75 x baseline ...
    p_identify: float = 0.9         # ... with posterior probability >= 0.9
    change_cost: float = 0.0        # nats per posture change (PostureJointPosterior)
    criterion: str = "joint_eig"


def group_of(name: str) -> str:
    return name[:-2] if name.endswith(("-R", "-L")) else name


def simulated_participants(pset: PostureSet, deep_groups: Sequence[str], s: ComparisonSettings,
                           rng: np.random.Generator) -> list[tuple[str, str, np.ndarray]]:
    """(id, condition, f_a) for ``n_deficit`` participants with a deep-extensor deficit and ``n_normal`` without."""
    base = pset.strengths
    deep = np.array([group_of(n) in set(deep_groups) for n in pset.muscle_names])
    if not deep.any():
        raise ValueError(f"deep-extensor groups {list(deep_groups)} not in model {pset.name} ({pset.muscle_names})")
    out = []
    for k in range(s.n_deficit + s.n_normal):
        cond = "deficit" if k < s.n_deficit else "normal"
        f = base * np.exp(s.spread * rng.standard_normal(len(base)))
        if cond == "deficit":
            f[deep] = base[deep] * rng.uniform(s.deficit_low, s.deficit_high)
        out.append((f"{cond[0].upper()}{k + 1}", cond, f))
    return out


def compare_postures(pset: PostureSet, directions: pd.DataFrame, deep_groups: Sequence[str],
                     settings: JointSettings, s: ComparisonSettings, seed: np.random.SeedSequence,
                     arms: Sequence[str] = ("neutral", "postures"),
                     progress: Callable[[str], None] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Run the comparison. Returns (per group: participant, condition, arm, t, group, f_a, f_base, E, sd, rel_error,
    rel_sd, p_below; per pick: participant, arm, t, test, posture)."""
    grid = posture_grid(pset, directions)
    s_truth, s_noise, s_runs = seed.spawn(3)
    parts = simulated_participants(pset, deep_groups, s, generator(s_truth))
    noise_rng = generator(s_noise)
    deep = np.array([group_of(n) in set(deep_groups) for n in pset.muscle_names])
    rows, picks = [], []
    t_max = max(s.t_values)
    run_seeds = s_runs.spawn(len(parts))
    for (pid, cond, fa), ss in zip(parts, run_seeds):
        data = posture_dataset(pset, grid, pid, fa)
        forces = data.forces * np.exp(s.noise_rel * noise_rng.standard_normal(len(data.forces)))
        measured = dict(zip(data.directions, forces))
        s_cand, s_prop = ss.spawn(2)
        for arm in arms:
            t0 = time.time()
            keep = grid["posture"].eq("neutral") if arm == "neutral" else np.ones(len(grid), bool)
            g = grid[keep].reset_index(drop=True)
            U = g[[c for c in g.columns if c.startswith("u") and c[1:].isdigit()]].to_numpy(float)
            post = PostureJointPosterior(pset, list(g["label"]), U, g["force_scale"].to_numpy(float),
                                         list(g["posture"]), pset.strengths, settings,
                                         generator(s_cand), change_cost=s.change_cost)
            rng = generator(s_prop)
            n = min(t_max, len(g))
            for t in range(1, n + 1):
                label, _ = post.propose(s.criterion, rng)
                post.update(label, measured[label])
                picks.append({"participant": pid, "condition": cond, "arm": arm, "t": t, "test": label,
                              "posture": post.current_posture})
                # a target t beyond the available tests (p3m12 neutral: 7 sagittal directions) is reported with
                # every available test (column n_tests)
                targets = [tv for tv in s.t_values if tv == t or (t == n and tv > n)]
                if targets:
                    w = post.weights()
                    E = w @ post.F
                    sd = np.sqrt(w @ (post.F - E) ** 2)
                    p_below = w @ (post.F < s.threshold * pset.strengths[None, :])
                    for tv in targets:
                        for j, name in enumerate(pset.muscle_names):
                            rows.append({"participant": pid, "condition": cond, "arm": arm, "t": tv, "n_tests": t,
                                         "muscle": name, "group": group_of(name), "deep": bool(deep[j]),
                                         "f_a": fa[j], "f_base": pset.strengths[j], "E": E[j], "sd": sd[j],
                                         "rel_error": abs(E[j] - fa[j]) / fa[j], "rel_sd": sd[j] / fa[j],
                                         "p_below": p_below[j]})
            if progress:
                progress(f"[postures {pset.name}] {pid} ({cond}) {arm}: {n} tests in {time.time() - t0:.1f} s, "
                         f"{post.n_resamples} resamples; postures picked "
                         f"{pd.Series([p['posture'] for p in picks[-n:]]).value_counts().to_dict()}")
    return pd.DataFrame(rows), pd.DataFrame(picks)


def summarize(groups: pd.DataFrame, picks: pd.DataFrame, s: ComparisonSettings) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per (model arm, t, group): mean relative error and sd over participants (both sides pooled); per
    (arm, t, condition): share of participants whose deep-extensor deficit is identified; and the posture share of
    the first picks."""
    g = groups.groupby(["condition", "arm", "t", "group"], as_index=False).agg(
        rel_error=("rel_error", "mean"), rel_sd=("rel_sd", "mean"), n_tests=("n_tests", "max"),
        n=("participant", "nunique"))
    deep = groups[groups["deep"]].groupby(["participant", "condition", "arm", "t"], as_index=False).agg(
        p_below=("p_below", "mean"), ratio=("E", "sum"), base=("f_base", "sum"))
    deep["ratio"] = deep["ratio"] / deep["base"]
    deep["identified"] = deep["p_below"] >= s.p_identify
    ident = deep.groupby(["arm", "t", "condition"], as_index=False).agg(
        identified=("identified", "mean"), p_below=("p_below", "mean"), E_over_base=("ratio", "mean"),
        n=("participant", "nunique"))
    return g, ident


def first_picks(picks: pd.DataFrame, first: int = 5) -> pd.DataFrame:
    """Share of each posture among the first ``first`` picks (and among all), arm 'postures'."""
    p = picks[picks["arm"] == "postures"]
    a = p[p["t"] <= first]["posture"].value_counts(normalize=True).rename(f"share_first_{first}")
    b = p["posture"].value_counts(normalize=True).rename("share_all")
    return pd.concat([a, b], axis=1).fillna(0.0).rename_axis("posture").reset_index()
