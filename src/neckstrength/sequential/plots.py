"""Chapter 6 figures: posteriors per muscle, iterations, order entropies, expected entropy reduction, radar,
and criteria curves (entropy and error vs number of tests)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd


def _muscle_axes(m: int, ncols: int = 4, size=(3.6, 2.9)):
    import matplotlib.pyplot as plt

    nrows = int(np.ceil(m / ncols))
    fig, axes = plt.subplots(nrows, ncols, figsize=(size[0] * ncols, size[1] * nrows), squeeze=False)
    for ax in axes.ravel()[m:]:
        ax.set_visible(False)
    return fig, axes.ravel()[:m]


def _save(fig, out, rect=(0, 0, 1, 1)):
    from neckstrength.plotting import _save as save

    fig.tight_layout(rect=rect)
    save(fig, out)


def _legend_below(fig, ax, fontsize: float = 7) -> tuple[float, float, float, float]:
    """The legend of ``ax`` below the panels (never over one); the rect that leaves room for it."""
    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return (0, 0, 1, 1)
    ncol = min(len(labels), 6)
    fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=fontsize)
    rows = int(np.ceil(len(labels) / ncol))
    return (0, (0.22 * rows + 0.15) / fig.get_figheight(), 1, 1)


def fig_posteriors(post: pd.DataFrame, est: pd.DataFrame, out, title: str, iterations: Sequence[int] | None = None,
                   styles: Mapping[int, dict] | None = None) -> None:
    """Figs. 6.4a / 6.5a / 6.9: posterior PDFs per muscle (prior green, truth red, E dashed)."""
    import matplotlib.pyplot as plt

    names = list(est["muscle"])
    T = int(post["iteration"].max())
    its = list(range(T + 1)) if iterations is None else list(iterations)
    cmap = plt.get_cmap("viridis")
    fig, axes = _muscle_axes(len(names))
    for ax, n in zip(axes, names):
        p = post[post["muscle"] == n]
        for t in its:
            q = p[p["iteration"] == t]
            if styles and t in styles:
                kw = dict(styles[t])
            elif t == 0:
                kw = {"color": "green", "lw": 1.5, "label": "prior"}
            elif t == T:
                kw = {"color": "blue", "lw": 2, "label": f"after {T}"}
            else:
                kw = {"color": cmap(t / max(T, 1)), "lw": 0.9, "alpha": 0.8, "label": f"after {t}"}
            ax.plot(q["f"], q["density"], **kw)
            mean = float((q["f"] * q["density"]).sum() / q["density"].sum())
            ax.axvline(mean, color=kw.get("color"), ls="--", lw=0.8)
        fa = est.loc[est["muscle"] == n, "f_actual"].iloc[0]
        if np.isfinite(fa):
            ax.axvline(fa, color="red", lw=1.5, label="actual f_a")
        ax.set_title(n, fontsize=10)
        ax.set_xlabel("strength (N)", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].plot([], [], color="grey", ls="--", lw=0.8, label="dashed: expected value E")
    rect = _legend_below(fig, axes[0])
    fig.suptitle(title, fontsize=10)
    _save(fig, out, rect)


def fig_iterations(it: pd.DataFrame, out, title: str) -> None:
    """Figs. 6.4b / 6.5b / 6.10: expected value (black) and variance (blue) per iteration."""
    names = list(dict.fromkeys(it["muscle"]))
    fig, axes = _muscle_axes(len(names))
    for ax, n in zip(axes, names):
        q = it[it["muscle"] == n].sort_values("iteration")
        x = q["iteration"].to_numpy()
        ax.plot(x, q["f_c"], "k-o", ms=3)
        fa = q["f_actual"].iloc[0]
        if np.isfinite(fa):
            ax.axhline(fa, color="red", lw=1, ls=":")
        ax.set_xticks(x)
        ax.set_xticklabels(["prior"] + [str(int(v)) for v in q["direction_index"].iloc[1:]], fontsize=7)
        ax.set_ylabel("E[f] (N)", fontsize=8)
        ax2 = ax.twinx()
        ax2.plot(x, q["v_c"], "b-s", ms=3)
        ax2.set_ylabel("Var (N^2)", color="blue", fontsize=8)
        ax2.tick_params(labelsize=7, colors="blue")
        ax.set_title(n, fontsize=10)
        ax.tick_params(labelsize=7)
    fig.suptitle(title, fontsize=10)
    _save(fig, out)


def fig_order_entropy(orders: pd.DataFrame, out, title: str) -> None:
    """Fig. 6.7: mean posterior entropy per iteration, selected order (red) vs every other order (box plots)."""
    import matplotlib.pyplot as plt

    cols = [c for c in orders.columns if c.startswith("H_")]
    others = orders[~orders["selected"]][cols].to_numpy()
    sel = orders[orders["selected"]][cols].to_numpy()[0]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.boxplot([others[:, t] for t in range(len(cols))], positions=range(len(cols)), widths=0.5,
               flierprops={"markersize": 2})
    ax.plot(range(len(cols)), sel, "r-o", label="entropy-reducing sequence")
    ax.set_xticks(range(len(cols)))
    ax.set_xticklabels([str(t) for t in range(len(cols))])
    ax.set_xlabel("number of measurements")
    ax.set_ylabel("mean posterior entropy (nats)")
    ax.legend()
    ax.set_title(title, fontsize=9)
    _save(fig, out)


def fig_expected_dS(dS: pd.DataFrame, K: int, out, title: str) -> None:
    """Fig. 6.8: stacked expected entropy reduction per direction (bars) and muscle (colours), per iteration."""
    import matplotlib.pyplot as plt

    its = sorted(dS["iteration"].unique())
    names = list(dict.fromkeys(dS["muscle"]))
    ncols = min(4, len(its))
    nrows = int(np.ceil(len(its) / ncols))
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.6 * ncols, 2.8 * nrows), squeeze=False, sharey=True)
    colors = plt.get_cmap("tab20" if len(names) > 10 else "tab10")
    idx = np.arange(1, K + 1)
    for ax, t in zip(axes.ravel(), its):
        q = dS[dS["iteration"] == t]
        piv = q.pivot(index="direction_index", columns="muscle", values="dS").reindex(idx)[names].fillna(0.0)
        bottom_pos = np.zeros(K)
        bottom_neg = np.zeros(K)
        for j, n in enumerate(names):
            v = piv[n].to_numpy()
            base = np.where(v >= 0, bottom_pos, bottom_neg)
            ax.bar(idx, v, bottom=base, color=colors(j % colors.N), label=n if t == its[0] else None, width=0.8)
            bottom_pos += np.maximum(v, 0)
            bottom_neg += np.minimum(v, 0)
        avail = set(q["direction_index"])
        sel = int(q.loc[q["selected"], "direction_index"].iloc[0])
        ax.set_xticks(idx)
        ax.set_xticklabels([str(i) for i in idx], fontsize=6 if K > 10 else 8)
        for lab, i in zip(ax.get_xticklabels(), idx):
            lab.set_color("green" if i == sel else ("black" if i in avail else "lightgrey"))
        ax.set_title(f"iteration {t}: selected {sel}", fontsize=9)
    for ax in axes.ravel()[len(its):]:
        ax.set_visible(False)
    fig.legend(loc="lower center", ncol=min(len(names), 8), fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.06 if len(names) <= 8 else 0.12, 1, 0.96))
    from neckstrength.plotting import _save as save
    save(fig, out)


def fig_radar_sagittal(directions: pd.DataFrame, series, out, title: str) -> None:
    """Fig. 6.6: one polar plot of the sagittal directions (angle of the test point in the sagittal plane)."""
    import matplotlib.pyplot as plt

    from neckstrength.model.geometry import plane_angle

    recs = sorted(directions.to_dict("records"), key=lambda r: np.mod(plane_angle(r, "sagittal_mid"), 2 * np.pi))
    th = np.array([np.mod(plane_angle(r, "sagittal_mid"), 2 * np.pi) for r in recs])
    names = [r["name"] for r in recs]
    idx = {r["name"]: int(r["sagittal_index"]) for r in recs}
    fig, ax = plt.subplots(figsize=(6.5, 6.5), subplot_kw={"projection": "polar"})
    for label, s_, kw in series:
        v = np.array([s_.get(n, np.nan) for n in names], float)
        ax.plot(np.r_[th, th[:1]], np.r_[v, v[:1]], label=label, **kw)
    ax.set_xticks(th)
    ax.set_xticklabels([f"{n} ({idx[n]})" for n in names], fontsize=8)
    ax.tick_params(axis="y", labelsize=7)
    ax.legend(loc="lower center", bbox_to_anchor=(0.5, -0.18), ncol=2, fontsize=8)
    ax.set_title(title + " [N]", fontsize=9, pad=18)
    _save(fig, out)


def fig_criteria_curves(curves: pd.DataFrame, entropy_label: str, title: str, out, dpi: int = 110) -> None:
    """Mean posterior entropy and mean relative error vs number of measurements, one line per criterion.

    ``curves``: columns ``criterion``, ``t``, ``entropy``, ``rel_error`` (means over simulated participants).
    """
    from neckstrength.plotting import plt, save_png   # Agg backend

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for crit, g in curves.groupby("criterion", sort=False):
        g = g.sort_values("t")
        axes[0].plot(g["t"], g["entropy"], "-o", ms=3, label=crit)
        axes[1].plot(g["t"], 100 * g["rel_error"], "-o", ms=3, label=crit)
    axes[0].set_ylabel(entropy_label)
    axes[1].set_ylabel("mean |E - f_a| / f_a (%)")
    for ax in axes:
        ax.set_xlabel("number of measurements")
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    save_png(fig, out, dpi=dpi)   # 256-colour palette: the report stays small
    plt.close(fig)


def fig_deficit_study(df: pd.DataFrame, per: pd.DataFrame, p_alarm: float, path, title: str) -> None:
    """Clinician-loop study (issue 18): P(deficit) after t tests per strategy (median and quartiles over deficit
    participants, median over normal ones) and the share of runs with an alarm (P > ``p_alarm``) by t."""
    from neckstrength.plotting import plt   # Agg backend

    fig, ax = plt.subplots(1, 2, figsize=(12, 4.6))
    strategies = list(dict.fromkeys(df["strategy"]))
    for k, s in enumerate(strategies):
        col = f"C{k}"
        for kind, ls in (("deficit", "-"), ("normal", "--")):
            sub = df[(df["strategy"] == s) & (df["kind"] == kind)]
            if sub.empty:
                continue
            q = sub.groupby("t")["p_deficit"].quantile([0.25, 0.5, 0.75]).unstack()
            ax[0].plot(q.index, q[0.5], ls, color=col, label=f"{s} ({kind})")
            if kind == "deficit":
                ax[0].fill_between(q.index, q[0.25], q[0.75], color=col, alpha=0.15)
            pr = per[(per["strategy"] == s) & (per["kind"] == kind)]
            tmax = int(df["t"].max())
            ts = np.arange(0, tmax + 1)
            share = [(pr["t_detect"] <= t).mean() for t in ts]
            ax[1].step(ts, share, ls, where="post", color=col, label=f"{s} ({kind})")
    ax[0].axhline(p_alarm, color="0.4", lw=0.8, ls=":")
    ax[0].set_xlabel("tests t")
    ax[0].set_ylabel("P(deficit) (median; band: quartiles, deficit)")
    ax[0].set_ylim(0, 1)
    ax[0].legend(fontsize=7)
    ax[1].set_xlabel("tests t")
    ax[1].set_ylabel(f"share of runs with P(deficit) > {p_alarm:g} by t")
    ax[1].set_ylim(0, 1)
    ax[1].legend(fontsize=7, title="solid: detected; dashed: false alarm", title_fontsize=7)
    fig.suptitle(title, fontsize=9)
    _save(fig, path)
