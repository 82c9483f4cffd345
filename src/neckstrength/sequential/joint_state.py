"""The joint posterior one measurement at a time, with undo: what the clinician session needs (issue 18 item 4).

:class:`JointState` wraps :class:`~neckstrength.sequential.joint.JointPosterior` with the interface the session
uses for the thesis's scheme (:class:`~neckstrength.sequential.SequentialState`): ``likelihood`` checks a
measurement without changing anything, ``push`` applies it, ``undo`` removes the last one (the candidates, weights
and random state saved before each update are restored, so undo-then-measure gives the same numbers as a replay of
the remaining measurements), ``propose`` scores the remaining directions by ``joint_eig`` (expected information
gain about the joint strength vector) or ``marginal_entropy`` (Eq. 6.7 on the joint posterior), ``estimate`` the
posterior mean / sd / marginal entropy. ``history`` keeps the estimate and P(deficit) after every step.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.model.reduction import ReducedModel
from neckstrength.sequential.algorithms import activation_bounds
from neckstrength.sequential.deficit import DeficitDefinition
from neckstrength.sequential.joint import JointPosterior, JointSettings

JOINT_CRITERIA = ("joint_eig", "marginal_entropy")


@dataclass
class JointProposal:
    """Scores of the remaining directions on the joint posterior (``dS`` per muscle for ``marginal_entropy``)."""

    directions: list[str]
    muscles: list[str]
    score: np.ndarray
    choice: str
    criterion: str
    dS: np.ndarray | None = None

    def table(self) -> pd.DataFrame:
        df = pd.DataFrame({"direction": self.directions})
        if self.dS is not None:
            for j, m in enumerate(self.muscles):
                df[m] = self.dS[:, j]
        df["score"] = self.score
        df["selected"] = df["direction"] == self.choice
        return df


@dataclass
class _Pending:
    direction: str
    force: float
    activations: object


class JointState:
    """One session's joint posterior with undo (see the module docstring)."""

    def __init__(self, model: ReducedModel, directions: Sequence[str], U: np.ndarray, force_scale: np.ndarray,
                 f0: np.ndarray, settings: JointSettings, rng: np.random.Generator, criterion: str = "joint_eig",
                 deficit: DeficitDefinition | None = None, cache=None, posterior: JointPosterior | None = None,
                 key_extra: str = "", n_threads: int = 1):
        if criterion not in JOINT_CRITERIA:
            raise ValueError(f"criterion {criterion!r} is not one of the joint posterior's: {JOINT_CRITERIA}")
        self.model = model
        self.criterion = criterion
        self.force_scale = np.asarray(force_scale, float)
        # ``posterior``: a ready JointPosterior over the same tests (e.g. the posture one, issue 20)
        # ``n_threads``: directions solved concurrently (the same numbers for any value)
        self.post = (JointPosterior(model, directions, U, force_scale, f0, settings, rng, cache=cache,
                                    n_threads=n_threads) if posterior is None else posterior)
        self.deficit = deficit if deficit is not None and deficit.applies(model.muscle_names) else None
        self.key = hashlib.sha256(np.ascontiguousarray(self.post.F).tobytes()
                                  + np.ascontiguousarray(U, float).tobytes()
                                  + key_extra.encode()).hexdigest()[:16]
        self._snaps: list[dict] = []
        self.history: list[dict] = [self._summary(None)]

    # -- state
    @property
    def tested(self) -> list[str]:
        return self.post.tested

    @property
    def remaining(self) -> list[str]:
        return self.post.remaining

    @property
    def steps(self) -> list[dict]:
        return self.post.tests

    def p_deficit(self) -> float:
        if self.deficit is None:
            return float("nan")
        return self.deficit.probability(self.post.F, self.post.weights(), self.post.f0, self.model.muscle_names)

    def p_deficit_se(self) -> float:
        """Monte Carlo standard error of :meth:`p_deficit` (:meth:`JointPosterior.mc_se`; not a posterior width)."""
        if self.deficit is None:
            return float("nan")
        below = self.deficit.ratio(self.post.F, self.post.f0, self.model.muscle_names) < self.deficit.threshold
        return self.post.mc_se(below)

    def estimate(self) -> pd.DataFrame:
        return self.post.estimate()

    def _summary(self, p: _Pending | None) -> dict:
        return {"direction": "" if p is None else p.direction, "force": np.nan if p is None else p.force,
                "estimate": self.estimate(), "p_deficit": self.p_deficit(),
                "p_deficit_se": self.p_deficit_se(), "mc_clusters": self.post.mc_clusters()}

    # -- updates
    def likelihood(self, direction: str, force: float, activations=None) -> _Pending:
        """Check a measurement (known, untested direction; positive force; valid activations); changes nothing."""
        if direction not in self.post.directions:
            raise ValueError(f"unknown direction {direction!r}; known: {self.post.directions}")
        if direction in self.tested:
            raise ValueError(f"direction {direction!r} has already been tested (each direction is tested once)")
        if not np.isfinite(force) or force <= 0:
            raise ValueError(f"measured force must be positive, got {force!r}")
        activation_bounds(activations, self.model.muscle_names, self.post.settings.emg_band)
        return _Pending(direction, float(force), activations)

    def push(self, p: _Pending) -> None:
        self._snaps.append(self.post.snapshot())
        try:
            self.post.update(p.direction, p.force, p.activations)
        except Exception:
            self.post.restore(self._snaps.pop())
            raise
        self.history.append(self._summary(p))

    def undo(self) -> None:
        if not self._snaps:
            raise ValueError("nothing to undo")
        self.post.restore(self._snaps.pop())
        self.history.pop()

    # -- proposals
    def propose(self, rng: np.random.Generator, gamma: np.ndarray | None = None) -> JointProposal:
        """Scores of every remaining direction (``gamma`` weighs the muscles of ``marginal_entropy``, Eq. 6.8)."""
        if gamma is not None and self.criterion != "marginal_entropy":
            raise ValueError("muscle priorities (Eq. 6.8) apply to the marginal-entropy criteria, not to joint_eig")
        _, df = self.post.propose(self.criterion, rng)
        muscles = list(self.model.muscle_names)
        dS = df[muscles].to_numpy(float) if self.criterion == "marginal_entropy" else None
        score = df["score"].to_numpy(float)
        if dS is not None and gamma is not None:
            charge = (df["gain"] - df["score"]).to_numpy(float) if "gain" in df.columns else 0.0   # posture change
            score = (dS * np.asarray(gamma, float)).sum(axis=1) / len(muscles) - charge
        dirs = list(df["direction"])
        return JointProposal(dirs, muscles, score, dirs[int(np.argmax(score))], self.criterion, dS)
