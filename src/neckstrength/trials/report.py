"""The import's quality report: per trial (matched or not and by how much, kept or not), per participant
(fatigue change), every exclusion with its reason, and one figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.trials.formats import CARDINAL

TRIAL_COLUMNS = ["participant", "direction", "block", "trial", "row", "frame", "magnitude", "force_N", "moment_Nm",
                 "angle_M_deg", "angle_F_deg", "R_fm", "R_fm_target", "R_fm_error", "matched", "kept", "reason", "flag"]


def trial_quality(selected: pd.DataFrame) -> pd.DataFrame:
    act = [c for c in selected.columns if c.startswith("act_")]
    return selected[[c for c in TRIAL_COLUMNS if c in selected.columns] + act].copy()


def exclusions(selected: pd.DataFrame, directions: list[str]) -> pd.DataFrame:
    """Every trial not used (with its reason) and every participant x test direction left without a value."""
    ex = selected.loc[~selected["kept"], ["participant", "direction", "block", "trial", "row", "reason"]].copy()
    ex.insert(0, "what", "trial")
    rows = []
    for p in selected["participant"].unique():
        have = set(selected.loc[selected["kept"] & (selected["participant"] == p), "direction"])
        tried = set(selected.loc[selected["participant"] == p, "direction"])
        for d in directions:
            if d not in have:
                rows.append({"what": "direction", "participant": p, "direction": d, "block": "main", "trial": np.nan,
                             "row": np.nan, "reason": "no valid trial: no value in the max-force table"
                             if d in tried else "not measured: no value in the max-force table"})
    return pd.concat([ex, pd.DataFrame(rows, columns=ex.columns)], ignore_index=True)


def markdown(summary: dict, fatigue: pd.DataFrame, excl: pd.DataFrame, flags: pd.DataFrame,
             emg_missing: pd.DataFrame) -> str:
    s = summary
    lines = [f"# Trial import: {s['source']}", "",
             f"{s['trials']} trials of {s['participants']} participants; {s['matched']} matched the target direction "
             f"(window {s['settings']['angle_deg']:g} deg, R_fm +- {s['settings']['ratio_tol']:g}; mismatched "
             f"trials: {s['settings']['mismatch_action']}); {s['kept']} kept (largest valid trial per direction); "
             f"{s['excluded_trials']} trials not used; {s['missing_directions']} participant x direction cells "
             "without a value.", "", "## Fatigue (start vs end cardinal directions)", "",
             "| participant | pairs | mean change | min change | fatigued |", "|---|---|---|---|---|"]
    for r in fatigue.to_dict("records"):
        lines.append(f"| {r['participant']} | {r['cardinal_pairs']} | {r['mean_change_rel']:+.1%} | "
                     f"{r['min_change_rel']:+.1%} | {'YES' if r['fatigued'] else 'no'} |")
    lines += ["", f"Fatigued = mean change below -{s['settings']['fatigue_threshold']:.0%}. A fatigued participant's "
              "data are kept (flagged): later directions may underestimate strength.", "",
              "## Protocol flags on kept trials", ""]
    lines += [f"- {r['participant']} {r['direction']} ({r['block']}) trial {r['trial']}: {r['flag']}"
              for r in flags.to_dict("records")] or ["- none"]
    lines += ["", "## EMG channels not recorded", ""]
    lines += [f"- {r['participant']}: {r['channel']}" for r in emg_missing.to_dict("records")] or ["- none"]
    lines += ["", "## Exclusions (every trial not used, with its reason)", "",
              "| what | participant | direction | block | trial | file row | reason |", "|---|---|---|---|---|---|---|"]
    for r in excl.to_dict("records"):
        t = "" if pd.isna(r["trial"]) else int(r["trial"])
        row = "" if pd.isna(r["row"]) else int(r["row"])
        lines.append(f"| {r['what']} | {r['participant']} | {r['direction']} | {r['block']} | {t} | {row} | "
                     f"{r['reason']} |")
    return "\n".join(lines) + "\n"


def quality_figure(selected: pd.DataFrame, fatigue_dirs: pd.DataFrame, settings: dict, path: str | Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(15, 4.6))
    main = selected[~selected["direction"].isin(list(CARDINAL))]
    ang = np.fmax(main["angle_M_deg"].fillna(0), main["angle_F_deg"].fillna(0))
    for kept, mk in ((True, "o"), (False, "x")):
        for matched, col in ((True, "tab:blue"), (False, "tab:red")):
            sel = (main["kept"] == kept) & (main["matched"] == matched)
            if not sel.any():   # no legend entry for a kind without trials
                continue
            ax[0].scatter(ang[sel], main.loc[sel, "R_fm_error"], marker=mk, c=col, s=18,
                          label=f"{'kept' if kept else 'not kept'}, {'matched' if matched else 'not matched'}")
    ax[0].axvline(settings["angle_deg"], color="k", ls="--", lw=0.8)
    ax[0].axhline(settings["ratio_tol"], color="k", ls="--", lw=0.8)
    ax[0].set_xlabel("largest unit-vector angle error (deg)")
    ax[0].set_ylabel("|R_fm error|")
    ax[0].set_title("Direction matching per trial (window dashed)")
    ax[0].legend(fontsize=7)
    parts = list(selected["participant"].unique())
    for j, p in enumerate(parts):
        k = main[(main["participant"] == p) & main["kept"]]
        ax[1].scatter(np.full(len(k), j) + np.linspace(-0.25, 0.25, max(len(k), 1))[:len(k)], k["force_N"], s=12)
    ax[1].set_xticks(range(len(parts)), parts)
    ax[1].set_ylabel("kept max force (N)")
    ax[1].set_title("Max force per direction (kept trials)")
    if len(fatigue_dirs):
        piv = fatigue_dirs.pivot(index="direction", columns="participant", values="change_rel")
        piv = piv.reindex([d for d in CARDINAL if d in piv.index])
        (100 * piv).plot.bar(ax=ax[2], legend=False)
        vals = 100 * piv.to_numpy(dtype=float)
        lo = min(np.nanmin(vals), -100 * settings["fatigue_threshold"], 0.0)
        hi = max(np.nanmax(vals), 0.0)
        span = (hi - lo) or 1.0
        # headroom above the bars for the legend, so it never covers a bar
        ax[2].set_ylim(lo - 0.05 * span, hi + 0.35 * span)
        ax[2].legend(title="participant", loc="upper center", ncol=min(len(piv.columns), 4), fontsize=8,
                     title_fontsize=8)
    ax[2].axhline(-100 * settings["fatigue_threshold"], color="r", ls="--", lw=0.8)
    ax[2].set_ylabel("end / start - 1 (%)")
    ax[2].set_title("Fatigue: cardinal directions, end vs start")
    fig.suptitle(f"Trial import quality ({Path(settings.get('source', '')).name})")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.png")
    from neckstrength.plotting import save_png

    save_png(fig, tmp, dpi=110)   # 256-colour palette: the report stays small
    plt.close(fig)
    tmp.replace(path)
