"""Figures of the clinician session: ``summary.png`` (estimate vs prior, entropy and P(deficit) per step)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd


def summary_figure(traj: pd.DataFrame, est: pd.DataFrame, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [2, 1]})
    x = np.arange(len(est))
    ax[0].errorbar(x - 0.12, est["f_0"], yerr=est["sd_0"], fmt="o", color="0.6", label="prior f_0 ± sd")
    ax[0].errorbar(x + 0.12, est["f_c"], yerr=est["sd_c"], fmt="o", color="C0", label="estimate f_c ± sd")
    ax[0].set_xticks(x, est["muscle"], rotation=60 if len(x) > 10 else 0, fontsize=8)
    ax[0].set_ylabel("strength (N)")
    ax[0].legend(fontsize=8)
    h = traj.groupby("step")["entropy"].mean()
    labels = traj.drop_duplicates("step")["direction"].tolist()
    ax[1].plot(h.index, h.values, "o-")
    ax[1].set_xticks(h.index, ["prior"] + labels[1:], rotation=60, fontsize=8)
    ax[1].set_ylabel("mean posterior entropy (nats)")
    if "p_deficit" in traj.columns:
        pd_ = traj.groupby("step")["p_deficit"].first()
        tw = ax[1].twinx()
        tw.plot(pd_.index, pd_.values, "s--", color="C3")
        tw.set_ylim(0, 1)
        tw.set_ylabel("P(deep-extensor deficit) (not calibrated)", color="C3")
    fig.suptitle(f"Clinician session: {title}")
    fig.tight_layout()
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)

