"""Reduced models per posture and the max wrench of mixed (posture, direction) tests (issue 20).

In posture q an element's maximum force is ``f_i x factor_i(q)`` (its active force-length factor, relative to
neutral by default) and its moment arms and the skull-frame Jacobian are those of q. Every posture uses the
*neutral* model's grouping ``S`` (the same reduction): group strength ``F_g(q) = ||f . factor(q) . S_g||``,
grouped moment arms ``R(q) diag(f . factor(q)) S / F_g(q)`` (Sec. 4.2.1.3). The estimated parameters stay the
neutral group strengths ``x``: scaling group g by ``s`` scales every element of g by ``s`` in every posture, so the
posture-q model's strengths are ``x . rho(q)`` with ``rho(q) = F_g(q) / F_g(neutral)``, exactly.

A test's direction is fixed to the head (the pad sits on the same spot of the head and pushes along the same
skull-frame normal in every posture), so its unit wrench ``u`` in the skull frame is the same in every posture;
what changes is ``J^T(q)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from neckstrength.model.full import COORDINATES, FullModel
from neckstrength.model.geometry import PLANAR_COMPONENTS, PLANAR_INDEX, WRENCH_COMPONENTS
from neckstrength.model.reduction import ReducedModel, reduce_strengths_and_arms
from neckstrength.postures.tables import PostureTable
from neckstrength.wrench import solve

#: Label of a (posture, direction) test, e.g. 'flex20:back'; a plain direction name means neutral.
SEPARATOR = ":"


def pair_label(posture: str, direction: str) -> str:
    return direction if posture == "neutral" else f"{posture}{SEPARATOR}{direction}"


def split_label(label: str) -> tuple[str, str]:
    """(posture, direction) of a test label ('back' -> ('neutral', 'back'))."""
    if SEPARATOR in label:
        p, d = label.split(SEPARATOR, 1)
        return p, d
    return "neutral", label


def posture_full_model(full: FullModel, table: PostureTable, force_length: str = "relative") -> FullModel:
    """The full model in a posture: its moment arms, joint centres/axes and strengths ``f x factor``."""
    if tuple(full.names) != table.names:
        raise ValueError(f"posture {table.name}: muscle names differ from the full model")
    f = full.strengths * table.strength_factor(force_length)
    muscles = full.muscles.copy()
    muscles["strength_N"] = f
    return FullModel(muscles, f, table.moment_arms, table.centres, table.axes,
                     {**dict(full.provenance), "posture": table.name, "force_length": force_length})


def reduce_in_posture(full_q: FullModel, neutral: ReducedModel, table: PostureTable,
                      posture: str) -> ReducedModel:
    """``neutral``'s reduction (joints, task space, grouping S) applied to the posture-q full model; ``J^T`` from
    the posture's skull-frame twists."""
    coords = neutral.coordinates
    rows = [COORDINATES.index(c) for c in coords]
    f_g, R_g = reduce_strengths_and_arms(full_q.moment_arms[rows], full_q.strengths, neutral.S)
    JT = table.JT[rows]
    task = WRENCH_COMPONENTS
    if neutral.planar:
        JT = JT[:, PLANAR_INDEX]
        task = PLANAR_COMPONENTS
    return ReducedModel(f"{neutral.name}@{posture}", neutral.kinematic, neutral.grouping, coords,
                        neutral.muscle_names, f_g, R_g, JT, neutral.S, task)


