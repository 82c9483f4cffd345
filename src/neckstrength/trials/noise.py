"""Trial-to-trial scatter of a participant's maximal efforts, from the repeats the protocol records (Appendix A).

Appendix A measures each test direction at least twice (a third trial when the second is more than 10% above
the first) and keeps the largest. The repeats that are *valid* (matched to the direction window, or kept
flagged with ``mismatch_action`` 'flag'; positive along the target) measure how much one maximal effort
differs from the next. :func:`repeat_noise` pools them per participant over the test directions (the main
block; the cardinal start/end efforts are the fatigue check and are left out):

``s^2 = sum_k sum_t (log F_kt - mean_t log F_kt)^2 / df``,  ``df = sum_k (n_k - 1)``

over the directions ``k`` with ``n_k >= 2`` valid trials: the pooled within-direction SD of the log force
(log-normal noise model, the one the gap diagnosis simulates). Its 95% confidence interval is the chi-square one
for a normal SD, ``[s sqrt(df / chi2_0.975(df)), s sqrt(df / chi2_0.025(df))]`` (exact for independent normal log
trials with one SD in every direction; the repeat rule's conditional third trial and effort learning within a
direction are not modelled).

The value is the scatter of *one* trial. The kept value is the largest of the direction's 2-3 trials, whose
scatter is somewhat smaller (for normal errors 0.83 x for 2 trials, 0.75 x for 3); the diagnosis uses the
one-trial value (docs/gap_diagnosis.md: a modelling choice, on the side of calling less an effect).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.io import DataValidationError

#: Columns of ``noise.csv`` (one row per participant).
NOISE_COLUMNS = ["participant", "noise_log_sd", "df", "ci_low", "ci_high", "n_directions_with_repeats",
                 "n_directions"]


def pooled_log_sd(groups: list[np.ndarray], level: float = 0.95) -> tuple[float, int, float, float]:
    """Pooled within-group SD of ``log`` of each group's values (groups with < 2 values ignored), its degrees of
    freedom and the chi-square confidence interval at ``level``. No repeats: ``(nan, 0, nan, nan)``."""
    from scipy.stats import chi2

    ss, df = 0.0, 0
    for g in groups:
        v = np.log(np.asarray(g, float))
        if len(v) >= 2:
            ss += float(((v - v.mean()) ** 2).sum())
            df += len(v) - 1
    if df == 0:
        return np.nan, 0, np.nan, np.nan
    s = float(np.sqrt(ss / df))
    a = (1 - level) / 2
    return s, df, float(s * np.sqrt(df / chi2.ppf(1 - a, df))), float(s * np.sqrt(df / chi2.ppf(a, df)))


def repeat_noise(selected: pd.DataFrame, directions: list[str]) -> pd.DataFrame:
    """Per participant of ``selected`` (:func:`neckstrength.trials.select.select_trials` output): the pooled log SD
    of the valid repeats over the test ``directions`` (main block), with ``df``, 95% CI and counts
    (:data:`NOISE_COLUMNS`). A participant without any direction with two valid trials gets ``df`` 0 and no
    value."""
    valid = selected["kept"] | selected["reason"].astype(str).str.startswith("not the largest")
    d = selected[valid & selected["direction"].isin(list(directions)) & (selected["block"] == "main")]
    rows = []
    for p in dict.fromkeys(selected["participant"]):
        g = d[d["participant"] == p]
        groups = [grp["magnitude"].to_numpy(float) for _, grp in g.groupby("direction", sort=False)]
        s, df, lo, hi = pooled_log_sd(groups)
        rows.append({"participant": p, "noise_log_sd": s, "df": df, "ci_low": lo, "ci_high": hi,
                     "n_directions_with_repeats": int(sum(len(x) >= 2 for x in groups)),
                     "n_directions": int(len(groups))})
    return pd.DataFrame(rows, columns=NOISE_COLUMNS)


def read_noise_table(path: str | Path) -> dict[str, dict]:
    """``noise.csv`` as written by the trial import: participant -> {noise_log_sd, df, ci_low, ci_high}; rows with
    ``df`` 0 (no repeats) are left out. Errors name the file, row and field."""
    path = Path(path)
    if not path.exists():
        raise DataValidationError(path, "noise table not found (written by neckstrength import-trials as noise.csv)")
    df = pd.read_csv(path, comment="#")
    for c in ("participant", "noise_log_sd", "df", "ci_low", "ci_high"):
        if c not in df.columns:
            raise DataValidationError(path, f"missing column '{c}' (columns: {', '.join(map(str, df.columns))})",
                                      field_name=c)
    out: dict[str, dict] = {}
    for i, r in enumerate(df.itertuples(index=False)):
        p = str(r.participant)
        if p in out:
            raise DataValidationError(path, f"participant '{p}' appears twice", i + 1, None, "participant")
        try:
            n = int(r.df)
        except (TypeError, ValueError):
            raise DataValidationError(path, f"df must be a whole number, not {r.df!r}", i + 1, None, "df") from None
        if n < 0:
            raise DataValidationError(path, f"df must be >= 0, not {n}", i + 1, None, "df")
        if n == 0:
            continue
        vals = {}
        for f in ("noise_log_sd", "ci_low", "ci_high"):
            v = float(getattr(r, f))
            if not np.isfinite(v) or v <= 0:
                raise DataValidationError(path, f"must be a positive number with df {n} > 0, not {v!r}", i + 1,
                                          None, f)
            vals[f] = v
        if not vals["ci_low"] <= vals["noise_log_sd"] <= vals["ci_high"]:
            raise DataValidationError(path, "ci_low <= noise_log_sd <= ci_high does not hold", i + 1, None,
                                      "noise_log_sd")
        out[p] = {**vals, "df": n}
    return out
