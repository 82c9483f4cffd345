"""Figures of the deficit-decision study: ROC curves, the reliability diagram and P(deficit) by test."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd


def fig_decision_study(runs: pd.DataFrame, reliability: pd.DataFrame, checkpoints: Sequence[int], p_decide: float,
                       path: str | Path, title: str) -> None:
    """A row of ROC panels, one per protocol (the score after each checkpoint: log BF, Algorithm 4's -log f_c
    ratio), above the reliability diagram (mean printed P against the share with the deficit, 95% intervals) and
    the median P(deficit) by test with quartiles, deficit vs normal participants. Legends sit below the panels,
    not over the data."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from neckstrength.sequential.decision_study import PROTOCOLS, _with_p, missing_kind, roc_curve

    def ordered(names):                           # the study's order of protocols (forces first), not the rows'
        names = list(dict.fromkeys(names))
        return sorted(names, key=lambda p: PROTOCOLS.index(p) if p in PROTOCOLS else len(PROTOCOLS))

    protocols = ordered(runs["protocol"])
    styles = ["-", "--", ":", "-.", (0, (5, 1, 1, 1, 1, 1))]
    n_top = len(protocols)
    fig = plt.figure(figsize=(max(14, 4.4 * n_top), 11), constrained_layout=True)
    gs = fig.add_gridspec(2, 1, height_ratios=[1, 1.25])
    top, bottom = gs[0].subgridspec(1, n_top), gs[1].subgridspec(1, 2)
    for pi, protocol in enumerate(protocols):
        a = fig.add_subplot(top[0, pi])
        for ci, t in enumerate(checkpoints):
            c = roc_curve(runs, protocol, t)
            if c["sensitivity"].isna().all() or len(c) <= 2:
                continue
            a.step(c["false_alarm"], c["sensitivity"], where="post", color=f"C{ci}", label=f"{t} tests")
        note = missing_kind(runs, protocol)
        if note:                                  # one kind only (a study stopped early): say so, no curve
            a.text(0.5, 0.5, note.replace(", so ", ",\nso ").replace(" (", "\n("), ha="center", va="center",
                   fontsize=8, transform=a.transAxes, wrap=True)
        a.plot([0, 1], [0, 1], color="grey", lw=0.8)
        a.axvline(0.05, color="grey", lw=0.8, ls=":")
        a.set_xlabel("false-alarm rate (normal called deficit)")
        a.set_ylabel("sensitivity (deficit called deficit)")
        score = "-log f_c(group) / normal" if protocol == "alg4" else "log Bayes factor"
        kinds = runs.loc[runs["protocol"] == protocol].groupby("kind")["participant"].nunique()
        a.set_title(f"ROC: {protocol} ({score})\n{kinds.get('deficit', 0)} deficit, {kinds.get('normal', 0)} normal "
                    "patients", fontsize=9)
        a.set_xlim(0, 1)
        a.set_ylim(0, 1.02)
        if not note:
            a.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=4)  # below the panel
    runs = _with_p(runs)
    protocols = ordered(runs["protocol"])
    ax = [None, fig.add_subplot(bottom[0, 0]), fig.add_subplot(bottom[0, 1])]
    a = ax[1]
    for pi, (protocol, g) in enumerate(reliability.groupby("protocol", sort=False)):
        x = g["mean_p_deficit"].to_numpy(float)
        y = g["share_with_deficit"].to_numpy(float)
        err = np.vstack([y - g["ci95_low"].to_numpy(float), g["ci95_high"].to_numpy(float) - y])
        a.errorbar(x + 0.008 * pi, y, yerr=err, fmt="o", color=f"C{pi}", capsize=3, label=protocol)
    a.plot([0, 1], [0, 1], color="grey", lw=0.8)
    a.set_xlabel("P(deficit) (model's, or recalibrated), mean within bin")
    a.set_ylabel("share of participants with the deficit (95% interval)")
    a.set_title(f"reliability, after {', '.join(map(str, checkpoints))} tests pooled")
    a.set_xlim(-0.02, 1.02)
    a.set_ylim(-0.02, 1.02)
    a.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2)      # below the panel
    a = ax[2]
    for pi, protocol in enumerate(protocols):
        for kind, color in (("deficit", "C3"), ("normal", "C0")):
            g = runs[(runs["protocol"] == protocol) & (runs["kind"] == kind)]
            if g.empty:
                continue
            q = g.groupby("t")["p_deficit"].quantile([0.25, 0.5, 0.75]).unstack()
            a.plot(q.index, q[0.5], color=color, ls=styles[pi % len(styles)], label=f"{kind}, {protocol} (median)")
            if pi == 0:
                a.fill_between(q.index, q[0.25], q[0.75], color=color, alpha=0.15, lw=0)
    for y in (p_decide, 1 - p_decide):
        a.axhline(y, color="grey", lw=0.8, ls=":")
    a.set_xlabel("tests done")
    a.set_ylabel("model's P(deficit) (quartiles shaded, first protocol)")
    a.set_title("P(deficit) by test")
    a.set_ylim(-0.02, 1.02)
    a.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2)      # below the panel
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)
