"""Figures. Matplotlib with the non-interactive Agg backend (no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

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


def muscle_radars(directions: Sequence[str], traces: Sequence[tuple[str, pd.DataFrame, dict]], out: str | Path,
                  title: str) -> None:
    """One radar per direction, axes = muscles (Fig. 4.6). ``traces``: (label, muscles x directions, kwargs)."""
    n = len(directions)
    ncol = min(n, 4)
    nrow = int(np.ceil(n / ncol)) if n else 1
    fig, axes = plt.subplots(nrow, ncol, figsize=(4 * ncol, 4 * nrow), subplot_kw={"projection": "polar"},
                             squeeze=False)
    for k, dname in enumerate(directions):
        ax = axes[k // ncol, k % ncol]
        muscles = list(traces[0][1].index)
        th = np.linspace(0, 2 * np.pi, len(muscles), endpoint=False)
        for label, tab, kw in traces:
            vals = tab[dname].to_numpy(float)
            ax.plot(np.r_[th, th[:1]], np.r_[vals, vals[:1]], label=label if k == 0 else None, **kw)
        ax.set_xticks(th)
        ax.set_xticklabels(muscles, fontsize=6)
        ax.set_ylim(0, 1)
        ax.set_title(dname, fontsize=9, pad=12)
        ax.tick_params(axis="y", labelsize=6)
    for k in range(n, nrow * ncol):
        axes[k // ncol, k % ncol].axis("off")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels))
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.05, 1, 0.95))
    _save(fig, out)


def stacked_share_bars(panels: Sequence[tuple[str, Sequence[str], pd.DataFrame, pd.DataFrame]], out: str | Path,
                       title: str) -> None:
    """Grouped bars per direction for several variants (Figs. 4.7/4.8).

    ``panels``: (panel title, variant names, strength at 1x [directions x variants], strength at 0x). The
    light part of each bar is the strength without deep extensors, the dark part their added contribution.
    """
    fig, axes = plt.subplots(len(panels), 1, figsize=(16, 4.5 * len(panels)), squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for p_i, (ptitle, variants, s1, s0) in enumerate(panels):
        ax = axes[p_i, 0]
        dirs = list(s1.index)
        x = np.arange(len(dirs))
        width = 0.8 / max(len(variants), 1)
        for k, v in enumerate(variants):
            base = np.minimum(s0[v].to_numpy(float), s1[v].to_numpy(float))
            extra = np.clip(s1[v].to_numpy(float) - base, 0, None)
            xs = x - 0.4 + width * (k + 0.5)
            ax.bar(xs, base, width, color=colors[k % len(colors)], alpha=0.45, label=f"{v} (0x deep ext.)")
            ax.bar(xs, extra, width, bottom=base, color=colors[k % len(colors)], alpha=1.0,
                   label=f"{v}: deep-extensor share")
        ax.set_xticks(x)
        ax.set_xticklabels(dirs, rotation=60, fontsize=8)
        ax.set_ylabel("max force (N)")
        ax.set_title(ptitle)
        ax.legend(fontsize=7, ncol=2)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    _save(fig, out)


# --------------------------------------------------------------------------- Chapter 5

def abc_traces(history: pd.DataFrame, truth: pd.Series, base: pd.Series, out: str | Path, title: str) -> None:
    """Per-parameter estimate traces (Figs. 5.7 / 5.8 / 5.11 / 5.13)."""
    params = list(dict.fromkeys(history["parameter"]))
    ncol = 4 if len(params) > 8 else min(len(params), 4)
    nrow = int(np.ceil(len(params) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 2.6 * nrow), squeeze=False)
    for k, p in enumerate(params):
        ax = axes[k // ncol, k % ncol]
        h = history[history["parameter"] == p]
        ax.plot(h["iteration"], h["f_c"], "k-", lw=1.5)
        ax.plot(h["iteration"], h["f_low"], "b--", lw=0.8)
        ax.plot(h["iteration"], h["f_high"], "b--", lw=0.8)
        t = truth.get(p, np.nan)
        if np.isfinite(t):
            ax.axhline(t, color="red", ls="--", lw=1)
        b = base.get(p, np.nan)
        if np.isfinite(b):
            ax.plot([0], [b], "kx")
        ax.set_title(p, fontsize=9)
        ax.tick_params(labelsize=7)
    for k in range(len(params), nrow * ncol):
        axes[k // ncol, k % ncol].axis("off")
    fig.suptitle(title, fontsize=10)
    fig.supxlabel("iteration")
    fig.supylabel("strength (N)")
    fig.tight_layout()
    _save(fig, out)


def dk_histograms(dk_hist: pd.DataFrame, out: str | Path, title: str) -> None:
    """Histogram of composite scores D_k for every iteration (Figs. 5.5 / 5.12a / 5.14a), one row each."""
    its = sorted(dk_hist["iteration"].unique())
    fig, axes = plt.subplots(len(its), 1, figsize=(7, 0.9 * len(its) + 1.2), sharex=True, squeeze=False)
    for k, it in enumerate(its):
        h = dk_hist[dk_hist["iteration"] == it]
        ax = axes[k, 0]
        ax.bar(h["bin_low"], h["count"], width=h["bin_high"] - h["bin_low"], align="edge", color="C0")
        ax.set_ylabel(f"{it}", rotation=0, labelpad=12, fontsize=8)
        ax.set_yticks([])
        ax.axvline(0.95, color="red", lw=0.8, ls=":")
    axes[-1, 0].set_xlabel("D_k (red: convergence cut-off 0.95)")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    _save(fig, out)


def d_by_direction_plot(dd: pd.DataFrame, out: str | Path, title: str) -> None:
    """Distribution of d_ik over candidates per direction at the last iteration (Figs. 5.12b / 5.14b)."""
    fig, ax = plt.subplots(figsize=(max(6, 0.45 * len(dd) + 2), 4))
    x = np.arange(len(dd))
    ax.vlines(x, dd["d_q05"], dd["d_q95"], color="grey", lw=1)
    ax.vlines(x, dd["d_q25"], dd["d_q75"], color="C0", lw=5)
    ax.plot(x, dd["d_median"], "k_", ms=10)
    ax.set_xticks(x)
    ax.set_xticklabels(dd["direction"], rotation=70, fontsize=8)
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("d_ik (5-95%, 25-75%, median)")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    _save(fig, out)


def parallel_coordinates(cand: pd.DataFrame, truth: pd.Series, out: str | Path, title: str,
                         iterations: Sequence[int] = (1, 5)) -> None:
    """Parallel-coordinate plots of candidates coloured by D_k percentile (Fig. 5.3)."""
    its = [i for i in iterations if i in set(cand["iteration"])] or [int(cand["iteration"].max())]
    params = [c for c in cand.columns if c not in ("iteration", "D_k", "percentile")]
    fig, axes = plt.subplots(1, len(its), figsize=(6 * len(its), 4.5), squeeze=False)
    cmap = plt.get_cmap("viridis")
    for k, it in enumerate(its):
        ax = axes[0, k]
        c = cand[cand["iteration"] == it].sort_values("percentile")
        x = np.arange(len(params))
        for vals, pct in zip(c[params].to_numpy(float), c["percentile"].to_numpy(float)):
            ax.plot(x, vals, color=cmap(pct / 100.0), lw=0.4, alpha=0.5)
        t = [truth.get(p, np.nan) for p in params]
        ax.plot(x, t, "o", mfc="none", mec="red", ms=8, label="truth")
        ax.set_xticks(x)
        ax.set_xticklabels(params, rotation=60, fontsize=7)
        ax.set_title(f"iteration {it}")
        ax.set_ylabel("strength (N)")
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, 100))
    fig.colorbar(sm, ax=axes[0, -1], label="D_k percentile")
    fig.suptitle(title, fontsize=10)
    _save(fig, out)
