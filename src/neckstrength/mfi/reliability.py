"""Rater reliability: Bland-Altman limits of agreement and intraclass correlation (thesis Sec. 3.3.3).

- :func:`bland_altman`: bias and limits of agreement ``bias +- k SD`` of paired
  differences (Bland & Altman 1986, Lancet 327:307-310), with the paper's 95 %
  confidence intervals: ``t(n-1) SD / sqrt(n)`` for the bias and
  ``t(n-1) sqrt(3 SD^2 / n)`` for each limit.
- :func:`icc`: the six Shrout & Fleiss (1979) forms from pingouin, labelled in
  Shrout & Fleiss notation (pingouin's ICC(A,1) = ICC(2,1): two-way random
  effects, absolute agreement, single rater), with unrounded 95 % CIs.
- :func:`rater_pairs` / :func:`reliability_table`: the intra-rater (rater A trial 1
  vs trial 2) and inter-rater (rater A vs rater B, trial 1) pairs of quartile MFI
  on the re-traced ROIs.  As in the thesis (Sec. 3.5), every ROI quartile counts as
  one independent observation (10 ROIs x 4 quartiles per participant).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd
from scipy import stats

#: pingouin's labels -> Shrout & Fleiss (1979) notation and McGraw & Wong description.
ICC_FORMS = {
    "ICC(1,1)": ("ICC(1,1)", "one-way random, single rater"),
    "ICC(A,1)": ("ICC(2,1)", "two-way random, absolute agreement, single rater"),
    "ICC(C,1)": ("ICC(3,1)", "two-way mixed, consistency, single rater"),
    "ICC(1,k)": ("ICC(1,k)", "one-way random, mean of k raters"),
    "ICC(A,k)": ("ICC(2,k)", "two-way random, absolute agreement, mean of k raters"),
    "ICC(C,k)": ("ICC(3,k)", "two-way mixed, consistency, mean of k raters"),
}


@dataclass(frozen=True)
class BlandAltman:
    """Bland-Altman agreement of paired measurements (difference = a - b)."""

    n: int
    bias: float
    sd: float
    lower: float
    upper: float
    bias_ci: tuple[float, float]
    lower_ci: tuple[float, float]
    upper_ci: tuple[float, float]
    k: float
    r_absdiff_mean: float       # Pearson r of |a - b| with (a + b) / 2 (systematic relationship?)
    p_absdiff_mean: float

    def as_dict(self) -> dict:
        d = asdict(self)
        for key in ("bias_ci", "lower_ci", "upper_ci"):
            lo, hi = d.pop(key)
            d[f"{key}_low"], d[f"{key}_high"] = lo, hi
        return d


def bland_altman(a, b, k: float = 1.96, confidence: float = 0.95) -> BlandAltman:
    """Bias, limits of agreement ``bias +- k SD`` and their confidence intervals (Bland & Altman 1986).

    ``a``, ``b``: paired measurements (same length, at least 3 pairs); the
    difference is ``a - b``.  The confidence interval of each limit uses the
    paper's standard error ``sqrt(3 SD^2 / n)``.
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError("a and b must be 1-D arrays of equal length")
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    n = len(a)
    if n < 3:
        raise ValueError(f"need at least 3 complete pairs, got {n}")
    d = a - b
    bias = float(d.mean())
    sd = float(d.std(ddof=1))
    t = float(stats.t.ppf(0.5 + confidence / 2, n - 1))
    se_bias = sd / np.sqrt(n)
    se_lim = np.sqrt(3 * sd ** 2 / n)
    lo, hi = bias - k * sd, bias + k * sd
    mean = (a + b) / 2
    if np.ptp(mean) > 0 and np.ptp(np.abs(d)) > 0:
        r, p = stats.pearsonr(mean, np.abs(d))
    else:
        r, p = np.nan, np.nan
    return BlandAltman(n, bias, sd, lo, hi, (bias - t * se_bias, bias + t * se_bias),
                       (lo - t * se_lim, lo + t * se_lim), (hi - t * se_lim, hi + t * se_lim), k,
                       float(r), float(p))


