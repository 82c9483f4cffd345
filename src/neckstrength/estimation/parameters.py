"""Free parameters of an estimate: one per muscle group, or one per left/right pair when sides are tied."""

from __future__ import annotations

import numpy as np

from neckstrength.model.reduction import ReducedModel


def free_parameters(model: ReducedModel, tie_sides: bool) -> tuple[np.ndarray, list[str]]:
    """Map muscles -> free parameters. Returns ``index`` (m,) and parameter names."""
    names = list(model.muscle_names)
    if not tie_sides:
        return np.arange(len(names)), names
    params: list[str] = []
    idx = np.zeros(len(names), dtype=int)
    for j, n in enumerate(names):
        base = n[:-2] if n.endswith(("-R", "-L")) else n
        if base not in params:
            params.append(base)
        idx[j] = params.index(base)
    return idx, params
