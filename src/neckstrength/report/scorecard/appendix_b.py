"""Appendix B scorers: Table B.1 (moment arms of the full model) and Tables B.3/B.5/B.7 (reduced-model
strengths and moment arms), with the calibrated degrees of freedom of the B.3-recovered strengths and the
erratum cells placed by our derivation (by construction).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pandas as pd

from neckstrength.report.scorecard.rows import B_TABLES, GROUPING_FILES, Context, _key, _read, _row, _sign
from neckstrength.report.scorecard.settings import ScorecardSettings
from neckstrength.report.scorecard.tolerances import (
    BY_CONSTRUCTION,
    CALIBRATED,
    INDEPENDENT,
    PRINT_UNIT,
    _fmt,
    _num,
    _tol_text,
)


def recovered_strengths(settings: ScorecardSettings) -> dict[str, dict]:
    """Muscles whose strength was recovered from Table B.3 in this configuration (name -> record of
    ``b3_implied_strengths.csv``); empty with ``model.unprinted_strengths: osim``."""
    if settings.unprinted_strengths != "b3_implied":
        return {}
    path = Path(settings.model_dir) / "b3_implied_strengths.csv"
    if not path.exists():
        return {}
    df = _read(path)
    return {_key(r["name"]): r for r in df.to_dict("records")}


def supplemented_groups(settings: ScorecardSettings, model: str) -> dict[str, str]:
    """Groups of ``model`` whose membership an applied supplement with basis 'fit' changes (a row of
    ``grouping_supplements.csv`` that exists only to reproduce a printed value; applied with
    ``model.grouping_supplements: all``): group (as named in the printed grouping table) -> the supplements.
    Supplements justified by the printed tables or by anatomy (basis 'printed' / 'anatomy') calibrate nothing."""
    from neckstrength.model.reduction import supplement_level

    level = supplement_level(settings.grouping_supplements)
    if level != "all":
        return {}
    thesis_dir = Path(settings.thesis_dir)
    path = thesis_dir / "grouping_supplements.csv"
    if not path.exists():
        return {}
    sup = _read(path)
    sup = sup[(sup["model"] == model) & (sup["basis"] == "fit")] if "basis" in sup else sup.iloc[:0]
    printed = {}
    if (thesis_dir / GROUPING_FILES.get(model, "-")).exists():
        g = _read(thesis_dir / GROUPING_FILES[model])
        printed = {_key(r["muscle"]): str(r["group"]) for r in g.to_dict("records")}
    out: dict[str, list[str]] = {}
    for r in sup.to_dict("records"):
        grp = r["group"] if r["action"] == "add" and isinstance(r["group"], str) else printed.get(_key(r["muscle"]))
        if grp:
            out.setdefault(grp, []).append(f"{r['action']} {r['muscle']}")
    return {g: ", ".join(v) for g, v in out.items()}


def _group_calibration(ctx: Context, model: str, groups: pd.DataFrame | None) -> dict[str, tuple[int, str]]:
    """Per group of a named model: (number of its items that are calibrated, why); -1 = all of them."""
    rec = recovered_strengths(ctx.settings)
    sup = supplemented_groups(ctx.settings, model)
    out = {}
    if groups is None:
        if rec or sup:
            raise FileNotFoundError(f"{ctx.rel}: groups.csv beside it is needed to tell calibrated from independent "
                                    "items (recovered strengths / supplements are in use)")
        return out
    for r in groups.to_dict("records"):
        g = str(r["group"])
        members = [m.strip() for m in str(r.get("members", "")).split(";") if m.strip()]
        recm = [m for m in members if _key(m) in rec]
        base = re.sub(r"-[RL]$", "", g)
        why = []
        if recm:
            why.append(f"{len(recm)} of its {len(members)} member strengths recovered from Table B.3 "
                       f"({', '.join(recm)})")
        if base in sup or g in sup:
            why.append(f"membership edited by grouping_supplements.csv only to reproduce the printed table "
                       f"(basis 'fit': {sup.get(base, sup.get(g))})")
        if not why:
            continue
        if model == "s3m24" and recm and not (base in sup or g in sup):
            # Table B.3 is what the strengths were solved from: as many items as unknowns are calibrated
            out[g] = (len(recm), "; ".join(why))
        else:
            out[g] = (-1, "; ".join(why) + (
                "; Table B.3 fixes the recovered strengths, so this table's numbers follow from the same printed "
                "values" if recm else ""))
    return out


def score_b_params(ctx: Context) -> list[dict]:
    model = ctx.match["model"]
    src = f"{B_TABLES.get(model, 'Table B.x')} ({model})"
    df = _read(ctx.path)
    groups_csv = ctx.path.parent / "groups.csv"
    n_members = {}
    groups = None
    if groups_csv.exists():
        groups = _read(groups_csv)
        n_members = dict(zip(groups["group"], groups["n_members"]))
    calib = _group_calibration(ctx, model, groups)
    ts, ta = ctx.tols["b_strength_N"], ctx.tols["b_moment_arm_m"]
    st = df[df["quantity"] == "strength_N"]
    reasons = ("print", "inputs")
    rows = []
    for r in df.to_dict("records"):
        g, q = r["group"], r["quantity"]
        t, o = _num(r["thesis"]), _num(r["ours"])
        n = int(n_members.get(g, 1))
        blank = isinstance(r.get("note"), str) and "blank" in r["note"]
        d = o - t
        if q == "strength_N":
            tol = ts.value * (1 + math.sqrt(n))
            tol_txt = _tol_text(ts, f"|d| <= {ts.value:g}*(1+sqrt({n})) = {tol:.3g} N (print + input rounding)")
            concl = f"same rank among the {len(st)} group strengths"
            item = f"{g} strength (N)"
            test, aux, unit = "group_strength_rank", (math.nan, math.nan), PRINT_UNIT["strength_N"]
        else:
            tol = ta.value * (1 + math.sqrt(n))
            if blank and abs(o) <= tol:
                continue  # blank printed cell (no arm about this joint) and ours zero: nothing printed to score
            tol_txt = _tol_text(ta, f"|d| <= {ta.value:g}*(1+sqrt({n})) = {tol:.2g} m (print + input rounding)")
            concl = f"same sign of the moment arm: thesis {_sign(t, tol):+d}, ours " + (
                "-" if math.isnan(o) else f"{_sign(o, tol):+d}")
            item = f"{g} {q.replace(' (m)', '').replace('_', ' ')} moment arm (m)"
            test, aux, unit = "moment_arm_sign", (tol, math.nan), PRINT_UNIT["moment_arm_m"]
        within = not math.isnan(d) and abs(d) <= tol * (1 + 1e-9)
        resid = abs(d) / unit if not math.isnan(d) else math.nan
        row = _row("Appendix B", src, item + (" [blank in thesis]" if blank else ""), "" if blank else _fmt(t),
                   _fmt(o), d, within, tol_txt, concl, reasons, ctx.rel, test=test, tv=0.0 if blank else t, ov=o,
                   aux=aux, stratum="", basis=f"group strengths from Table B.1 as printed; moment arms derived "
                                             f"from the public OpenSim model; residual {resid:.2f} print units")
        row["_group"], row["_resid"], row["_q"] = g, resid, q
        rows.append(row)
    # degrees of freedom: per calibrated group, its strength and the (k - 1) best-fitting moment arms are calibrated
    for g, (k, why) in calib.items():
        mine = [r for r in rows if r["_group"] == g]
        if k < 0:
            chosen = mine
        else:
            st_rows = [r for r in mine if r["_q"] == "strength_N"]
            arms = sorted([r for r in mine if r["_q"] != "strength_N"], key=lambda r: r["_resid"])
            chosen = (st_rows + arms)[:k]
        for r in mine:
            if r in chosen:
                r["kind"] = CALIBRATED
                r["basis"] = (why + (f"; one of the {k} items counted for the {k} strengths solved from this group "
                                     f"(residual {r['_resid']:.2f} print units)" if k > 0 else
                                     f"; residual {r['_resid']:.2f} print units"))
            else:
                r["basis"] = (why + f"; over-determined: {len(mine) - k} printed numbers beyond the {k} solved "
                                    f"for; residual {r['_resid']:.2f} print units")
    for r in rows:
        for k in ("_group", "_resid", "_q"):
            r.pop(k, None)
    return rows


def b1_errata_from_derivation(settings: ScorecardSettings) -> dict[tuple[int, str], str]:
    """Table B.1 cells that the erratum (``errata_B1.csv``, applied with ``model.apply_b1_errata``) relocated or
    inserted because they equal our derived moment arms: (row index, 'joint_axis') -> the erratum's evidence.

    An erratum row counts when it sets a value (``corrected`` not empty) and its evidence cites the derivation
    (the word 'derived'); a relocation justified by another printed table (rows 33/34 from Table B.3) does not.
    Empty without the erratum applied."""
    if not settings.apply_b1_errata:
        return {}
    path = Path(settings.thesis_dir) / "errata_B1.csv"
    if not path.exists():
        return {}
    err = _read(path)
    out = {}
    for r in err.to_dict("records"):
        ev = str(r.get("evidence", ""))
        if not math.isnan(_num(r.get("corrected"))) and re.search(r"derived", ev, re.I):
            out[(int(r["index"]), str(r["field"]))] = ev
    return out


def score_b1(ctx: Context) -> list[dict]:
    df = _read(ctx.path)
    df = df[df["joint"] != "strength"]  # B.1 strengths are inputs (used as printed), not reproduced
    t = ctx.tols["b1_moment_arm_m"]
    errata = b1_errata_from_derivation(ctx.settings)
    rows = []
    for r in df.to_dict("records"):
        th, o = _num(r["thesis_B1"]), _num(r["derived"])
        d = o - th
        within = abs(d) <= t.value * (1 + 1e-6)
        st_, so = _sign(th, t.value), _sign(o, t.value)
        ev = errata.get((int(r["index"]), f"{r['joint']}_{r['axis']}"))
        kind, basis = INDEPENDENT, "derived from the public OpenSim model geometry; nothing fitted to Table B.1"
        if ev is not None:
            kind, basis = BY_CONSTRUCTION, (
                "cell relocated or inserted by the Table B.1 erratum (errata_B1.csv) because it equals our derived "
                f"moment arm ({ev}): agreement by construction")
        rows.append(_row("Appendix B", "Table B.1", f"row {r['index']} {r['name']}: {r['joint']} {r['axis']} moment "
                         "arm (m)", _fmt(th), _fmt(o), d, within,
                         _tol_text(t, f"|d| <= {t.value:g} m (print rounding)"),
                         f"same sign: thesis {st_:+d}, ours {so:+d}", ("print",), ctx.rel, kind=kind,
                         basis=basis, test="moment_arm_sign", tv=th, ov=o, aux=(t.value, math.nan), stratum="B.1"))
    return rows