def icc(data: pd.DataFrame, targets: str, raters: str, ratings: str) -> pd.DataFrame:
    """Intraclass correlations (Shrout & Fleiss 1979 forms) of a fully crossed long-format table.

    Returns one row per form: ``form`` (e.g. 'ICC(2,1)'), ``pingouin_type``,
    ``description``, ``icc``, ``ci_low``, ``ci_high`` (95 %, unrounded), ``F``, ``df1``,
    ``df2``, ``p``.  Targets without a rating from every rater are dropped.
    """
    import warnings

    import pingouin as pg

    saved = pg.options.get("round.column.CI95")
    pg.options["round.column.CI95"] = None        # pingouin rounds the CI to 2 decimals by default
    try:
        with warnings.catch_warnings():           # pingouin's own pandas deprecation (dropna inplace)
            warnings.filterwarnings("ignore", message="The inplace keyword")
            res = pg.intraclass_corr(data=data, targets=targets, raters=raters, ratings=ratings, nan_policy="omit")
    finally:
        pg.options["round.column.CI95"] = saved
    rows = []
    for r in res.to_dict("records"):
        form, desc = ICC_FORMS[r["Type"]]
        ci = np.asarray(r["CI95"], float)
        rows.append({"form": form, "pingouin_type": r["Type"], "description": desc, "icc": float(r["ICC"]),
                     "ci_low": float(ci[0]), "ci_high": float(ci[1]), "F": float(r["F"]), "df1": int(r["df1"]),
                     "df2": int(r["df2"]), "p": float(r["pval"])})
    return pd.DataFrame(rows)


ROI_KEYS = ["participant", "side", "level", "quartile"]


def rater_pairs(df: pd.DataFrame, a: tuple[str, int], b: tuple[str, int]) -> pd.DataFrame:
    """Quartile MFI of the same ROIs traced as ``a`` = (rater, trial) and ``b``: columns ROI keys, group, a, b."""
    def pick(rt):
        sel = df[(df["rater"] == rt[0]) & (df["trial"] == rt[1])]
        return sel[ROI_KEYS + ["group", "mfi"]]
    m = pick(a).merge(pick(b).drop(columns="group"), on=ROI_KEYS, suffixes=("_a", "_b"))
    return m.rename(columns={"mfi_a": "a", "mfi_b": "b"}).reset_index(drop=True)


def reliability_designs(rater: str, second_rater: str) -> dict[str, tuple[tuple[str, int], tuple[str, int]]]:
    """Intra: ``rater`` trial 1 vs trial 2; inter: ``rater`` vs ``second_rater``, trial 1 (Sec. 3.3.2)."""
    return {"intra": ((rater, 1), (rater, 2)), "inter": ((rater, 1), (second_rater, 1))}


def reliability_table(df: pd.DataFrame, rater: str, second_rater: str, k: float = 1.96) -> tuple[pd.DataFrame,
                                                                                                  dict]:
    """Bland-Altman and ICC(2,1) for intra- and inter-rater pairs.

    Returns (table, pairs): one table row per design with n_pairs, n_participants,
    the Bland-Altman fields and ICC(2,1) with its 95 % CI; ``pairs[design]`` is the
    paired data used (empty when the data hold no re-tracings, the row then says so).
    """
    rows, pairs = [], {}
    for design, (a, b) in reliability_designs(rater, second_rater).items():
        p = rater_pairs(df, a, b)
        pairs[design] = p
        row = {"design": design, "a": f"rater {a[0]} trial {a[1]}", "b": f"rater {b[0]} trial {b[1]}",
               "n_pairs": len(p), "n_participants": int(p["participant"].nunique()) if len(p) else 0}
        if len(p) >= 3:
            row.update(bland_altman(p["a"], p["b"], k=k).as_dict())
            long = pd.concat([pd.DataFrame({"roi": p.index, "who": "a", "mfi": p["a"]}),
                              pd.DataFrame({"roi": p.index, "who": "b", "mfi": p["b"]})])
            ic = icc(long, "roi", "who", "mfi").set_index("form").loc["ICC(2,1)"]
            row.update({"icc21": ic["icc"], "icc21_ci_low": ic["ci_low"], "icc21_ci_high": ic["ci_high"],
                        "note": ""})
        else:
            row["note"] = "fewer than 3 paired ROI quartiles in the data: not computed"
        rows.append(row)
    return pd.DataFrame(rows), pairs
