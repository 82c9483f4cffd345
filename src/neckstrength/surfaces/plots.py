"""Chapter 4 figures: per-muscle activation radars and stacked activation-share bars."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from neckstrength.plotting import _save


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
