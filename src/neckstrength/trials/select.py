"""The repeat-trial rule and the fatigue check (Appendix A).

Appendix A: "A maximum effort was measured in each target direction at least 2 times. A third measurement was
taken if the second measurement magnitude was more than 10% greater than the first. The largest magnitude of
the measurements was taken as the true value of the set." The six cardinal directions were measured "at the
beginning and end of the experiment to test for fatigue".

:func:`select_trials` keeps, per participant, direction and block, the largest matched trial, and records for
every trial whether it is kept and why not; protocol departures (one valid trial only, a third trial that the
10% rule asked for but is missing) are flagged on the kept trial, not hidden. :func:`fatigue_table` compares
the kept start and end cardinal efforts.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from neckstrength.trials.formats import CARDINAL


def select_trials(resolved: pd.DataFrame, repeat_rel: float = 0.10, mismatch_action: str = "drop") -> pd.DataFrame:
    """Add ``kept`` (bool), ``reason`` (why a trial is not used) and ``flag`` (protocol notes) to every trial.

    ``mismatch_action``: 'drop' (default) excludes trials outside the direction-matching window; 'flag' keeps
    them eligible and notes the mismatch in ``flag``.
    """
    if mismatch_action not in ("drop", "flag"):
        raise ValueError(f"mismatch_action must be 'drop' or 'flag', not {mismatch_action!r}")
    df = resolved.copy()
    df["kept"] = False
    df["reason"] = ""
    df["flag"] = ""
    for _, g in df.groupby(["participant", "direction", "block"], sort=False):
        g = g.sort_values("trial")
        ok = g["magnitude"] > 0
        if mismatch_action == "drop":
            eligible = g[g["matched"] & ok]
        else:
            eligible = g[ok]
        for i in g.index:
            if not ok[i]:
                df.at[i, "reason"] = f"effort opposite to the target (magnitude {df.at[i, 'magnitude']:.1f} <= 0)"
            elif i not in eligible.index:
                df.at[i, "reason"] = "direction not matched: " + df.at[i, "mismatch"]
        if eligible.empty:
            continue
        best = eligible["magnitude"].idxmax()
        df.at[best, "kept"] = True
        flags = []
        if mismatch_action == "flag" and not df.at[best, "matched"]:
            flags.append("kept although not matched: " + df.at[best, "mismatch"])
        if len(eligible) < 2:
            flags.append(f"only {len(eligible)} valid trial (protocol: at least 2)")
        else:
            mags = eligible["magnitude"].to_numpy()
            if mags[1] > (1 + repeat_rel) * mags[0] and len(eligible) < 3:
                flags.append(f"second valid trial {100 * (mags[1] / mags[0] - 1):.0f}% above the first but no third "
                             f"(protocol: a third when > {100 * repeat_rel:g}%)")
        df.at[best, "flag"] = "; ".join(flags)
        for i in eligible.index:
            if i != best:
                df.at[i, "reason"] = (f"not the largest of the set ({df.at[i, 'magnitude']:.1f} < "
                                      f"{df.at[best, 'magnitude']:.1f})")
    return df


def fatigue_table(selected: pd.DataFrame, threshold: float = 0.10) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Start vs end cardinal efforts: per participant and direction, and per participant (mean change).

    ``change_rel`` = end / start - 1 of the kept efforts (moment about the cardinal axis, N*m). A participant is
    flagged ``fatigued`` when the mean change is below ``-threshold``.
    """
    k = selected[selected["kept"] & selected["direction"].isin(list(CARDINAL))]
    rows = []
    for (p, d), g in k.groupby(["participant", "direction"], sort=False):
        s = g.loc[g["block"] == "start", "magnitude"]
        e = g.loc[g["block"] == "end", "magnitude"]
        start = float(s.iloc[0]) if len(s) else np.nan
        end = float(e.iloc[0]) if len(e) else np.nan
        rows.append({"participant": p, "direction": d, "start_Nm": start, "end_Nm": end,
                     "change_rel": end / start - 1 if np.isfinite(start) and np.isfinite(end) else np.nan})
    per_dir = pd.DataFrame(rows, columns=["participant", "direction", "start_Nm", "end_Nm", "change_rel"])
    summ = []
    for p in selected["participant"].unique():
        g = per_dir[per_dir["participant"] == p]
        ch = g["change_rel"].dropna()
        mean = float(ch.mean()) if len(ch) else np.nan
        summ.append({"participant": p, "cardinal_pairs": int(len(ch)), "mean_change_rel": mean,
                     "min_change_rel": float(ch.min()) if len(ch) else np.nan,
                     "fatigued": bool(np.isfinite(mean) and mean < -threshold),
                     "note": "" if len(ch) else "no start/end cardinal pair: fatigue not checked"})
    return per_dir, pd.DataFrame(summ)
