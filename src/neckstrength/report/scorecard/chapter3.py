"""Chapter 3 scorers: Sec. 3.4 statistics (limits of agreement, ICCs, F tests, pairwise comparisons) and
Table 3.2 (MFI mean and SD per group x level x quartile).
"""

from __future__ import annotations

import math
import re

from neckstrength.report.scorecard.rows import Context, _read, _row, _sign
from neckstrength.report.scorecard.tolerances import CALIBRATED, INDEPENDENT, _fmt, _num, _tol_text


ICC_CLASSES = ((0.9, "excellent"), (0.75, "good"), (0.5, "moderate"), (-math.inf, "poor"))  # Koo & Li 2016


# Direction of the significant pairwise differences as printed (Sec. 3.4, line 355): WAD higher than recovered and
# control; recovered lower than control.
PAIRWISE_DIRECTION = {"WAD - Recovered": 1, "WAD - Control": 1, "Recovered - Control": -1}


def _icc_class(x: float) -> str:
    return next(name for lo, name in ICC_CLASSES if x > lo)


def _ch3_caveats(ctx: Context) -> tuple[str, ...]:
    return ("synthetic",) if ctx.match["dataset"] == "SYNTHETIC" else ()


def _ch3_kind(ctx: Context) -> tuple[str, str]:
    if ctx.match["dataset"] == "SYNTHETIC":
        return CALIBRATED, ("SYNTHETIC cohort drawn to the printed Table 3.2 means/SDs and limits of agreement "
                            "(the thesis's participant data were never published): agreement shows the "
                            "calibration and the internal consistency of the printed statistics, not a replication")
    return INDEPENDENT, "measured cohort from config chapter3.data"


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
    alpha = float(ctx.settings.mixed_model_alpha)
    synth = _ch3_caveats(ctx)
    cal = ("calibrated",) if synth else ()
    kind, basis = _ch3_kind(ctx)
    src = "Sec. 3.4"
    half = ctx.tols["ci_print_half_unit"]
    kw = dict(kind=kind, basis=basis)
    rows = []
    for r in df.to_dict("records"):
        k = r["kind"]
        th, o = _num(r["thesis_value"]), _num(r["ours_value"])
        if k == "loa":
            lo, hi = _num(r["ours_ci_low"]), _num(r["ours_ci_high"])
            within = not math.isnan(o) and lo - half.value <= th <= hi + half.value
            rows.append(_row("Chapter 3", src, r["statistic"], _fmt(th), f"{_fmt(o, 3)} (95% CI {_fmt(lo, 3)}, "
                             f"{_fmt(hi, 3)})", o - th, within,
                             _tol_text(half, f"printed limit inside our 95% CI +- {half.value:g}"),
                             f"same sign: thesis {_sign(th, 0):+d}, ours {_sign(o, 0) if not math.isnan(o) else 0:+d}",
                             ("random",), ctx.rel, always=synth + cal, test="loa_sign", tv=th, ov=o,
                             aux=(0.0, math.nan), **kw))
        elif k == "icc":
            lo, hi = _num(r["thesis_ci_low"]), _num(r["thesis_ci_high"])
            within = not math.isnan(o) and lo - half.value <= o <= hi + half.value
            ct, co = _icc_class(th), (_icc_class(o) if not math.isnan(o) else "-")
            rows.append(_row("Chapter 3", src, r["statistic"], f"{_fmt(th)} (95% CI {_fmt(lo)}, {_fmt(hi)})",
                             f"{_fmt(o, 3)} (95% CI {_fmt(r['ours_ci_low'], 3)}, {_fmt(r['ours_ci_high'], 3)})",
                             o - th, within, _tol_text(half, f"ours inside the printed 95% CI +- {half.value:g}"),
                             f"same reliability class (Koo & Li 2016): thesis {ct}, ours {co}",
                             ("random",), ctx.rel, always=synth, test="icc_class", tv=th, ov=o, **kw))
        elif k == "f_test":
            t = ctx.tols["f_rel"]
            within = not math.isnan(o) and abs(o - th) <= t.value * abs(th)
            sig_t, sig_o = str(r["thesis_significant"]), str(r["ours_significant"])
            code = {"True": 1.0, "False": 0.0}
            rows.append(_row("Chapter 3", src, r["statistic"], f"F[{r['thesis_df']}] = {_fmt(th)}, {r['thesis_p']}",
                             f"F_wald[{r['ours_df']}] = {_fmt(o, 3)}, p = {_fmt(r['ours_p'], 2)}", o - th, within,
                             _tol_text(t, f"|d| <= {t.value:g} x F"),
                             f"same significance at alpha = {alpha:g}: thesis {sig_t}, ours {sig_o}",
                             ("random", "satterthwaite"), ctx.rel, always=synth, test="f_significance",
                             tv=code.get(sig_t, math.nan), ov=code.get(sig_o, math.nan), **kw))
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
            # signed significance: +-1 significant in that direction, 0 not significant
            code_t = float(want if want else 1) if sig_t else 0.0
            code_o = float(_sign(o, 0) if not math.isnan(o) else 0) if sig_o else 0.0
            rows.append(_row("Chapter 3", src, r["statistic"], f"{r['thesis_p']}" + (
                f" ({'higher' if want > 0 else 'lower'})" if want and op != "ns" else ""),
                f"p = {_fmt(p_o, 2)} (difference {o:+.3f})", math.nan, within, _tol_text(ctx.tols["p_print"],
                "printed p statement holds, same direction"),
                f"same significance at alpha = {alpha:g} and direction: thesis {sig_t}, ours {sig_o}"
                + ("" if dir_ok else " (direction reversed)"),
                ("random", "satterthwaite"), ctx.rel, always=synth, test="pairwise_significance", tv=code_t,
                ov=code_o, **kw))
    return rows


def score_table_3_2(ctx: Context) -> list[dict]:
    df = _read(ctx.path)
    df = df[df["thesis_mean"].notna()]
    t = ctx.tols["sampling_z"]
    synth = _ch3_caveats(ctx)
    cal = ("calibrated",) if synth else ()
    kind, basis = _ch3_kind(ctx)
    rows = []
    for stat in ("mean", "sd"):
        for i, r in df.iterrows():
            n = int(r["n"])
            sd = float(r["thesis_sd"])
            se = sd / math.sqrt(n) if stat == "mean" else sd / math.sqrt(2 * (n - 1))
            th, o = float(r[f"thesis_{stat}"]), float(r[f"mfi_{stat}"])
            within = abs(o - th) <= t.value * se
            rows.append(_row("Chapter 3", "Table 3.2", f"{r['level']} {r['quartile']} {r['group']} MFI {stat}",
                             _fmt(th), _fmt(o, 3), o - th, within,
                             _tol_text(t, f"|d| <= {t.value:g} SE = {t.value * se:.3g} (n = {n})"),
                             f"same rank of {r['group']} among the 3 groups at {r['level']} {r['quartile']}",
                             ("random",), ctx.rel, always=synth + cal, kind=kind, basis=basis,
                             test="table_3_2_rank", tv=th, ov=o, stratum=f"{stat}|{r['level']}|{r['quartile']}"))
    return rows
