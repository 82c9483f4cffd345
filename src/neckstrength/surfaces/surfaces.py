"""Chapter 4: strength surfaces across kinematic and muscle complexities.

For a model variant (kinematic x muscle grouping) and a set of deep-extensor
strength factors, the maximum force in every test direction and the activation
pattern (thesis Sec. 4.2-4.3). Deep extensors (Table B.2 group 'mf': semispinalis
cervicis and the multifidus slips) are scaled in the full model before reduction,
so every grouping sees the same physical change.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.model.full import FullModel, _key
from neckstrength.model.reduction import read_grouping, reduce_model, scale_strengths
from neckstrength.wrench import solve
from neckstrength.wrench.problem import STATUS_CODES

WRENCH = ("Mx", "My", "Mz", "Fx", "Fy", "Fz")


def deep_extensor_mask(full: FullModel, thesis_dir: str | Path, group: str = "mf") -> np.ndarray:
    """Boolean mask (96) of the muscles in Table B.2's ``group`` (both sides)."""
    table = read_grouping(Path(thesis_dir) / "table_B2_groups_s3m24.csv")
    members = {_key(m) for m, g in zip(table["name_normalized"], table["group"]) if g == group}
    if not members:
        raise ValueError(f"Table B.2 has no group {group!r}")
    mask = np.array([_key(b) in members for b in full.muscles["base"]])
    return mask


@dataclass
class Surface:
    """Strength and activation of one variant over directions x strength factors."""

    strength: pd.DataFrame     # direction, factor, wrench, force_N, status
    activation: pd.DataFrame   # direction, factor, muscle, alpha


def strength_surface(full: FullModel, kinematic: str, grouping: str, directions: pd.DataFrame,
                     factors: Sequence[float], mask: np.ndarray, thesis_dir: str | Path,
                     signature_tol: float = 1e-3) -> Surface:
    """Max force and activations of variant ``kinematic-grouping`` for each deep-extensor factor."""
    srows, arows = [], []
    for fac in factors:
        model = reduce_model(scale_strengths(full, mask, float(fac)), kinematic, grouping, thesis_dir,
                             signature_tol=signature_tol)
        d = directions[directions["sagittal"]] if model.planar else directions
        U = model.task_direction(d[[f"u_{c}" for c in WRENCH]].to_numpy(float))
        w, alpha, status = solve(model, model.strengths[None, :], U)
        scale = d["force_scale"].to_numpy(float)
        for k, name in enumerate(d["name"]):
            srows.append({"direction": name, "factor": float(fac), "wrench": w[0, k], "force_N": w[0, k] / scale[k],
                          "status": STATUS_CODES[int(status[0, k])]})
            for j, mname in enumerate(model.muscle_names):
                arows.append({"direction": name, "factor": float(fac), "muscle": mname, "alpha": alpha[0, k, j]})
    return Surface(pd.DataFrame(srows), pd.DataFrame(arows))


def activation_slopes(activation: pd.DataFrame, mf_strength_per_factor: dict[float, float]) -> pd.DataFrame:
    """Slope of each muscle's activation regressed on bilateral deep-extensor strength (Fig. 4.5).

    Returns a muscles x directions table of least-squares slopes (activation per N of bilateral
    deep-extensor strength, i.e. the summed strength of the scaled muscles).
    """
    a = activation.copy()
    a["x"] = a["factor"].map(mf_strength_per_factor)
    out = {}
    for (m, d), g in a.groupby(["muscle", "direction"], sort=False):
        x = g["x"].to_numpy(float)
        y = np.nan_to_num(g["alpha"].to_numpy(float))
        xc = x - x.mean()
        out[(m, d)] = float((xc * (y - y.mean())).sum() / (xc ** 2).sum()) if (xc ** 2).sum() > 0 else np.nan
    s = pd.Series(out)
    s.index = pd.MultiIndex.from_tuples(s.index, names=["muscle", "direction"])
    muscles = list(dict.fromkeys(activation["muscle"]))
    dirs = list(dict.fromkeys(activation["direction"]))
    return s.unstack("direction").loc[muscles, dirs]
