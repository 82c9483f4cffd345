"""Thesis scorecard: every number the thesis prints that the pipeline reproduces, ours beside it, with a verdict.

One row per printed number (or qualitative claim):

    chapter, source, item, thesis, ours, difference, verdict, tolerance, conclusion, reason, file

Verdict classes (:data:`VERDICTS`), decided per row in this order:

``matches``
    ours agrees with the printed value within the tolerance stated for its source (:data:`TOLERANCES`).
``same conclusion, different number``
    outside that tolerance, but the conclusion the thesis draws from the number also holds for ours (each source's
    conclusion test is spelled out in the ``conclusion`` column and in :data:`TOLERANCES`).
``differs``
    neither.

Every tolerance and every conclusion threshold lives in :data:`TOLERANCES`, with its reasoning; none was chosen by
looking at how close our numbers come to the thesis (no tuning).  ``report.tolerances`` in the config may override
a value (key = the :data:`TOLERANCES` key); the reasoning then no longer applies and the tolerance column says so.

Which result files are scored, and how, is the registry :data:`SOURCES`: one entry per kind of comparison table
(regular expression on the path, loader, sibling files it also reads).  A chapter that adds a comparison table adds
one entry here; the Snakemake rule takes its inputs from the pipeline's final outputs filtered by the registry
(:func:`scorecard_inputs`), so nothing else changes.

Not scored, on purpose:

- Table B.1 strengths, Table A.2/A.3 and f_a of the simulated data sets: these are the pipeline's *inputs*
  (printed values used as they are), not numbers it reproduces.
- Blank cells of Tables B.3/B.5/B.7 (no moment arm about that joint) are scored only where ours is not zero.
- Appendix A (Fig. A.4) prints no numbers, only the radar plot.
- Chapter 4 claims that this configuration cannot evaluate (variants not computed) are counted in the summary as
  ``not_evaluated``, not scored.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np
import pandas as pd

MATCHES = "matches"


SAME_CONCLUSION = "same conclusion, different number"


DIFFERS = "differs"


VERDICTS = (MATCHES, SAME_CONCLUSION, DIFFERS)


NOT_EVALUATED = "not evaluated"


COLUMNS = ["chapter", "source", "item", "thesis", "ours", "difference", "verdict", "tolerance", "conclusion",
           "reason", "file"]


CHAPTER_ORDER = ["Appendix B", "Chapter 3", "Chapter 4", "Chapter 5", "Chapter 6"]


@dataclass(frozen=True)
class Tolerance:
    """A tolerance or conclusion threshold: ``kind`` says how ``value`` is used, ``why`` gives the reasoning."""

    value: float
    kind: str      # abs | rel | print | ci | sampling | statement | threshold
    unit: str
    why: str
    overridden: bool = False


TOLERANCES: dict[str, Tolerance] = {
    # ---- Appendix B: model parameters (deterministic; only rounding separates ours from the print)
    "b1_moment_arm_m": Tolerance(
        5e-5, "print", "m",
        "Table B.1 prints moment arms in m to 4 decimals. Ours are derived from the same public OpenSim model "
        "(docs/model_derivation.md), so only print rounding separates them: half a unit of the last printed digit."),
    "b_strength_N": Tolerance(
        0.05, "print", "N",
        "Tables B.3/B.5/B.7 print group strengths to 0.1 N. Our inputs are printed values too (Table B.1 strengths "
        "to 0.1 N; the 32 unprinted rows recovered from B.3), and a group strength is the 2-norm of its n members, "
        "so input rounding contributes up to 0.05*sqrt(n) N and the print another 0.05 N: "
        "tolerance 0.05*(1 + sqrt(n)) N."),
    "b_moment_arm_m": Tolerance(
        5e-5, "print", "m",
        "Group moment arms are printed to 0.1 mm. A group arm is sum(R_i F_i)/F_g over its n members, and our "
        "member arms agree with the thesis's only to print precision (Table B.1: 5e-5 m), so the members "
        "contribute up to 5e-5*sqrt(n) m and the print another 5e-5 m: tolerance 5e-5*(1 + sqrt(n)) m."),
    # ---- Chapters 5 and 6: stochastic estimates
    "estimate_rel": Tolerance(
        0.10, "rel", "",
        "ABC estimates are random (Algorithm 4 draws candidates; our random stream is not the thesis's) and depend "
        "on the rejection percentile q, which the thesis does not state. 10 % is our convention for 'the same "
        "estimate' (a third of the largest sampling spread sigma_max = 0.3 of Sec. 5.2.2.7), with a floor of the "
        "print rounding (0.5 N). Variances (Table 6.1 v_c) get (1 + 0.10)^2 - 1 = 21 %."),
    "sigma_c_abs": Tolerance(
        0.05, "abs", "",
        "sigma_c (relative spread, printed to 0.01, clipped to [0.01, 0.3]) of a random run: 0.05 absolute, a sixth "
        "of the clip range."),
    "D_fc_abs": Tolerance(
        0.01, "abs", "",
        "D(f_c) is printed to 2 decimals; one unit of the last printed digit."),
    "iters_rel": Tolerance(
        0.20, "rel", "",
        "Iteration counts of a random run: 20 % of the printed count (at least 1 iteration)."),
    "identified_sigma": Tolerance(
        0.10, "threshold", "",
        "Conclusion threshold: a group counts as 'identified' when its relative spread sigma_c (or sqrt(v_c)/f_c) "
        "is below 0.1, a third of sigma_max; otherwise 'uncertain' (the thesis reads sigma_c as high / low "
        "confidence, e.g. the Table 5.1 caption)."),
    # ---- Chapter 3: statistics of one cohort (SYNTHETIC unless real data are configured)
    "ci_print_half_unit": Tolerance(
        0.005, "ci", "",
        "Limits of agreement: matches when the printed limit lies inside our 95 % CI of that limit (Bland & "
        "Altman 1986). ICC(2,1): matches when ours lies inside the printed 95 % CI. Either interval is widened by "
        "half a unit of the printed digit (0.005)."),
    "f_rel": Tolerance(
        0.20, "rel", "",
        "F statistics of one cohort of 15 participants: 20 % of the printed F. There is no sampling distribution "
        "to derive this from (F values across synthetic seeds spread over an order of magnitude, "
        "docs/chapter3.md), so 20 % is a strict bar for 'the same number'."),
    "p_print": Tolerance(
        0.0, "statement", "",
        "Pairwise comparisons print only p (and df): matches when ours satisfies the printed statement "
        "('p < x', 'p = x' within half a unit of its last digit, 'no significant difference' = p > alpha) with "
        "the printed direction."),
    "sampling_z": Tolerance(
        2.0, "sampling", "",
        "Table 3.2 cells (mean and SD over n = 5 participants per group): matches within 2 standard errors of "
        "the printed value, SE = SD/sqrt(n) for a mean and SD/sqrt(2(n-1)) for an SD (the printed SD is used)."),
    # ---- Chapter 4: qualitative claims
    "claim": Tolerance(
        0.0, "statement", "",
        "A claim matches when our computed check holds (neckstrength.surfaces.evaluate_claims with the "
        "config chapter4 thresholds) and differs when it does not hold."),
}


# Why a number may differ from the print (joined into the 'reason' column of rows that do not match).
REASONS = {
    "print": "print rounding",
    "inputs": "inputs recovered from printed values (Table B.1 rounding, B.3-implied strengths)",
    "synthetic": "synthetic data: SYNTHETIC cohort (the thesis's per-participant MFI was never published)",
    "calibrated": "synthetic data calibrated to this printed number: agreement shows the calibration, "
                  "not a replication",
    "satterthwaite": "different method: Wald chi-square/z tests without Satterthwaite df (statsmodels; the thesis "
                     "used SPSS)",
    "geometry": "reconstructed geometry: test-point coordinates are not printed (docs/geometry.md)",
    "random": "random estimator: different random stream from the thesis",
    "q": "unspecified parameter: rejection percentile q (90) not stated in the thesis",
    "grouping": "reconstructed grouping: the sagittal groupings are described only in words (docs/model.md)",
}


def tolerances(overrides: Mapping[str, float] | None = None) -> dict[str, Tolerance]:
    """:data:`TOLERANCES` with config overrides (``report.tolerances``) applied and marked."""
    out = dict(TOLERANCES)
    for k, v in (overrides or {}).items():
        if k not in out:
            raise ValueError(f"report.tolerances: unknown key {k!r} (known: {', '.join(sorted(out))})")
        out[k] = replace(out[k], value=float(v), overridden=True)
    return out


def tolerance_table(tols: Mapping[str, Tolerance] | None = None) -> pd.DataFrame:
    tols = tols or TOLERANCES
    return pd.DataFrame([{"key": k, "value": t.value, "kind": t.kind, "unit": t.unit, "overridden": t.overridden,
                          "why": t.why} for k, t in tols.items()])


def _num(x) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return math.nan
    return v


def _fmt(x, sig: int = 5) -> str:
    v = _num(x)
    if math.isnan(v):
        return "" if x is None or (isinstance(x, float) and math.isnan(x)) else str(x)
    return f"{v:.{sig}g}"


def _tol_text(t: Tolerance, text: str) -> str:
    return text + (" (config override)" if t.overridden else "")


def _row(chapter, source, item, thesis, ours, difference, verdict, tolerance, conclusion, reason, file) -> dict:
    return dict(zip(COLUMNS, (chapter, source, item, thesis, ours, difference, verdict, tolerance, conclusion,
                              reason, str(file))))


def _verdict(within: bool, same_conclusion: bool | None) -> str:
    if within:
        return MATCHES
    return SAME_CONCLUSION if same_conclusion else DIFFERS


def _reason(verdict: str, codes: Sequence[str], always: Sequence[str] = ()) -> str:
    """Reasons for a difference (rows that do not match); ``always`` codes are caveats shown on every row."""
    keys = list(always) + ([c for c in codes if c not in always] if verdict != MATCHES else [])
    return "; ".join(REASONS[c] for c in keys)


def _sign(x: float, zero: float) -> int:
    return 0 if abs(x) <= zero else (1 if x > 0 else -1)


def _read(path) -> pd.DataFrame:
    return pd.read_csv(path, comment="#")


@dataclass
class Context:
    config: Mapping
    tols: Mapping[str, Tolerance]
    match: re.Match
    path: Path
    rel: str  # path as given (relative to the working directory)


B_TABLES = {"s3m24": "Table B.3", "p3m12": "Table B.5", "p2m7": "Table B.7"}


def score_b_params(ctx: Context) -> list[dict]:
    model = ctx.match["model"]
    src = f"{B_TABLES.get(model, 'Table B.x')} ({model})"
    df = _read(ctx.path)
    groups_csv = ctx.path.parent / "groups.csv"
    n_members = {}
    if groups_csv.exists():
        g = _read(groups_csv)
        n_members = dict(zip(g["group"], g["n_members"]))
    ts, ta = ctx.tols["b_strength_N"], ctx.tols["b_moment_arm_m"]
    st = df[df["quantity"] == "strength_N"]
    rank_t = st.set_index("group")["thesis"].rank(ascending=False, method="min")
    rank_o = st.set_index("group")["ours"].rank(ascending=False, method="min")
    reasons = ("print", "inputs")
    rows = []
    for r in df.to_dict("records"):
        g, q = r["group"], r["quantity"]
        t, o = _num(r["thesis"]), _num(r["ours"])
        n = int(n_members.get(g, 1))
        blank = isinstance(r.get("note"), str) and "blank" in r["note"]
        if q == "strength_N":
            tol = ts.value * (1 + math.sqrt(n))
            tol_txt = _tol_text(ts, f"|d| <= {ts.value:g}*(1+sqrt({n})) = {tol:.3g} N (print + input rounding)")
            same = (not math.isnan(o)) and rank_t.get(g) == rank_o.get(g)
            concl = (f"same rank among the {len(st)} group strengths: thesis #{int(rank_t.get(g, 0))}, "
                     f"ours #{int(rank_o[g]) if g in rank_o and not math.isnan(rank_o[g]) else '-'}")
            item = f"{g} strength (N)"
        else:
            tol = ta.value * (1 + math.sqrt(n))
            if blank and abs(o) <= tol:
                continue  # blank printed cell (no arm about this joint) and ours zero: nothing printed to score
            tol_txt = _tol_text(ta, f"|d| <= {ta.value:g}*(1+sqrt({n})) = {tol:.2g} m (print + input rounding)")
            st_, so = _sign(t, tol), _sign(o, tol) if not math.isnan(o) else None
            same = so is not None and st_ == so
            concl = (f"same sign of the moment arm (role about the joint): thesis {st_:+d}, ours "
                     f"{'-' if so is None else f'{so:+d}'}")
            item = f"{g} {q.replace(' (m)', '').replace('_', ' ')} moment arm (m)"
        d = o - t
        within = not math.isnan(d) and abs(d) <= tol * (1 + 1e-9)
        v = _verdict(within, same)
        rows.append(_row("Appendix B", src, item + (" [blank in thesis]" if blank else ""),
                         "" if blank else _fmt(t), _fmt(o), d, v, tol_txt, concl,
                         _reason(v, reasons), ctx.rel))
    return rows


def score_b1(ctx: Context) -> list[dict]:
    df = _read(ctx.path)
    df = df[df["joint"] != "strength"]  # B.1 strengths are inputs (used as printed), not reproduced
    t = ctx.tols["b1_moment_arm_m"]
    rows = []
    for r in df.to_dict("records"):
        th, o = _num(r["thesis_B1"]), _num(r["derived"])
        d = o - th
        within = abs(d) <= t.value * (1 + 1e-6)
        st_, so = _sign(th, t.value), _sign(o, t.value)
        v = _verdict(within, st_ == so)
        rows.append(_row("Appendix B", "Table B.1", f"row {r['index']} {r['name']}: {r['joint']} {r['axis']} moment "
                         "arm (m)", _fmt(th), _fmt(o), d, v, _tol_text(t, f"|d| <= {t.value:g} m (print rounding)"),
                         f"same sign: thesis {st_:+d}, ours {so:+d}", _reason(v, ("print",)), ctx.rel))
    return rows


ICC_CLASSES = ((0.9, "excellent"), (0.75, "good"), (0.5, "moderate"), (-math.inf, "poor"))  # Koo & Li 2016


# Direction of the significant pairwise differences as printed (Sec. 3.4, line 355): WAD higher than recovered and
# control; recovered lower than control.
PAIRWISE_DIRECTION = {"WAD - Recovered": 1, "WAD - Control": 1, "Recovered - Control": -1}


def _icc_class(x: float) -> str:
    return next(name for lo, name in ICC_CLASSES if x > lo)


def _ch3_caveats(ctx: Context) -> tuple[str, ...]:
    return ("synthetic",) if ctx.match["dataset"] == "SYNTHETIC" else ()


def _parse_p(text: str):
    """'p < 0.001' -> ('<', 0.001, half-unit); 'p = 0.03' -> ('=', 0.03, 0.005); 'n.s. ...' -> ('ns', nan, nan)."""
    text = str(text or "")
    if text.startswith("n.s."):
        return "ns", math.nan, math.nan
    m = re.match(r"p\s*([<=>])\s*([0-9.]+)", text)
    if not m:
        return "", math.nan, math.nan
    digits = m.group(2).split(".")[1] if "." in m.group(2) else ""
    return m.group(1), float(m.group(2)), 0.5 * 10 ** -len(digits)


def score_ch3_statistics(ctx: Context) -> list[dict]:
    df = _read(ctx.path)
    df = df[df["kind"] != "table_3_2"]  # Table 3.2 cells are scored from table_3_2.csv (with n)
    alpha = float(ctx.config.get("chapter3", {}).get("mixed_model", {}).get("alpha", 0.05))
    synth = _ch3_caveats(ctx)
    cal = ("calibrated",) if synth else ()
    src = "Sec. 3.4"
    half = ctx.tols["ci_print_half_unit"]
    loa = df[df["kind"] == "loa"].set_index("id")

    def width(prefix, col):
        try:
            return float(loa.loc[f"loa_{prefix}_upper", col]) - float(loa.loc[f"loa_{prefix}_lower", col])
        except KeyError:
            return math.nan

    rows = []
    for r in df.to_dict("records"):
        k = r["kind"]
        th, o = _num(r["thesis_value"]), _num(r["ours_value"])
        if k == "loa":
            lo, hi = _num(r["ours_ci_low"]), _num(r["ours_ci_high"])
            within = not math.isnan(o) and lo - half.value <= th <= hi + half.value
            w_t = width("intra", "thesis_value") < width("inter", "thesis_value")
            w_o = width("intra", "ours_value") < width("inter", "ours_value")
            same = not math.isnan(o) and _sign(th, 0) == _sign(o, 0) and w_t == w_o
            v = _verdict(within, same)
            rows.append(_row("Chapter 3", src, r["statistic"], _fmt(th), f"{_fmt(o, 3)} (95% CI {_fmt(lo, 3)}, "
                             f"{_fmt(hi, 3)})", o - th, v,
                             _tol_text(half, f"printed limit inside our 95% CI +- {half.value:g}"),
                             f"same sign and intra narrower than inter: thesis {w_t}, ours {w_o}",
                             _reason(v, ("random",), synth + cal), ctx.rel))
        elif k == "icc":
            lo, hi = _num(r["thesis_ci_low"]), _num(r["thesis_ci_high"])
            within = not math.isnan(o) and lo - half.value <= o <= hi + half.value
            ct, co = _icc_class(th), (_icc_class(o) if not math.isnan(o) else "-")
            v = _verdict(within, ct == co)
            rows.append(_row("Chapter 3", src, r["statistic"], f"{_fmt(th)} (95% CI {_fmt(lo)}, {_fmt(hi)})",
                             f"{_fmt(o, 3)} (95% CI {_fmt(r['ours_ci_low'], 3)}, {_fmt(r['ours_ci_high'], 3)})",
                             o - th, v, _tol_text(half, f"ours inside the printed 95% CI +- {half.value:g}"),
                             f"same reliability class (Koo & Li 2016): thesis {ct}, ours {co}",
                             _reason(v, ("random",), synth), ctx.rel))
        elif k == "f_test":
            t = ctx.tols["f_rel"]
            within = not math.isnan(o) and abs(o - th) <= t.value * abs(th)
            sig_t, sig_o = r["thesis_significant"], r["ours_significant"]
            same = str(sig_t) == str(sig_o) and str(sig_o) in ("True", "False")
            v = _verdict(within, same)
            rows.append(_row("Chapter 3", src, r["statistic"], f"F[{r['thesis_df']}] = {_fmt(th)}, {r['thesis_p']}",
                             f"F_wald[{r['ours_df']}] = {_fmt(o, 3)}, p = {_fmt(r['ours_p'], 2)}", o - th, v,
                             _tol_text(t, f"|d| <= {t.value:g} x F"),
                             f"same significance at alpha = {alpha:g}: thesis {sig_t}, ours {sig_o}",
                             _reason(v, ("random", "satterthwaite"), synth), ctx.rel))
        elif k == "pairwise":
            op, p, h = _parse_p(r["thesis_p"])
            p_o = _num(r["ours_p"])
            contrast = r["statistic"].split(" in ")[0].replace("pairwise ", "")
            want = PAIRWISE_DIRECTION.get(contrast, 0)
            dir_ok = want == 0 or (not math.isnan(o) and _sign(o, 0) == want)
            if op == "<":
                holds = p_o < p
            elif op == "=":
                holds = abs(p_o - p) <= h + 1e-12
            elif op == "ns":
                holds = p_o > alpha
            else:
                holds = False
            sig_t = op != "ns" and (op == "<" or p <= alpha)
            sig_o = p_o <= alpha
            within = holds and (dir_ok or op == "ns")
            same = sig_t == sig_o and (dir_ok or not sig_t)
            v = _verdict(within, same)
            rows.append(_row("Chapter 3", src, r["statistic"], f"{r['thesis_p']}" + (
                f" ({'higher' if want > 0 else 'lower'})" if want and op != "ns" else ""),
                f"p = {_fmt(p_o, 2)} (difference {o:+.3f})", math.nan, v, _tol_text(ctx.tols["p_print"],
                "printed p statement holds, same direction"),
                f"same significance at alpha = {alpha:g} and direction: thesis {sig_t}, ours {sig_o}"
                + ("" if dir_ok else " (direction reversed)"),
                _reason(v, ("random", "satterthwaite"), synth), ctx.rel))
    return rows


def score_table_3_2(ctx: Context) -> list[dict]:
    df = _read(ctx.path)
    df = df[df["thesis_mean"].notna()]
    t = ctx.tols["sampling_z"]
    synth = _ch3_caveats(ctx)
    cal = ("calibrated",) if synth else ()
    rows = []
    for stat in ("mean", "sd"):
        rk_t = df.groupby(["level", "quartile"])[f"thesis_{stat}"].rank(method="min")
        rk_o = df.groupby(["level", "quartile"])[f"mfi_{stat}"].rank(method="min")
        for i, r in df.iterrows():
            n = int(r["n"])
            sd = float(r["thesis_sd"])
            se = sd / math.sqrt(n) if stat == "mean" else sd / math.sqrt(2 * (n - 1))
            th, o = float(r[f"thesis_{stat}"]), float(r[f"mfi_{stat}"])
            within = abs(o - th) <= t.value * se
            same = rk_t[i] == rk_o[i]
            v = _verdict(within, same)
            rows.append(_row("Chapter 3", "Table 3.2", f"{r['level']} {r['quartile']} {r['group']} MFI {stat}",
                             _fmt(th), _fmt(o, 3), o - th, v,
                             _tol_text(t, f"|d| <= {t.value:g} SE = {t.value * se:.3g} (n = {n})"),
                             f"same rank of {r['group']} among the 3 groups at {r['level']} {r['quartile']}: "
                             f"thesis {int(rk_t[i])}, ours {int(rk_o[i])} (1 = lowest)",
                             _reason(v, ("random",), synth + cal), ctx.rel))
    return rows


def score_ch4_claims(ctx: Context) -> list[dict]:
    df = _read(ctx.path)
    c4 = ctx.config.get("chapter4", {})
    t = ctx.tols["claim"]
    rows = []
    for r in df.to_dict("records"):
        verdict = str(r["verdict"])
        if verdict not in ("holds", "does not hold"):
            rows.append(_row("Chapter 4", f"Sec. {r['section']}", r["claim"], "holds", verdict, math.nan,
                             NOT_EVALUATED, "", str(r["numbers"]), "", ctx.rel))
            continue
        v = MATCHES if verdict == "holds" else DIFFERS
        rows.append(_row("Chapter 4", f"Sec. {r['section']}", f"{r['claim']} [{r['variants']}]", "holds", verdict,
                         math.nan, v, _tol_text(t, f"claim check (relative tolerance "
                                                   f"{c4.get('claim_tolerance_rel', '')}, anterior |azimuth| < "
                                                   f"{c4.get('anterior_max_azimuth_deg', '')} deg)"),
                         str(r["numbers"]), _reason(v, ("geometry", "grouping") if "sagittal" in str(r["variants"])
                                                    else ("geometry",)), ctx.rel))
    return rows


def _baseline(df: pd.DataFrame, ctx: Context, model: str | None, thesis_table: str | None) -> dict:
    """Baseline group strengths f_base as printed (f_a of the unweakened simulated set: 'norm' or 'Sim')."""
    fa = df[df["quantity"] == "f_a"]
    for ds in ("norm", "Sim"):
        sub = fa[fa["dataset"] == ds]
        if len(sub):
            return dict(zip(sub["muscle"], sub["thesis"].astype(float)))
    try:
        from neckstrength.estimation.datasets import thesis_result_table

        t = thesis_result_table(ctx.config["data"]["thesis_dir"], model or "p2m7", thesis_table)
        t = t[(t["quantity"] == "f_a") & t["dataset"].isin(["norm", "Sim"])]
        return dict(zip(t["group"], t["value_numeric"].astype(float)))
    except Exception:  # noqa: BLE001 - no baseline: participant conclusions are then not available
        return {}


def _score_estimates(ctx: Context, chapter: str, source: str, model: str | None,
                     thesis_table: str | None) -> list[dict]:
    df = _read(ctx.path)
    tc, tab = (ctx.tols[k] for k in ("estimate_rel", "identified_sigma"))
    eps_d = float(ctx.config.get("chapter5", {}).get("eps_D", 0.95))
    thesis_col = "thesis" if "thesis" in df.columns else "thesis_value"
    ours_col = "ours" if "ours" in df.columns else "ours_value"
    if thesis_col not in df.columns or ours_col not in df.columns:
        raise ValueError(f"{ctx.rel}: a comparison table needs columns 'thesis' and 'ours' (has {list(df.columns)})")
    for c in ("dataset", "quantity", "muscle"):
        if c not in df.columns:
            df[c] = ""
    df["muscle"] = df["muscle"].fillna("")
    df["_t"] = pd.to_numeric(df[thesis_col], errors="coerce")
    df["_o"] = pd.to_numeric(df[ours_col], errors="coerce")
    df = df[df["_t"].notna()].copy()  # only cells the thesis prints (e.g. Table 6.1 has no 'norm'/'weak' rows)
    base = _baseline(df.rename(columns={thesis_col: "thesis"}), ctx, model, thesis_table)
    simulated = set(df.loc[df["quantity"] == "f_a", "dataset"])
    fa = {(r["dataset"], r["muscle"]): r["_t"] for r in df[df["quantity"] == "f_a"].to_dict("records")}
    fc = {(r["dataset"], r["muscle"]): (r["_t"], r["_o"]) for r in df[df["quantity"] == "f_c"].to_dict("records")}

    def rel_weak(ds):  # participant: f_c / f_base relative to the data set's median ratio (scale-free)
        out = {}
        for side in (0, 1):
            ratios = {m: v[side] / base[m] for (d, m), v in fc.items() if d == ds and m in base and base[m] > 0}
            med = float(np.median(list(ratios.values()))) if ratios else math.nan
            out[side] = {m: ("weaker" if r < med else "not weaker") for m, r in ratios.items()}
        return out

    weak_cache: dict = {}
    rows = []
    for r in df.to_dict("records"):
        ds, q, m, th, o = r["dataset"], r["quantity"], r["muscle"], r["_t"], r["_o"]
        if q == "f_a":
            continue  # simulated 'actual' strengths are inputs, taken from the printed table
        note = str(r.get("note", "") if not pd.isna(r.get("note", "")) else "")
        d = o - th
        reasons = ["random", "q"] + (["geometry"] if ds not in simulated else [])
        label = f"{ds}: {m + ' ' if m else ''}{q}"
        if q == "f_c":
            tol = max(0.5, tc.value * abs(th))
            within = abs(d) <= tol
            if ds in simulated and (ds, m) in fa:
                f_true = fa[(ds, m)]

                def cls(x):
                    return "recovers f_a" if abs(x - f_true) <= tc.value * f_true else (
                        "above f_a" if x > f_true else "below f_a")
                ct, co = cls(th), cls(o)
                concl = f"same recovery of f_a = {f_true:g} N (within {tc.value:.0%}): thesis {ct}, ours {co}"
            elif m in base:
                w = weak_cache.setdefault(ds, rel_weak(ds))
                ct, co = w[0].get(m), w[1].get(m)
                concl = (f"same relative strength (f_c/f_base vs the median group of {ds}): thesis {ct}, ours {co}")
            else:
                ct, co, concl = None, None, "no baseline strength for this group: conclusion not available"
            v = _verdict(within, ct is not None and ct == co)
            tol_txt = _tol_text(tc, f"|d| <= max(0.5 N, {tc.value:g} x thesis) = {tol:.3g} N")
            label += " (N)"
        elif q in ("sigma_c", "v_c"):
            if q == "sigma_c":
                t = ctx.tols["sigma_c_abs"]
                tol = t.value
                tol_txt = _tol_text(t, f"|d| <= {tol:g}")
                s_t, s_o = th, o
            else:
                rel = (1 + tc.value) ** 2 - 1
                tol = max(0.5, rel * abs(th))
                tol_txt = _tol_text(tc, f"|d| <= max(0.5, {rel:.2f} x thesis) = {tol:.3g} N^2")
                f_t, f_o = fc.get((ds, m), (math.nan, math.nan))
                s_t = math.sqrt(th) / f_t if th >= 0 and f_t > 0 else math.nan
                s_o = math.sqrt(o) / f_o if o >= 0 and f_o > 0 else math.nan
                label += " (N^2)"
            within = abs(d) <= tol
            cls = lambda s: "-" if math.isnan(s) else ("identified" if s < tab.value else "uncertain")  # noqa: E731
            ct, co = cls(s_t), cls(s_o)
            v = _verdict(within, ct != "-" and ct == co)
            concl = f"same identification (relative spread < {tab.value:g}): thesis {ct}, ours {co}"
        elif q == "D_fc":
            t = ctx.tols["D_fc_abs"]
            within = abs(d) <= t.value
            ct, co = th >= eps_d, o >= eps_d
            v = _verdict(within, ct == co)
            tol_txt = _tol_text(t, f"|d| <= {t.value:g}")
            concl = f"same side of the convergence threshold eps_D = {eps_d:g}: thesis {ct}, ours {co}"
        elif q == "iters":
            t = ctx.tols["iters_rel"]
            tol = max(1.0, t.value * abs(th))
            within = abs(d) <= tol
            ct = "did not converge" if "thesis did not converge" in note else "converged"
            co = "did not converge" if "ours did not converge" in note else "converged"
            v = _verdict(within, ct == co)
            tol_txt = _tol_text(t, f"|d| <= max(1, {t.value:g} x thesis) = {tol:.3g}")
            concl = f"same convergence: thesis {ct}, ours {co}"
        else:  # any other printed quantity: relative tolerance only
            tol = tc.value * abs(th)
            within = abs(d) <= tol
            v = _verdict(within, None)
            tol_txt = _tol_text(tc, f"|d| <= {tc.value:g} x thesis")
            concl = "no conclusion test defined for this quantity"
        th_txt = f"{_fmt(th)}+" if (q == "iters" and "thesis did not converge" in note) else _fmt(th)
        rows.append(_row(chapter, source, label, th_txt, _fmt(o, 4), d, v, tol_txt, concl,
                         _reason(v, reasons), ctx.rel))
    return rows


CH5_TABLES = {"p2m7": "Table 5.1", "p3m12": "Table 5.2", "s3m24": "Table 5.3"}


# Claims printed in a table caption: model -> (data set, group). Table 5.1: "The algorithm was able to identify
# weakness of the deep extensor muscle group (TC-E) in the 'weak' data set, with high confidence."
CH5_CAPTION_CLAIMS = {"p2m7": ("weak", "TC-E")}


def _weakness_claim(ctx: Context, source: str, model: str) -> list[dict]:
    """'weakness of <group> identified in <data set> with high confidence': f_c closer to the weakened f_a than to
    the baseline f_base, and sigma_c below the identification threshold."""
    if model not in CH5_CAPTION_CLAIMS:
        return []
    ds, g = CH5_CAPTION_CLAIMS[model]
    df = _read(ctx.path)
    df["muscle"] = df["muscle"].fillna("")
    cell = {(r["dataset"], r["quantity"], r["muscle"]): (_num(r["thesis"]), _num(r["ours"]))
            for r in df.to_dict("records")}
    need = [(ds, "f_c", g), (ds, "sigma_c", g), (ds, "f_a", g)]
    if not all(k in cell for k in need):
        return []
    base = _baseline(df, ctx, model, None).get(g, math.nan)
    f_a = cell[(ds, "f_a", g)][0]
    thr = ctx.tols["identified_sigma"].value

    def holds(side):
        f, s = cell[(ds, "f_c", g)][side], cell[(ds, "sigma_c", g)][side]
        return bool(abs(f - f_a) < abs(f - base) and s < thr), f, s

    h_t, f_t, s_t = holds(0)
    h_o, f_o, s_o = holds(1)
    v = MATCHES if h_o else DIFFERS
    return [_row("Chapter 5", source.replace(" (", " caption (", 1), f"{ds}: weakness of {g} identified with high confidence",
                 "holds", "holds" if h_o else "does not hold", math.nan, v,
                 _tol_text(ctx.tols["identified_sigma"], f"f_c closer to f_a = {f_a:g} N than to f_base = {base:g} N "
                                                        f"and sigma_c < {thr:g}"),
                 f"thesis f_c {f_t:g} N, sigma_c {s_t:g} ({'holds' if h_t else 'does not hold'} on the printed "
                 f"numbers); ours f_c {f_o:.4g} N, sigma_c {s_o:.3g}", _reason(v, ("random", "q")), ctx.rel)]


def score_ch5(ctx: Context) -> list[dict]:
    model = ctx.match["model"]
    source = f"{CH5_TABLES.get(model, 'Table 5.x')} ({model})"
    return _score_estimates(ctx, "Chapter 5", source, model, None) + _weakness_claim(ctx, source, model)


def score_ch6(ctx: Context) -> list[dict]:
    return _score_estimates(ctx, "Chapter 6", "Table 6.1 (p2m7)", "p2m7", "table_6_1_p2m7_sequential.csv")


@dataclass(frozen=True)
class Source:
    """One kind of comparison table: ``pattern`` (regex on the path), ``loader`` (-> scorecard rows), and sibling
    files the loader also reads (added to the rule's inputs)."""

    key: str
    chapter: str
    pattern: str
    loader: Callable[[Context], list[dict]]
    companions: tuple[str, ...] = field(default=())
    describes: str = ""

    def matches(self, path: str) -> re.Match | None:
        return re.search(self.pattern, str(path).replace("\\", "/"))


SOURCES: tuple[Source, ...] = (
    Source("b_params", "Appendix B", r"(^|/)results/model/(?P<model>p2m7|p3m12|s3m24)/parameters_vs_thesis\.csv$",
           score_b_params, ("groups.csv",), "Tables B.3/B.5/B.7: reduced-model strengths and moment arms"),
    Source("b1", "Appendix B", r"(^|/)results/model/momentarm_vs_B1\.csv$", score_b1,
           describes="Table B.1: moment arms of the full model (strengths are inputs, not scored)"),
    Source("ch3_statistics", "Chapter 3", r"(^|/)results/chapter3/(?P<dataset>[^/]+)/thesis_vs_ours\.csv$",
           score_ch3_statistics, describes="Sec. 3.4: limits of agreement, ICCs, F tests, pairwise comparisons"),
    Source("ch3_table_3_2", "Chapter 3", r"(^|/)results/chapter3/(?P<dataset>[^/]+)/table_3_2\.csv$",
           score_table_3_2, describes="Table 3.2: MFI mean and SD per group x level x quartile"),
    Source("ch4_claims", "Chapter 4", r"(^|/)results/chapter4/claims\.csv$", score_ch4_claims,
           describes="Sec. 4.3-4.4: qualitative claims as computed checks"),
    Source("ch5_tables", "Chapter 5", r"(^|/)results/chapter5/(?P<model>p2m7|p3m12|s3m24)/table_vs_thesis\.csv$",
           score_ch5, describes="Tables 5.1-5.3: ABC estimates f_c, sigma_c, D(f_c), iterations"),
    # Chapter 6 (Table 6.1, p2m7 sequential estimation): any comparison table under results/chapter6/ whose name
    # says it is beside the thesis, in the long format of Chapter 5 (dataset, quantity, muscle, thesis, ours).
    Source("ch6_table", "Chapter 6", r"(^|/)results/chapter6/(.*/)?[^/]*(vs_thesis|thesis_vs|6_1)[^/]*\.csv$",
           score_ch6, describes="Table 6.1: sequential estimation f_c, v_c, D(f_c)"),
)


def source_for(path: str) -> tuple[Source, re.Match] | None:
    for s in SOURCES:
        m = s.matches(path)
        if m:
            return s, m
    return None


def scorecard_inputs(paths: Iterable[str]) -> list[str]:
    """The files among ``paths`` that the registry scores, plus their sibling files (order kept, no duplicates)."""
    out: list[str] = []
    for p in paths:
        hit = source_for(str(p))
        if not hit:
            continue
        s, _ = hit
        for f in [str(p)] + [str(Path(p).parent / c) for c in s.companions]:
            if f not in out:
                out.append(f)
    return out


def build_scorecard(paths: Iterable[str], config: Mapping,
                    overrides: Mapping[str, float] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Score every registered comparison table among ``paths``.

    Returns ``(scorecard, not_evaluated)``: scored rows (verdict in :data:`VERDICTS`) and the items this
    configuration could not evaluate.
    """
    tols = tolerances(overrides)
    rows: list[dict] = []
    for p in paths:
        hit = source_for(str(p))
        if not hit:
            continue
        s, m = hit
        rows += s.loader(Context(config=config, tols=tols, match=m, path=Path(p), rel=str(p)))
    df = pd.DataFrame(rows, columns=COLUMNS)
    order = {c: i for i, c in enumerate(CHAPTER_ORDER)}
    df["_o"] = df["chapter"].map(lambda c: order.get(c, len(order)))
    df = df.sort_values("_o", kind="stable").drop(columns="_o").reset_index(drop=True)
    skipped = df[df["verdict"] == NOT_EVALUATED].reset_index(drop=True)
    scored = df[df["verdict"] != NOT_EVALUATED].reset_index(drop=True)
    bad = set(scored["verdict"]) - set(VERDICTS)
    if bad:
        raise AssertionError(f"invalid verdicts {bad}")
    return scored, skipped


def summarize(scored: pd.DataFrame, skipped: pd.DataFrame | None = None) -> pd.DataFrame:
    """Counts per chapter and verdict (plus items not evaluated in this configuration), and a total row."""
    skipped = skipped if skipped is not None else pd.DataFrame(columns=COLUMNS)
    chapters = [c for c in CHAPTER_ORDER if c in set(scored["chapter"]) | set(skipped["chapter"])]
    chapters += sorted((set(scored["chapter"]) | set(skipped["chapter"])) - set(chapters))
    rows = []
    for c in chapters + ["all"]:
        sc = scored if c == "all" else scored[scored["chapter"] == c]
        sk = skipped if c == "all" else skipped[skipped["chapter"] == c]
        n = len(sc)
        counts = {v: int((sc["verdict"] == v).sum()) for v in VERDICTS}
        rows.append({"chapter": c, "sources": "; ".join(dict.fromkeys(sc["source"].map(_source_family))),
                     "items": n, "matches": counts[MATCHES],
                     "same_conclusion_different_number": counts[SAME_CONCLUSION], "differs": counts[DIFFERS],
                     "share_matches": round(counts[MATCHES] / n, 3) if n else math.nan,
                     "share_same_conclusion_or_better": round((counts[MATCHES] + counts[SAME_CONCLUSION]) / n, 3)
                     if n else math.nan,
                     "not_evaluated": len(sk)})
    return pd.DataFrame(rows)


def _source_family(source: str) -> str:
    """'Table B.3 (s3m24)' -> 'Table B.3'; 'Sec. 4.3.2' -> 'Sec. 4.3'."""
    s = re.sub(r"\s*\(.*\)$", "", source)
    return re.sub(r"^Sec\. (\d+\.\d+)\..*$", r"Sec. \1", s)


def header_lines(config: Mapping, tols: Mapping[str, Tolerance]) -> list[str]:
    over = [k for k, t in tols.items() if t.overridden]
    return ["thesis scorecard: every number the thesis prints that we reproduce, ours beside it "
            "(neckstrength.report.scorecard; tolerances and their reasons: scorecard_tolerances.csv)",
            f"verdicts: {' / '.join(VERDICTS)}; difference = ours - thesis; seed {config.get('seed')}",
            "tolerance overrides from config report.tolerances: " + (", ".join(over) if over else "none")]