@dataclass
class PostureSet:
    """The reduced model in each posture, with ``rho`` mapping neutral group strengths to each posture's."""

    neutral: ReducedModel
    models: dict[str, ReducedModel]
    rho: dict[str, np.ndarray]
    force_length: str = "relative"
    cache: object = field(default=None, repr=False)

    @property
    def name(self) -> str:
        return self.neutral.name

    @property
    def postures(self) -> list[str]:
        return list(self.models)

    @property
    def muscle_names(self) -> tuple[str, ...]:
        return self.neutral.muscle_names

    @property
    def m(self) -> int:
        return self.neutral.m

    @property
    def planar(self) -> bool:
        return self.neutral.planar

    @property
    def strengths(self) -> np.ndarray:
        """Baseline (neutral) group strengths: the parameters every estimator works with."""
        return self.neutral.strengths

    @property
    def moment_arms(self) -> np.ndarray:
        """All postures' grouped moment arms side by side (for fingerprints such as Algorithm 4's checkpoint key)."""
        return np.concatenate([self.models[p].moment_arms for p in self.models], axis=0)

    @property
    def JT(self) -> np.ndarray:
        return np.concatenate([self.models[p].JT for p in self.models], axis=0)

    def task_direction(self, u6: np.ndarray) -> np.ndarray:
        return self.neutral.task_direction(u6)

    def wrenches(self, F: np.ndarray, U: np.ndarray, postures: Sequence[str], alpha_lb=None, alpha_ub=None,
                 return_alpha: bool = False, cache=None, n_threads: int = 1):
        """Max wrench of strength vectors ``F`` (N x m, *neutral* group strengths) for the tests (U[k], posture
        postures[k]): one :func:`neckstrength.wrench.solve` call per posture. Returns w (N x K), alpha or None,
        status (N x K)."""
        from neckstrength.wrench.batched import BasisCache

        F = np.atleast_2d(np.asarray(F, float))
        U = np.atleast_2d(np.asarray(U, float))
        postures = list(postures)
        if len(postures) != len(U):
            raise ValueError(f"{len(U)} test directions but {len(postures)} postures")
        unknown = sorted(set(postures) - set(self.models))
        if unknown:
            raise ValueError(f"postures {unknown} not in this model set ({self.postures})")
        if cache is None:
            if self.cache is None:
                self.cache = BasisCache()
            cache = self.cache
        N, K = len(F), len(U)
        w = np.zeros((N, K))
        status = np.zeros((N, K), dtype=np.int64)
        alpha = np.zeros((N, K, self.m)) if return_alpha else None
        pa = np.array(postures)
        for p in dict.fromkeys(postures):
            idx = np.flatnonzero(pa == p)
            lb = None if alpha_lb is None else np.asarray(alpha_lb)[idx]
            ub = None if alpha_ub is None else np.asarray(alpha_ub)[idx]
            wp, ap, sp = solve(self.models[p], F * self.rho[p][None, :], U[idx], lb, ub, return_alpha=return_alpha,
                               cache=cache, n_threads=n_threads)
            w[:, idx] = wp
            status[:, idx] = sp
            if return_alpha:
                alpha[:, idx] = ap
        return w, alpha, status


def build_posture_set(full: FullModel, neutral: ReducedModel, tables: dict[str, PostureTable],
                      postures: Sequence[str] | None = None, force_length: str = "relative") -> PostureSet:
    """Reduced models of ``neutral``'s variant in each posture (neutral itself is ``neutral``, unchanged).

    Planar models take every posture: their pitch rows of ``J^T(q)`` restricted to (Mz, Fx, Fy) give the pitch
    torque demanded by a wrench in the skull's sagittal plane exactly; like the planar model at neutral, they drop
    the roll/yaw equilibrium (docs/postures.md).
    """
    postures = list(tables) if postures is None else list(postures)
    if "neutral" not in postures:
        postures = ["neutral", *postures]
    models: dict[str, ReducedModel] = {}
    rho: dict[str, np.ndarray] = {}
    for p in postures:
        if p not in tables:
            raise ValueError(f"no table for posture {p!r}; have {list(tables)}")
        if p == "neutral":
            models[p] = neutral
            rho[p] = np.ones(neutral.m)
            continue
        fq = posture_full_model(full, tables[p], force_length)
        rq = reduce_in_posture(fq, neutral, tables[p], p)
        with np.errstate(divide="ignore", invalid="ignore"):
            rho[p] = np.where(neutral.strengths > 0, rq.strengths / np.where(neutral.strengths > 0,
                                                                             neutral.strengths, 1.0), 0.0)
        # the posture model is evaluated with strengths x . rho(q); its own strengths are the baseline's
        models[p] = rq
    return PostureSet(neutral, models, rho, force_length)
