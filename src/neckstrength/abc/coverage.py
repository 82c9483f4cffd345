"""Coverage check of Algorithm 4's reported spread (beyond the thesis)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from neckstrength.abc.algorithm4 import ABCSettings, estimate_strengths
from neckstrength.model.reduction import ReducedModel


def coverage_check(model: ReducedModel, make_data, f_true: np.ndarray, settings: ABCSettings, f0_fn,
                   n_rep: int, noise: float, rng: np.random.Generator) -> pd.DataFrame:
    """Repeat Algorithm 4 on noisy simulated data; per muscle: does f_c (1 +- sigma_c) cover the truth?

    ``make_data(noise_factors)`` returns a :class:`Dataset` whose measured wrenches are multiplied by the
    given factors; ``f0_fn(data)`` returns the prior point estimate (Eq. 5.3).
    """
    rows = []
    for r in range(n_rep):
        data = make_data(np.exp(noise * rng.standard_normal(len(make_data(None).directions))))
        f0 = f0_fn(data)
        res = estimate_strengths(model, data, settings, f0, progress=None)
        from neckstrength.estimation.parameters import free_parameters
        pidx, pnames = free_parameters(model, settings.tie_sides)
        for k, p in enumerate(pnames):
            truth = float(np.mean(f_true[pidx == k]))
            lo, hi = res.f_c[k] * (1 - res.sigma_c[k]), res.f_c[k] * (1 + res.sigma_c[k])
            rows.append({"replicate": r, "parameter": p, "truth": truth, "f_c": res.f_c[k], "sigma_c": res.sigma_c[k],
                         "lower": lo, "upper": hi, "covered": bool(lo <= truth <= hi), "D_fc": res.D_fc,
                         "iterations": res.iterations})
    return pd.DataFrame(rows)
