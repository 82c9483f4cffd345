"""Data discrepancy of simulated vs measured wrenches (thesis Eq. 5.5-5.6)."""

from __future__ import annotations

import numpy as np


def data_discrepancy(w_sim: np.ndarray, w_meas: np.ndarray, epsilon: float) -> np.ndarray:
    """Eq. 5.5: ``d = exp(-(eps * |w_sim - w_meas| / w_meas)^2)``, broadcast over candidates."""
    delta = np.abs((w_sim - w_meas) / w_meas)
    return np.exp(-(epsilon * delta) ** 2)


def composite_score(d: np.ndarray) -> np.ndarray:
    """Eq. 5.6: mean of the per-direction scores."""
    return d.mean(axis=-1)
