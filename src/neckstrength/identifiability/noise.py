"""The noise level below which a deficit is distinguishable from normal (issue 31 item 1.3).

With ``n`` tests whose log forces carry independent Gaussian noise of sd ``sigma``, the log-likelihood ratio of the
truth against the best-fitting 'normal' hypothesis (the group at 1 x normal, every other group free in its bounds)
is, for data at the truth's expected forces, about

    LR = n x RMS^2 / sigma^2

with ``RMS`` the profile's best RMS log residual at r = 1 (the noise-free misfit of 'normal'). The deficit is
distinguishable at the 95% level when LR >= 3.84 (chi-square, 1 degree of freedom), i.e. when

    sigma <= sigma* = RMS x sqrt(n / 3.84).

This is a heuristic (not checked by simulation here): it takes the expected data (no noise realisation), one degree
of freedom, and the profile's RMS as the true minimum (it is an upper bound from finite starts, so sigma* is too).
"""

from __future__ import annotations

import numpy as np

#: chi-square(1) 95% quantile
CHI2_1_95 = 3.841458820694124

RULE = "sigma* = RMS(r=1) x sqrt(n / 3.84): LR = n RMS^2 / sigma^2 >= 3.84 (chi-square 1 dof, 95%; heuristic)"


def lr_statistic(rms: float, n: int, sigma: float) -> float:
    """Likelihood-ratio statistic ``n RMS^2 / sigma^2`` of 'normal' vs the truth."""
    if sigma <= 0 or n < 1 or rms < 0:
        raise ValueError(f"need sigma > 0, n >= 1, rms >= 0; got sigma={sigma}, n={n}, rms={rms}")
    return n * rms ** 2 / sigma ** 2


def sigma_star(rms, n, threshold: float = CHI2_1_95):
    """Largest log-noise sd at which LR >= ``threshold``: ``RMS x sqrt(n / threshold)`` (array-friendly)."""
    rms = np.asarray(rms, float)
    n = np.asarray(n, float)
    if np.any(rms < 0) or np.any(n < 1):
        raise ValueError("need rms >= 0 and n >= 1")
    return rms * np.sqrt(n / threshold)
