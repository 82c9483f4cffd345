"""The joint sequential estimator over (posture, direction) tests, with an optional cost per posture change.

:class:`PostureJointPosterior` is :class:`neckstrength.sequential.joint.JointPosterior` whose "directions" are
test labels (``direction`` for neutral, ``posture:direction`` otherwise, :func:`neckstrength.postures.pair_label`)
and whose candidate wrenches come from the posture models (:meth:`PostureSet.wrenches`). The selection criterion
(``joint_eig`` or ``marginal_entropy``) scores every remaining (posture, direction) pair; with ``change_cost`` > 0
a pair in another posture than the last test's is charged that many nats (``joint_eig``: expected information in
nats; ``marginal_entropy``: mean entropy drop per muscle in nats), so the criterion changes posture only when the
expected gain pays for it.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.postures.model import PostureSet
from neckstrength.sequential.joint import JointPosterior, JointSettings
from neckstrength.wrench import solve
from neckstrength.wrench.problem import STATUS_CODES

_OPT = {v: k for k, v in STATUS_CODES.items()}["optimal"]


class PostureWrenches:
    """The candidate wrenches of a :class:`~neckstrength.sequential.joint.JointPosterior` whose tests are in several
    postures: test ``k`` in posture ``test_postures[k]`` of the :class:`PostureSet` ``pset`` (neutral group
    strengths mapped to each posture's model). Mixed in before the posterior class, which sets ``pset`` and
    ``test_postures``: :class:`PostureJointPosterior` and the deficit decision's
    :class:`~neckstrength.sequential.decision.PostureHypothesisPosterior`."""

    pset: PostureSet
    test_postures: list[str]

    def _solve_all(self, F: np.ndarray, cols: np.ndarray | None = None):
        cols = np.arange(len(self.U)) if cols is None else np.asarray(cols, int)
        w, _, st = self.pset.wrenches(F, self.U[cols], [self.test_postures[i] for i in cols], cache=self.cache,
                                      n_threads=self.n_threads)
        return w, st

    def _bounded(self, F: np.ndarray, i: int, bounds) -> np.ndarray:
        lb, ub = bounds
        p = self.test_postures[i]
        w, _, st = solve(self.pset.models[p], F * self.pset.rho[p][None, :], self.U[i:i + 1], np.asarray(lb)[None],
                         np.asarray(ub)[None], return_alpha=False, cache=self.bounded_cache,
                         n_threads=self.n_threads)
        self.n_lps += w.size
        return np.where(st[:, 0] == _OPT, w[:, 0], 0.0)


class PostureJointPosterior(PostureWrenches, JointPosterior):
    """Joint posterior over neutral group strengths, tests in several postures (``postures[k]`` of test k)."""

    def __init__(self, pset: PostureSet, labels: Sequence[str], U: np.ndarray, force_scale: np.ndarray,
                 postures: Sequence[str], f0: np.ndarray, settings: JointSettings, rng: np.random.Generator,
                 change_cost: float = 0.0, start_posture: str = "neutral", **kw):
        if len(postures) != len(labels):
            raise ValueError("one posture per test label")
        if change_cost < 0:
            raise ValueError("change_cost must be >= 0")
        self.pset = pset
        self.test_postures = list(postures)
        self.change_cost = float(change_cost)
        self.start_posture = start_posture
        super().__init__(pset.neutral, labels, U, force_scale, f0, settings, rng, **kw)

    @property
    def current_posture(self) -> str:
        """The posture of the last test (``start_posture`` before any): derived from ``tests``, so restoring the
        tests (an undo) restores it too."""
        return self.test_postures[self.tests[-1]["i"]] if self.tests else self.start_posture

    def propose(self, criterion: str, rng: np.random.Generator) -> tuple[str, pd.DataFrame]:
        """As :meth:`JointPosterior.propose`, with columns ``posture``, ``gain`` (the criterion) and ``score`` =
        gain - change_cost x [posture differs from the last test's]."""
        choice, df = super().propose(criterion, rng)
        post = [self.test_postures[self.directions.index(d)] for d in df["direction"]]
        df.insert(1, "posture", post)
        df["gain"] = df["score"]
        change = np.array([p != self.current_posture for p in post])
        df["posture_change"] = change
        if criterion != "random" and self.change_cost > 0:
            df["score"] = df["gain"] - self.change_cost * change
            choice = df["direction"].iloc[int(np.argmax(df["score"].to_numpy()))]
        return choice, df
