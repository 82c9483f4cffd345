"""Calibration figures: SBC rank (PIT) histograms per muscle group and interval coverage per method."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from neckstrength.calibration.sbc import LEVELS, method_label
from neckstrength.plotting import _save


def _labels(df: pd.DataFrame) -> pd.Series:
    return pd.Series([method_label(m, t) for m, t in zip(df["method"], df["t"])], index=df.index)


def rank_histograms(df: pd.DataFrame, out: str | Path, title: str, n_bins: int = 10) -> None:
    """Rows: method (and t); columns: muscle groups (both sides pooled). Dashed: the uniform count; grey band: its
    central 99% binomial range."""
    from scipy.stats import binom

    df = df.assign(label=_labels(df))
    labels = list(dict.fromkeys(df["label"]))
    groups = list(dict.fromkeys(df["group"]))
    fig, axes = plt.subplots(len(labels), len(groups), figsize=(1.7 * len(groups) + 1, 1.5 * len(labels) + 1),
                             squeeze=False, sharex=True)
    edges = np.linspace(0, 1, n_bins + 1)
    for r, lab in enumerate(labels):
        for c, g in enumerate(groups):
            ax = axes[r, c]
            u = df[(df["label"] == lab) & (df["group"] == g)]["pit"].to_numpy(float)
            ax.hist(u, bins=edges, color="C0")
            n = len(u)
            lo, hi = binom.ppf([0.005, 0.995], n, 1 / n_bins)
            ax.axhspan(lo, hi, color="0.85", zorder=0)
            ax.axhline(n / n_bins, color="k", ls="--", lw=0.8)
            ax.set_yticks([])
            if r == 0:
                ax.set_title(g, fontsize=8)
            if c == 0:
                ax.set_ylabel(lab, fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    _save(fig, out)


def coverage_plot(df: pd.DataFrame, out: str | Path, title: str) -> None:
    """Coverage of the 50% and 90% intervals per method (all muscles pooled, +-2 binomial s.e.), nominal dashed;
    the 85-95% target band shaded."""
    df = df.assign(label=_labels(df))
    labels = list(dict.fromkeys(df["label"]))
    fig, ax = plt.subplots(figsize=(1.2 * len(labels) + 3, 3.5))
    x = np.arange(len(labels))
    for k, L in enumerate(LEVELS):
        col = f"covered{int(round(100 * L))}"
        c = np.array([df[df["label"] == lab][col].mean() for lab in labels])
        n = np.array([(df["label"] == lab).sum() for lab in labels])
        se = np.sqrt(c * (1 - c) / n)
        ax.errorbar(x + 0.1 * (2 * k - 1), c, yerr=2 * se, fmt="o", color=f"C{k}", label=f"{int(100 * L)}% interval")
        ax.axhline(L, color=f"C{k}", ls="--", lw=0.8)
    ax.axhspan(0.85, 0.95, color="C1", alpha=0.1)
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=20, fontsize=8)
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("share of (participant, muscle) covered")
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    _save(fig, out)
