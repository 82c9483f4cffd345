"""Shared plot helpers: the radar grid of the test directions by plane (Figs. A.4, 5.x, 6.x, gap) and saving.

Matplotlib with the non-interactive Agg backend (no display needed). Topic figures live in each subpackage's
``plots.py`` (``abc.plots``, ``surfaces.plots``, ``sequential.plots``, ``mfi.plots``) and ``gap.report``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import matplotlib
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from neckstrength.model.geometry import PLANE_GRID, plane_angle

matplotlib.use("Agg")


PLANE_TITLES = {
    "sagittal_right": "right sagittal", "sagittal_mid": "mid sagittal", "sagittal_left": "left sagittal",
    "transverse_superior": "superior transverse", "transverse_mid": "mid transverse",
    "transverse_inferior": "inferior transverse", "coronal_anterior": "anterior coronal",
    "coronal_mid": "mid coronal", "coronal_posterior": "posterior coronal",
}


def radar_grid(directions: pd.DataFrame, dashed: Mapping[str, pd.Series], solid: Mapping[str, pd.Series],
               out: str | Path, title: str = "", rmax: float | None = None) -> None:
    """3x3 grid of radar plots (Fig. 4.2 layout): dashed traces (e.g. participants) and solid red traces."""
    series = [(k, v, {"ls": "--", "lw": 1}) for k, v in dashed.items()]
    series += [(k, v, {"ls": "-", "lw": 2, "color": "red"}) for k, v in solid.items()]
    radar_grid_series(directions, series, out, title, rmax)


def radar_grid_series(directions: pd.DataFrame, series: Sequence[tuple[str, pd.Series, dict]], out: str | Path,
                      title: str = "", rmax: float | None = None, rlabel: str = "") -> None:
    """3x3 grid of radar plots, one polar axis per plane of Fig. 4.2.

    ``series``: (label, values indexed by direction name, matplotlib kwargs). Directions are placed at
    their polar angle within each plane (sagittal: x right / y up; transverse: x right / z up;
    coronal: z right / y up).
    """
    fig, axes = plt.subplots(3, 3, figsize=(12, 12), subplot_kw={"projection": "polar"})
    allvals = [np.nanmax(s.to_numpy(float)) for _, s, _ in series if len(s)]
    rmax = rmax or (1.1 * max(allvals) if allvals and max(allvals) > 0 else 1.0)
    recs = directions.to_dict("records")
    for r_i, row in enumerate(PLANE_GRID):
        for c_i, plane in enumerate(row):
            ax = axes[r_i, c_i]
            members = [r for r in recs if plane in str(r["planes"]).split(";")]
            members.sort(key=lambda r: np.mod(plane_angle(r, plane), 2 * np.pi))
            names = [r["name"] for r in members]
            ax.set_title(PLANE_TITLES[plane], fontsize=10, pad=14)
            if not names:
                continue
            th = np.mod(np.array([plane_angle(r, plane) for r in members]), 2 * np.pi)
            closed = np.r_[th, th[:1]]
            for label, s, kw in series:
                vals = np.array([s.get(n, np.nan) for n in names], float)
                ax.plot(closed, np.r_[vals, vals[:1]], label=label if (r_i, c_i) == (0, 0) else None, **kw)
            ax.set_xticks(th)
            ax.set_xticklabels(names, fontsize=7)
            ax.set_xlim(0, 2 * np.pi)
            ax.set_ylim(0, rmax)
            ax.set_rlabel_position(250)
            ax.tick_params(axis="y", labelsize=6)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(max(len(labels), 1), 6), fontsize=8)
    if title:
        fig.suptitle(title + (f" [{rlabel}]" if rlabel else ""))
    fig.tight_layout(rect=(0, 0.04, 1, 0.97))
    _save(fig, out)


def _save(fig, out):
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def heatmap(table: pd.DataFrame, out: str | Path, title: str, cbar_label: str) -> None:
    """Muscles x directions heat map with a diverging colour map centred at 0 (Fig. 4.5)."""
    v = np.nanmax(np.abs(table.to_numpy(float))) or 1.0
    fig, ax = plt.subplots(figsize=(13, 8))
    im = ax.imshow(table.to_numpy(float), cmap="RdBu_r", vmin=-v, vmax=v, aspect="auto")
    ax.set_xticks(range(table.shape[1]))
    ax.set_xticklabels(table.columns, rotation=75, fontsize=8)
    ax.set_yticks(range(table.shape[0]))
    ax.set_yticklabels(table.index, fontsize=8)
    fig.colorbar(im, ax=ax, label=cbar_label)
    ax.set_title(title)
    fig.tight_layout()
    _save(fig, out)
