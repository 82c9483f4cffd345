"""Simulated patients for measuring the deficit decision: truths made apart from the decision's own priors.

The decision (:mod:`neckstrength.sequential.decision`) assumes every muscle varies independently as a truncated
normal with sd ``population_sd`` of normal, and a deficit uniform per side. The truths here are drawn otherwise, so
that the study does not only check the method against its own assumptions:

- every muscle group (both sides together) at ``exp(N(0, group_log_sd^2))`` x normal, each side then at
  ``exp(N(0, side_log_sd^2))`` x its group's value (left/right differ a little, as people do);
- deficit patients: each side of the deficit group at ``U(lo, hi)`` x normal, independently;
- normal participants: the deficit group drawn like every other group, redrawn until each side is at least
  ``normal_floor`` x normal (a participant below it would not be "normal");
- forces: the model's maximum force of the truth in every test direction times ``exp(N(0, noise^2))``;
- a truth that cannot push in every direction is redrawn (from the same stream).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from neckstrength.model.reduction import ReducedModel
from neckstrength.wrench.problem import STATUS_CODES

_OPT = {v: k for k, v in STATUS_CODES.items()}["optimal"]


@dataclass(frozen=True)
class CohortSettings:
    """The simulated cohort of the decision study (config ``clinician.decision_study``)."""

    n_deficit: int = 100
    n_normal: int = 100
    deficit_range: tuple[float, float] = (0.2, 0.6)
    normal_floor: float = 0.6
    group_log_sd: float = 0.25
    side_log_sd: float = 0.05
    noise: float = 0.05

    def __post_init__(self):
        lo, hi = self.deficit_range
        if not 0 < lo < hi:
            raise ValueError(f"deficit_range must be 0 < low < high, got {self.deficit_range}")
        if min(self.n_deficit, self.n_normal) < 1:
            raise ValueError("the cohort needs at least one deficit and one normal participant")
        if self.noise < 0 or self.group_log_sd < 0 or self.side_log_sd < 0:
            raise ValueError("noise and spreads must be >= 0")


def _groups(muscle_names: Sequence[str]) -> tuple[list[str], np.ndarray]:
    base = [n[:-2] if n.endswith(("-R", "-L")) else n for n in muscle_names]
    names = list(dict.fromkeys(base))
    return names, np.array([names.index(b) for b in base])


def draw_truth(f0: np.ndarray, muscle_names: Sequence[str], group: Sequence[str], deficit: bool,
               settings: CohortSettings, rng: np.random.Generator) -> np.ndarray:
    """One participant's strengths (see the module docstring)."""
    f0 = np.asarray(f0, float)
    names, gi = _groups(muscle_names)
    in_group = np.array([n in set(group) for n in np.array(names)[gi]])
    for _ in range(1000):
        g = np.exp(settings.group_log_sd * rng.standard_normal(len(names)))
        side = np.exp(settings.side_log_sd * rng.standard_normal(len(f0)))
        r = g[gi] * side
        if deficit:
            lo, hi = settings.deficit_range
            r[in_group] = rng.uniform(lo, hi, int(in_group.sum()))
            return f0 * r
        if np.all(r[in_group] >= settings.normal_floor):
            return f0 * r
    raise RuntimeError("no normal participant above the floor in 1000 draws: normal_floor too high")


def simulate_participant(model: ReducedModel, U: np.ndarray, force_scale: np.ndarray, f0: np.ndarray,
                         group: Sequence[str], deficit: bool, settings: CohortSettings, rng: np.random.Generator,
                         cache=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(truth f, forces in N per direction with noise, true activations (K, m)) of one simulated participant."""
    from neckstrength.wrench import solve

    for _ in range(100):
        f = draw_truth(f0, model.muscle_names, group, deficit, settings, rng)
        w, alpha, st = solve(model, f[None], U, cache=cache)
        if np.all(st[0] == _OPT) and np.all(w[0] > 0):
            forces = w[0] * np.exp(settings.noise * rng.standard_normal(len(w[0]))) / np.asarray(force_scale, float)
            return f, forces, alpha[0]
    raise RuntimeError("no producible simulated participant in 100 draws")
