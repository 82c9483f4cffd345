"""Figures. Matplotlib with the non-interactive Agg backend (no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from .geometry import PLANE_GRID, plane_angle  # noqa: E402

PLANE_TITLES = {
    "sagittal_right": "right sagittal", "sagittal_mid": "mid sagittal", "sagittal_left": "left sagittal",
    "transverse_superior": "superior transverse", "transverse_mid": "mid transverse",
    "transverse_inferior": "inferior transverse", "coronal_anterior": "anterior coronal",
    "coronal_mid": "mid coronal", "coronal_posterior": "posterior coronal",
}


def radar_grid(directions: pd.DataFrame, dashed: Mapping[str, pd.Series], solid: Mapping[str, pd.Series],
               out: str | Path, title: str = "", rmax: float | None = None) -> None:
    """3x3 grid of radar plots (Fig. 4.2 layout): one polar axis per plane.

    ``dashed`` / ``solid``: named series indexed by direction name (e.g. the
    participants' measurements and the model prediction). Directions are placed
    at their polar angle within each plane.
    """
    fig, axes = plt.subplots(3, 3, figsize=(12, 12), subplot_kw={"projection": "polar"})
    allvals = [s.max() for s in list(dashed.values()) + list(solid.values()) if len(s)]
    rmax = rmax or (1.1 * max(allvals) if allvals else 1.0)
    recs = directions.to_dict("records")
    for r_i, row in enumerate(PLANE_GRID):
        for c_i, plane in enumerate(row):
            ax = axes[r_i, c_i]
            members = [r for r in recs if plane in str(r["planes"]).split(";")]
            members.sort(key=lambda r: np.mod(plane_angle(r, plane), 2 * np.pi))
            names = [r["name"] for r in members]
            th = np.mod(np.array([plane_angle(r, plane) for r in members]), 2 * np.pi)
            if len(names) == 0:
                ax.set_title(PLANE_TITLES[plane])
                continue
            closed = np.r_[th, th[:1]]
            for k, (label, s) in enumerate(dashed.items()):
                vals = np.array([s.get(n, np.nan) for n in names], float)
                ax.plot(closed, np.r_[vals, vals[:1]], "--", lw=1, label=label if (r_i, c_i) == (0, 0) else None)
            for label, s in solid.items():
                vals = np.array([s.get(n, np.nan) for n in names], float)
                ax.plot(closed, np.r_[vals, vals[:1]], "-", color="red", lw=2,
                        label=label if (r_i, c_i) == (0, 0) else None)
            ax.set_xticks(th)
            ax.set_xticklabels(names, fontsize=7)
            ax.set_xlim(0, 2 * np.pi)
            ax.set_ylim(0, rmax)
            ax.set_rlabel_position(250)
            ax.tick_params(axis="y", labelsize=6)
            ax.set_title(PLANE_TITLES[plane], fontsize=10, pad=14)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 6), fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.04, 1, 0.97))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
