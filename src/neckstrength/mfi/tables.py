"""Table 3.2 regenerated from per-ROI data, and the side-by-side comparison with the thesis's statistics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.io import Column, Schema, read_table
from neckstrength.mfi.schema import GROUPS, LEVELS, QUARTILES

THESIS_STATISTICS_SCHEMA = Schema(
    name="statistics reported in the text of thesis Chapter 3",
    columns=(Column("id", "str"), Column("kind", "str", choices=("loa", "icc", "f_test", "pairwise")),
             Column("what", "str"), Column("bound", "str", allow_missing=True),
             Column("quartile", "str", allow_missing=True), Column("printed", "str"),
             Column("value", "float", allow_missing=True), Column("ci_low", "float", allow_missing=True),
             Column("ci_high", "float", allow_missing=True), Column("df1", "float", allow_missing=True),
             Column("df2", "float", allow_missing=True), Column("p_op", "str", allow_missing=True),
             Column("p_value", "float", allow_missing=True), Column("line", "int")),
    unique=("id",),
)


def read_thesis_statistics(path: str | Path) -> pd.DataFrame:
    return read_table(path, THESIS_STATISTICS_SCHEMA)


def participant_cells(df: pd.DataFrame, rater: str, trial: int = 1) -> pd.DataFrame:
    """Side-averaged MFI per participant x level x quartile (Q1-Q4 and Whole = mean of Q1-Q4)."""
    sel = df[(df["rater"] == rater) & (df["trial"] == trial)]
    cells = sel.groupby(["participant", "group", "level", "quartile"], as_index=False)["mfi"].mean()
    whole = cells.groupby(["participant", "group", "level"], as_index=False)["mfi"].mean()
    whole["quartile"] = "Whole"
    return pd.concat([cells, whole], ignore_index=True)


def table_3_2(df: pd.DataFrame, rater: str, trial: int = 1, thesis: pd.DataFrame | None = None) -> pd.DataFrame:
    """Table 3.2 (mean and between-participant SD of MFI by level x quartile x group) from per-ROI data.

    Each participant contributes the mean of the left and right sides of the
    primary tracing; the whole-ROI value is the mean of its four quartiles.  With
    ``thesis`` (data/thesis/table_3_2_mfi.csv), the printed values and the
    differences ours - thesis are added.  Rows in the thesis's order (C7..C3).
    """
    cells = participant_cells(df, rater, trial)
    g = cells.groupby(["level", "quartile", "group"])["mfi"]
    out = pd.DataFrame({"n": g.count(), "mfi_mean": g.mean(), "mfi_sd": g.std(ddof=1)}).reset_index()
    order = {(lvl, q, grp): i for i, (lvl, q, grp) in enumerate(
        (lvl, q, grp) for lvl in reversed(LEVELS) for q in QUARTILES + ("Whole",) for grp in GROUPS)}
    out["_o"] = [order.get(k, len(order)) for k in zip(out["level"], out["quartile"], out["group"])]
    out = out.sort_values("_o").drop(columns="_o").reset_index(drop=True)
    if thesis is not None:
        t = thesis.rename(columns={"mfi_mean": "thesis_mean", "mfi_sd": "thesis_sd"})
        out = out.merge(t[["level", "quartile", "group", "thesis_mean", "thesis_sd"]],
                        on=["level", "quartile", "group"], how="left")
        out["diff_mean"] = out["mfi_mean"] - out["thesis_mean"]
        out["diff_sd"] = out["mfi_sd"] - out["thesis_sd"]
    return out


def _p_text(op, p) -> str:
    if op == "ns":
        return "n.s. (p > 0.05)"
    if p is None or (isinstance(p, float) and np.isnan(p)):
        return ""
    return f"p {op} {p:g}"


def _thesis_significant(op, p, alpha: float) -> bool | None:
    if op == "ns":
        return False
    if p is None or np.isnan(p):
        return None
    return bool(p <= alpha)        # 'p = x' or 'p < x': significant when x <= alpha


def compare_with_thesis(thesis_stats: pd.DataFrame, reliability: pd.DataFrame, wald: pd.DataFrame,
                        pairwise: pd.DataFrame, table32: pd.DataFrame, source: str,
                        alpha: float = 0.05) -> pd.DataFrame:
    """One row per statistic the thesis reports, with ours beside it.

    ``source`` describes where our numbers come from (e.g. 'SYNTHETIC cohort, seed
    ...'); it is repeated on every row so that no number is read without it.
    """
    rel = reliability.set_index("design")
    wt = wald.set_index("effect")
    pw = pairwise.set_index(["contrast", "quartile"])
    rows = []
    for r in thesis_stats.to_dict("records"):
        row = {"id": r["id"], "kind": r["kind"], "statistic": "", "thesis_printed": r["printed"],
               "thesis_value": r["value"], "thesis_ci_low": r["ci_low"], "thesis_ci_high": r["ci_high"],
               "thesis_df": "", "thesis_p": _p_text(r["p_op"], r["p_value"]), "ours_value": np.nan,
               "ours_ci_low": np.nan, "ours_ci_high": np.nan, "ours_df": "", "ours_p": np.nan,
               "ours_method": "", "thesis_significant": None, "ours_significant": None, "source_line": r["line"]}
        k = r["kind"]
        if k == "loa":
            row["statistic"] = f"{r['what']}-rater 95% limit of agreement, {r['bound']}"
            if r["what"] in rel.index and "lower" in rel.columns and not pd.isna(rel.loc[r["what"], "lower"]):
                x = rel.loc[r["what"]]
                b = r["bound"]
                row.update(ours_value=x[b], ours_ci_low=x[f"{b}_ci_low"], ours_ci_high=x[f"{b}_ci_high"],
                           ours_method=f"bias {x['bias']:+.4f} +- {x['k']:g} SD (SD {x['sd']:.4f}), "
                                       f"n = {int(x['n'])} ROI quartiles of {int(x['n_participants'])} "
                                       "participants; CI: Bland & Altman 1986")
            else:
                row["ours_method"] = "no re-tracings in the data"
        elif k == "icc":
            row["statistic"] = f"{r['what']}-rater ICC(2,1)"
            if r["what"] in rel.index and "icc21" in rel.columns and not pd.isna(rel.loc[r["what"], "icc21"]):
                x = rel.loc[r["what"]]
                row.update(ours_value=x["icc21"], ours_ci_low=x["icc21_ci_low"], ours_ci_high=x["icc21_ci_high"],
                           ours_method="pingouin ICC(A,1): two-way random, absolute agreement, single rater")
            else:
                row["ours_method"] = "no re-tracings in the data"
        elif k == "f_test":
            row["statistic"] = f"F test: {r['what']}"
            row["thesis_df"] = f"{r['df1']:g}, {r['df2']:g}"
            row["thesis_significant"] = _thesis_significant(r["p_op"], r["p_value"], alpha)
            if r["what"] in wt.index:
                x = wt.loc[r["what"]]
                row.update(ours_value=x["F_wald"], ours_df=f"{int(x['df'])}, inf", ours_p=x["p_chi2"],
                           ours_method=f"Wald chi2({int(x['df'])}) = {x['chi2']:.2f}; F_wald = chi2/df; p from "
                                       "chi2 (no Satterthwaite df in statsmodels)",
                           ours_significant=bool(x["p_chi2"] <= alpha))
        elif k == "pairwise":
            row["statistic"] = f"pairwise {r['what']} in {r['quartile']} (Bonferroni)"
            row["thesis_df"] = "" if pd.isna(r["df2"]) else f"{r['df2']:g}"
            row["thesis_significant"] = _thesis_significant(r["p_op"], r["p_value"], alpha)
            key = (r["what"], r["quartile"])
            if key in pw.index:
                x = pw.loc[key]
                row.update(ours_value=x["difference"], ours_ci_low=np.nan, ours_ci_high=np.nan, ours_df="inf",
                           ours_p=x["p_bonferroni"],
                           ours_method=f"EMM difference (MFI), Wald z = {x['z']:.2f}, "
                                       f"Bonferroni x{int(x['n_comparisons'])}",
                           ours_significant=bool(x["p_bonferroni"] <= alpha))
        rows.append(row)
    for r in table32.to_dict("records"):
        if pd.isna(r.get("thesis_mean")):
            continue
        for stat in ("mean", "sd"):
            rows.append({"id": f"t32_{r['level']}_{r['quartile']}_{r['group']}_{stat}", "kind": "table_3_2",
                         "statistic": f"Table 3.2 {r['level']} {r['quartile']} {r['group']} MFI {stat}",
                         "thesis_printed": f"{r[f'thesis_{stat}']:g}", "thesis_value": r[f"thesis_{stat}"],
                         "thesis_ci_low": np.nan, "thesis_ci_high": np.nan, "thesis_df": "", "thesis_p": "",
                         "ours_value": r[f"mfi_{stat}"], "ours_ci_low": np.nan, "ours_ci_high": np.nan,
                         "ours_df": "", "ours_p": np.nan,
                         "ours_method": f"n = {int(r['n'])} participants, side-averaged"
                                        + ("" if r["quartile"] != "Whole" else ", Whole = mean of Q1-Q4"),
                         "thesis_significant": None, "ours_significant": None, "source_line": np.nan})
    out = pd.DataFrame(rows)
    out["difference"] = out["ours_value"] - out["thesis_value"]
    out["significance_agrees"] = [None if (a is None or b is None) else bool(a == b)
                                  for a, b in zip(out["thesis_significant"], out["ours_significant"])]
    out.insert(2, "ours_source", source)
    return out


def data_source_text(data_file: str | None, dataset: str = "real", seed: int | None = None) -> str:
    """Where the Chapter 3 numbers come from, for captions, headers and the comparison table: the data file
    (config ``chapter3.data``, data set name ``chapter3.dataset``) or, when None, the SYNTHETIC cohort of ``seed``."""
    if data_file:
        return f"data file {data_file} (dataset '{dataset}')"
    return (f"SYNTHETIC cohort (neckstrength.mfi.synthetic, seed {seed}), calibrated to thesis "
            "Tables 3.1/3.2 and the reported limits of agreement; NOT the thesis's participants")
