"""Figures of Chapter 3: reliability (Fig. 3.2), marginal means (Fig. 3.3), MFI maps (Fig. 3.4)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import matplotlib
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from neckstrength.mfi.schema import GROUPS, LEVELS, QUARTILES

matplotlib.use("Agg")


GROUP_COLOURS = {"Control": "tab:blue", "Recovered": "tab:green", "WAD": "tab:red"}


def _save(fig, out: str | Path) -> None:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp.png")
    from neckstrength.plotting import save_png

    save_png(fig, tmp, dpi=120, bbox_inches="tight")   # 256-colour palette: the report stays small
    plt.close(fig)
    tmp.replace(out)


def _stars(p: float) -> str:
    return "***" if p < 0.001 else "**" if p < 0.01 else "*" if p < 0.05 else ""


def fig_reliability(pairs: Mapping[str, pd.DataFrame], table: pd.DataFrame, out: str | Path, label: str) -> None:
    """Fig. 3.2: Bland-Altman plots (a intra, b inter) and rater-vs-rater scatter with ICC(2,1) (c, d)."""
    fig, axes = plt.subplots(2, 2, figsize=(12, 10))
    fig.subplots_adjust(wspace=0.35, hspace=0.3)
    rel = table.set_index("design")
    for col, design in enumerate(("intra", "inter")):
        p = pairs.get(design, pd.DataFrame())
        ax_ba, ax_sc = axes[0, col], axes[1, col]
        letter_ba, letter_sc = "ab"[col], "cd"[col]
        if p is None or len(p) < 3 or design not in rel.index or pd.isna(rel.loc[design].get("bias", np.nan)):
            for ax in (ax_ba, ax_sc):
                ax.text(0.5, 0.5, f"no {design}-rater re-tracings in the data", ha="center", transform=ax.transAxes)
            continue
        r = rel.loc[design]
        mean, diff = (p["a"] + p["b"]) / 2, p["a"] - p["b"]
        for g in GROUPS:
            sel = p["group"] == g
            if sel.any():
                ax_ba.scatter(mean[sel], diff[sel], s=10, alpha=0.6, color=GROUP_COLOURS[g], label=g)
        x0, x1 = float(mean.min()), float(mean.max())
        for val, lo, hi, ls in ((r["bias"], r["bias_ci_low"], r["bias_ci_high"], "-"),
                                (r["lower"], r["lower_ci_low"], r["lower_ci_high"], "--"),
                                (r["upper"], r["upper_ci_low"], r["upper_ci_high"], "--")):
            ax_ba.axhline(val, color="k", ls=ls, lw=1)
            ax_ba.axhspan(lo, hi, color="0.8", alpha=0.5, lw=0)
        ax_ba.text(x1, r["upper"], f" {r['upper']:+.3f}", va="bottom", ha="right", fontsize=8)
        ax_ba.text(x1, r["lower"], f" {r['lower']:+.3f}", va="top", ha="right", fontsize=8)
        ax_ba.set_xlim(x0 - 0.01, x1 + 0.01)
        ax_ba.set_xlabel("mean of the two tracings (MFI)")
        ax_ba.set_ylabel(f"{r['a']} - {r['b']} (MFI)")
        ax_ba.set_title(f"{letter_ba}) Bland-Altman, {design}-rater: LOA ({r['lower']:.3f}, {r['upper']:.3f}); "
                        f"n = {int(r['n'])}", fontsize=9)
        ax_ba.legend(fontsize=7, loc="upper left")
        lim = [min(p["a"].min(), p["b"].min()) - 0.01, max(p["a"].max(), p["b"].max()) + 0.01]
        for g in GROUPS:
            sel = p["group"] == g
            if sel.any():
                ax_sc.scatter(p["a"][sel], p["b"][sel], s=10, alpha=0.6, color=GROUP_COLOURS[g], label=g)
        ax_sc.plot(lim, lim, "k-", lw=1)
        ax_sc.set_xlim(lim)
        ax_sc.set_ylim(lim)
        ax_sc.set_aspect("equal")
        ax_sc.set_xlabel(f"{r['a']} (MFI)")
        ax_sc.set_ylabel(f"{r['b']} (MFI)")
        ax_sc.set_title(f"{letter_sc}) {design}-rater ICC(2,1) = {r['icc21']:.3f} "
                        f"(95% CI {r['icc21_ci_low']:.3f}, {r['icc21_ci_high']:.3f})", fontsize=9)
    fig.suptitle(f"Fig. 3.2 (reproduced): MFI tracing reliability -- {label}", fontsize=11)
    _save(fig, out)


def fig_marginal_means(emm: pd.DataFrame, pairwise: pd.DataFrame, covariates: Mapping, out: str | Path,
                       label: str) -> None:
    """Fig. 3.3: estimated marginal means per quartile and group with 95 % CIs and Bonferroni stars."""
    fig, ax = plt.subplots(figsize=(8, 5))
    width = 0.26
    x = np.arange(len(QUARTILES))
    e = emm.set_index(["group", "quartile"])
    for k, g in enumerate(GROUPS):
        vals = np.array([e.loc[(g, q), "emm"] for q in QUARTILES])
        lo = vals - np.array([e.loc[(g, q), "ci_low"] for q in QUARTILES])
        hi = np.array([e.loc[(g, q), "ci_high"] for q in QUARTILES]) - vals
        ax.bar(x + (k - 1) * width, vals, width, yerr=[lo, hi], capsize=3, color=GROUP_COLOURS[g], alpha=0.8,
               label=g)
    top = float(emm["ci_high"].max())
    step = 0.04 * top
    offs = {g: (k - 1) * width for k, g in enumerate(GROUPS)}
    for i, q in enumerate(QUARTILES):
        h = float(emm[emm["quartile"] == q]["ci_high"].max()) + step
        for r in pairwise[pairwise["quartile"] == q].to_dict("records"):
            s = _stars(r["p_bonferroni"])
            if not s:
                continue
            xa, xb = i + offs[r["group_1"]], i + offs[r["group_2"]]
            ax.plot([xa, xa, xb, xb], [h, h + step / 3, h + step / 3, h], "k-", lw=0.8)
            ax.text((xa + xb) / 2, h + step / 3, s, ha="center", va="bottom", fontsize=9)
            h += step * 1.3
    ax.set_xticks(x)
    ax.set_xticklabels([f"{q}" + (" (medial)" if q == "Q1" else " (lateral)" if q == "Q4" else "") for q in QUARTILES])
    ax.set_ylabel("estimated marginal mean MFI")
    ax.legend(loc="upper right", fontsize=8)
    female = covariates.get("female")
    ax.set_title(f"Fig. 3.3 (reproduced): EMMs at age {covariates['age']:g}, BMI {covariates['bmi']:g}, level "
                 f"C{int(covariates['level_c'] + 5)}, female share {female:.2f}\n{label}; * p<0.05 ** p<0.01 "
                 "*** p<0.001 (Wald z, Bonferroni)", fontsize=9)
    _save(fig, out)


def fig_maps(table32: pd.DataFrame, out: str | Path, label: str) -> None:
    """Fig. 3.4: MFI across quartiles (a-c, map of level x quartile) and across levels (d-f) per group."""
    t = table32.set_index(["level", "quartile", "group"])
    fig, axes = plt.subplots(2, 3, figsize=(15, 9))
    fig.subplots_adjust(wspace=0.3, hspace=0.3)
    vmax = float(table32[table32["quartile"] != "Whole"]["mfi_mean"].max())
    vmin = float(table32[table32["quartile"] != "Whole"]["mfi_mean"].min())
    levels_top_down = list(LEVELS)            # C3 (cranial) at the top
    for k, g in enumerate(GROUPS):
        M = np.array([[t.loc[(lvl, q, g), "mfi_mean"] for q in QUARTILES] for lvl in levels_top_down])
        ax = axes[0, k]
        im = ax.imshow(M, cmap="viridis", vmin=vmin, vmax=vmax, aspect="auto")
        for i in range(M.shape[0]):
            for j in range(M.shape[1]):
                ax.text(j, i, f"{M[i, j]:.3f}", ha="center", va="center", fontsize=8,
                        color="w" if M[i, j] < (vmin + vmax) / 2 else "k")
        ax.set_xticks(range(len(QUARTILES)))
        ax.set_xticklabels(QUARTILES)
        ax.set_yticks(range(len(levels_top_down)))
        ax.set_yticklabels(levels_top_down)
        ax.set_title(f"{'abc'[k]}) {g}: by quartile (Q1 medial, Q4 lateral)", fontsize=9)
        ax2 = axes[1, k]
        lv = np.arange(len(LEVELS))
        for q in QUARTILES:
            ax2.plot(lv, [t.loc[(lvl, q, g), "mfi_mean"] for lvl in LEVELS], "o-", label=q)
        ax2.plot(lv, [t.loc[(lvl, "Whole", g), "mfi_mean"] for lvl in LEVELS], "k--", label="Whole")
        ax2.set_xticks(lv)
        ax2.set_xticklabels(LEVELS)
        ax2.set_ylim(vmin * 0.8, vmax * 1.1)
        ax2.set_xlabel("cervical level")
        ax2.set_ylabel("mean MFI")
        ax2.set_title(f"{'def'[k]}) {g}: across cervical levels", fontsize=9)
        ax2.legend(fontsize=7)
    fig.colorbar(im, ax=axes[0, :].tolist(), shrink=0.8, label="mean MFI")
    fig.suptitle(f"Fig. 3.4 (reproduced): group means of MFI -- {label}", fontsize=11)
    _save(fig, out)
