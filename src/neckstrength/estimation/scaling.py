"""Bootstrap scaling of the baseline strengths (thesis Eq. 5.3)."""

from __future__ import annotations

import numpy as np

from neckstrength.estimation.datasets import Dataset
from neckstrength.model.reduction import ReducedModel
from neckstrength.wrench import solve
from neckstrength.wrench.highs import max_wrench
from neckstrength.wrench.problem import STATUS_CODES


def bootstrap_prior(model: ReducedModel, data: Dataset, direction: str) -> tuple[np.ndarray, float]:
    """Eq. 5.3: ``f_0 = a f'_base`` with ``a`` matching the measured wrench in ``direction``.

    The max wrench is positively homogeneous in the strengths, so ``a = w_meas / M(f'_base, u)``.
    Activation bounds of that direction are not applied (Algorithm 3 step 3 uses M(a f, u)).
    """
    k = data.directions.index(direction)
    w, _, status = solve(model, model.strengths[None, :], data.U[k:k + 1])
    if STATUS_CODES[int(status[0, 0])] != "optimal":
        raise ValueError(f"model {model.name} cannot produce the bootstrap direction '{direction}'")
    a = float(data.w_meas[k] / w[0, 0])
    return a * model.strengths, a


def bootstrap_scale(model: ReducedModel, f_base: np.ndarray, u: np.ndarray, w_meas: float) -> float:
    """Scalar ``a`` of Eq. 5.3: ``argmin_a |w_meas - M(a f_base, u)|`` with ``a >= 0``.

    ``M`` is positively homogeneous in ``f`` (scaling all strengths scales the
    feasible set), so ``a = w_meas / M(f_base, u)`` exactly; no search needed.
    """
    r = max_wrench(model.moment_arms, model.JT, f_base, u)
    if not r.producible:
        raise ValueError(f"model {model.name} cannot produce the bootstrap direction (status {r.status})")
    return float(w_meas / r.w)
