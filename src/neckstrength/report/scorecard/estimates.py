"""Scorer of ABC estimate tables (Chapters 5 and 6): f_c, sigma_c / v_c, D(f_c) and iteration counts beside
the thesis, with their conclusion tests and the by-construction cases (clip limits, the noise-free
ceiling, censored counts).
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.report.scorecard.rows import B_FILES, Context, _read, _row
from neckstrength.report.scorecard.tolerances import BY_CONSTRUCTION, INDEPENDENT, N_PERMUTATIONS, _fmt, _num, _tol_text
from neckstrength.seeds import derive_rng


def _baseline(df: pd.DataFrame, ctx: Context, model: str | None, thesis_table: str | None) -> dict:
    """Printed f_a of the unweakened simulated set ('norm' or 'Sim'), for the Table 5.1 caption claim: from the
    comparison table, else from the thesis table. Raises when neither can be read (the caller turns that into a
    'not evaluated' item with the error as its reason)."""
    fa = df[df["quantity"] == "f_a"]
    for ds in ("norm", "Sim"):
        sub = fa[fa["dataset"] == ds]
        if len(sub):
            return dict(zip(sub["muscle"], sub["thesis"].astype(float)))
    from neckstrength.estimation.datasets import thesis_result_table

    t = thesis_result_table(ctx.settings.thesis_dir, model or "p2m7", thesis_table)
    t = t[(t["quantity"] == "f_a") & t["dataset"].isin(["norm", "Sim"])]
    return dict(zip(t["group"], t["value_numeric"].astype(float)))


def _printed_group_strengths(ctx: Context, model: str | None) -> dict:
    """f_base: the printed baseline group strengths of the model (Table B.3/B.5/B.7; spatial groups by their right
    side), the baseline the thesis bootstraps its prior from (Sec. 5.2.2.1, 6.2)."""
    if model not in B_FILES:
        return {}
    path = Path(ctx.settings.thesis_dir) / B_FILES[model]
    if not path.exists():
        return {}
    t = _read(path)
    out = {}
    for r in t.to_dict("records"):
        g = str(r["group"])
        if g.endswith("-L"):
            continue
        out[re.sub(r"-R$", "", g)] = _num(r["strength_N"])
    return out


def _spearman_perm(a: np.ndarray, b: np.ndarray, rng: np.random.Generator, n: int = N_PERMUTATIONS) -> tuple[float, float]:
    """Spearman rank correlation and its one-sided permutation p-value (share of permutations at least as high)."""
    from scipy.stats import rankdata

    ok = ~np.isnan(a) & ~np.isnan(b)
    a, b = rankdata(a[ok]), rankdata(b[ok])
    if len(a) < 3:
        return math.nan, math.nan
    rho = float(np.corrcoef(a, b)[0, 1])
    hits = sum(float(np.corrcoef(a, rng.permutation(b))[0, 1]) >= rho - 1e-12 for _ in range(n))
    return rho, (hits + 1) / (n + 1)


def _score_estimates(ctx: Context, chapter: str, source: str, model: str | None,
                     thesis_table: str | None) -> list[dict]:
    df = _read(ctx.path)
    tc, tab = (ctx.tols[k] for k in ("estimate_rel", "identified_sigma"))
    eps_d = float(ctx.settings.eps_D)
    clip = [float(x) for x in ctx.settings.sigma_clip]
    thesis_col = "thesis" if "thesis" in df.columns else "thesis_value"
    ours_col = "ours" if "ours" in df.columns else "ours_value"
    if thesis_col not in df.columns or ours_col not in df.columns:
        raise ValueError(f"{ctx.rel}: a comparison table needs columns 'thesis' and 'ours' (has {list(df.columns)})")
    for c in ("dataset", "quantity", "muscle"):
        if c not in df.columns:
            df[c] = ""
    df["muscle"] = df["muscle"].astype(object).fillna("")
    df["_t"] = pd.to_numeric(df[thesis_col], errors="coerce")
    df["_o"] = pd.to_numeric(df[ours_col], errors="coerce")
    df = df[df["_t"].notna()].copy()  # only cells the thesis prints (e.g. Table 6.1 has no 'norm'/'weak' rows)
    f_base = _printed_group_strengths(ctx, model)
    simulated = set(df.loc[df["quantity"] == "f_a", "dataset"])
    fa = {(r["dataset"], r["muscle"]): r["_t"] for r in df[df["quantity"] == "f_a"].to_dict("records")}
    fc = {(r["dataset"], r["muscle"]): (r["_t"], r["_o"]) for r in df[df["quantity"] == "f_c"].to_dict("records")}
    seed = int(ctx.settings.seed)
    rank_text: dict = {}

    def participant_rank(ds):  # Spearman of f_c / f_base across the data set's groups, permutation p-value
        if ds not in rank_text:
            ms = [m for (d, m) in fc if d == ds and m in f_base and f_base[m] > 0]
            a = np.array([fc[(ds, m)][0] / f_base[m] for m in ms])
            b = np.array([fc[(ds, m)][1] / f_base[m] for m in ms])
            rho, p = _spearman_perm(a, b, derive_rng(seed, f"scorecard/rank/{ctx.rel}|{ds}"))
            rank_text[ds] = f"; across the {len(ms)} groups of {ds}: Spearman rho {rho:.2f}, permutation p {p:.3f}"
        return rank_text[ds]

    rows = []
    for r in df.to_dict("records"):
        ds, q, m, th, o = r["dataset"], r["quantity"], r["muscle"], r["_t"], r["_o"]
        if q == "f_a":
            continue  # simulated 'actual' strengths are inputs, taken from the printed table
        note = str(r.get("note", "") if not pd.isna(r.get("note", "")) else "")
        d = o - th
        reasons = ["random", "q"] + (["geometry"] if ds not in simulated else [])
        label = f"{ds}: {m + ' ' if m else ''}{q}"
        basis = ("estimate from data simulated with the printed f_a (an input, not scored)" if ds in simulated
                 else "estimate from the participant's printed forces (Table A.2, an input)")
        test, tv, ov, aux, stratum = "", math.nan, math.nan, (math.nan, math.nan), ds
        th_txt = _fmt(th)
        kind = INDEPENDENT
        if q == "f_c":
            tol = max(0.5, tc.value * abs(th))
            within = abs(d) <= tol
            if ds in simulated and (ds, m) in fa:
                f_true = fa[(ds, m)]

                def cls(x):
                    return "recovers f_a" if abs(x - f_true) <= tc.value * f_true else (
                        "above f_a" if x > f_true else "below f_a")
                concl = f"same recovery of f_a = {f_true:g} N (within {tc.value:.0%}): thesis {cls(th)}, ours {cls(o)}"
                test, tv, ov, aux = "recovers_f_a", th, o, (f_true, tc.value)
            elif m in f_base and f_base[m] > 0:
                concl = (f"same rank of f_c / f_base (printed baseline {f_base[m]:g} N) among the groups of {ds}"
                         + participant_rank(ds))
                test, tv, ov = "relative_strength_rank", th / f_base[m], o / f_base[m]
            else:
                concl = "no baseline strength for this group: conclusion not available"
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
            lim = _at_clip_limit(th, o, clip) if q == "sigma_c" else None
            if lim is not None:
                kind = BY_CONSTRUCTION
                basis += (f"; both runs at the sigma_c clip limit {lim:g} (chapter5.sigma_clip, Sec. 5.2.2.7): any "
                          "run that reaches the limit matches, so the agreement is by construction")
            cls = lambda s: "-" if math.isnan(s) else ("identified" if s < tab.value else "uncertain")  # noqa: E731
            concl = f"same identification (relative spread < {tab.value:g}): thesis {cls(s_t)}, ours {cls(s_o)}"
            test, tv, ov, aux, stratum = "identification", s_t, s_o, (tab.value, math.nan), q
        elif q == "D_fc":
            t, band = ctx.tols["D_fc_abs"], ctx.tols["D_fc_band"].value
            within = abs(d) <= t.value
            tol_txt = _tol_text(t, f"|d| <= {t.value:g}")
            if ds in simulated and min(th, o) >= 1.0 - t.value:
                kind = BY_CONSTRUCTION
                basis += (f"; noise-free simulated data: the printed f_a fits them exactly (D = 1), and both runs sit "
                          f"at that ceiling (D(f_c) >= {1.0 - t.value:g}), so the agreement is by construction")
            concl = (f"same fit: |d| <= {band:g} or both >= eps_D = {eps_d:g} (thesis {th:.2f}, ours {o:.2f})")
            test, tv, ov, aux, stratum = "D_fc_same_fit", th, o, (band, eps_d), ""
        elif q == "iters":
            t = ctx.tols["iters_rel"]
            cens_t = "thesis did not converge" in note
            cens_o = "ours did not converge" in note
            if cens_t or cens_o:
                # censored: '30+' is the statement 'did not converge within maxIter'
                within = cens_t and cens_o and o >= th
                tol_txt = _tol_text(t, "censored: matches only if both stopped at maxIter without converging")
                if cens_t and cens_o:
                    kind = BY_CONSTRUCTION
                    basis += ("; both runs stopped at maxIter without converging, and our maxIter is copied from "
                              "the thesis (chapter5.settings), so the counts agree by construction; the "
                              "convergence itself is the conclusion column")
            else:
                tol = max(1.0, t.value * abs(th))
                within = abs(d) <= tol
                tol_txt = _tol_text(t, f"|d| <= max(1, {t.value:g} x thesis) = {tol:.3g} (both converged)")
            ct = "did not converge" if cens_t else "converged"
            co = "did not converge" if cens_o else "converged"
            concl = f"same convergence: thesis {ct}, ours {co}"
            test, tv, ov, stratum = "convergence", float(not cens_t), float(not cens_o), ""
            th_txt = f"{_fmt(th)}+" if cens_t else _fmt(th)
            o_txt = f"{_fmt(o, 4)}+" if cens_o else _fmt(o, 4)
        else:  # any other printed quantity: relative tolerance only
            tol = tc.value * abs(th)
            within = abs(d) <= tol
            tol_txt = _tol_text(tc, f"|d| <= {tc.value:g} x thesis")
            concl = "no conclusion test defined for this quantity"
        ours_txt = o_txt if q == "iters" else _fmt(o, 4)
        rows.append(_row(chapter, source, label, th_txt, ours_txt, d, within, tol_txt, concl, reasons, ctx.rel,
                         kind=kind, basis=basis, test=test, tv=tv, ov=ov, aux=aux, stratum=stratum))
    return rows


# sigma_c clip limits of Sec. 5.2.2.7 (config chapter5.sigma_clip)
SIGMA_CLIP = (0.01, 0.3)


def _at_clip_limit(thesis: float, ours: float, clip: Sequence[float]) -> float | None:
    """The clip limit both sigma_c values sit at (the printed one within half a unit of its 0.01 print, ours to
    1e-6), or None."""
    for lim in clip:
        if abs(thesis - lim) <= 0.005 + 1e-12 and abs(ours - lim) <= 1e-6 * max(1.0, abs(lim)):
            return float(lim)
    return None
