"""Chapter 5 figures: ABC traces, D_k histograms, per-direction discrepancy, parallel coordinates."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from neckstrength.plotting import _save


def abc_traces(history: pd.DataFrame, truth: pd.Series, base: pd.Series, out: str | Path, title: str,
               converged: bool | None = None, iterations: int | None = None, D_fc: float | None = None,
               eps_D: float | None = None) -> None:
    """Per-parameter estimate traces (Figs. 5.7 / 5.8 / 5.11 / 5.13).

    The legend (below the panels) lists the true strength only when ``truth`` has a value (simulated data sets; a
    participant has no truth). With ``converged`` given, the title says whether the run converged, and after how
    many iterations with which ``D(f_c)``; a run stopped at maxIter says NOT CONVERGED.
    """
    params = list(dict.fromkeys(history["parameter"]))
    ncol = 4 if len(params) > 8 else min(len(params), 4)
    nrow = int(np.ceil(len(params) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 2.6 * nrow + 1.0), squeeze=False)
    has_truth = False
    for k, p in enumerate(params):
        ax = axes[k // ncol, k % ncol]
        h = history[history["parameter"] == p]
        ax.plot(h["iteration"], h["f_c"], "k-", lw=1.5, label="f_c (estimate)")
        ax.plot(h["iteration"], h["f_low"], "b--", lw=0.8,
                label="f_c(1 -+ sigma_c): sampling width, a heuristic, not an interval")
        ax.plot(h["iteration"], h["f_high"], "b--", lw=0.8)
        t = truth.get(p, np.nan)
        if np.isfinite(t):
            has_truth = True
            ax.axhline(t, color="red", ls="--", lw=1, label="true strength (simulated data set)")
        b = base.get(p, np.nan)
        if np.isfinite(b):
            ax.plot([0], [b], "kx", label="f'_base (before the Eq. 5.3 scaling)")
        ax.set_title(p, fontsize=9)
        ax.tick_params(labelsize=7)
        if k + ncol >= len(params):                     # the lowest panel of its column
            ax.set_xlabel("iteration", fontsize=8)
    for k in range(len(params), nrow * ncol):
        axes[k // ncol, k % ncol].axis("off")
    handles = {}
    for ax in axes.ravel():
        for hd, lb in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lb, hd)
    note = None if has_truth else "no true strength: a participant's data set"
    fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=min(len(handles), 2), fontsize=8,
               title=note, title_fontsize=8)
    if converged is not None:
        d = f", D(f_c) = {D_fc:.3f}" if D_fc is not None else ""
        n = f" after {iterations} iterations" if iterations is not None else ""
        status = (f"converged{n}{d}" if converged else
                  f"NOT CONVERGED: stopped{n} (maxIter){d}" + (f", needs every D_k > {eps_D:g}" if eps_D else ""))
        title = f"{title}\n{status}"
    fig.suptitle(title, fontsize=10, color="black" if converged is not False else "darkred")
    fig.supylabel("strength (N)", fontsize=9)
    legend_in = 0.2 * (int(np.ceil(len(handles) / 2)) + (note is not None)) + 0.25
    fig.tight_layout(rect=(0, legend_in / fig.get_figheight(), 1, 1))
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
