"""Building the scorecard: every registered table's rows, each conclusion test's chance rate on the run's own
items, then each row's verdict; the summary per chapter, kind and verdict, the headline and the header.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import pandas as pd

from neckstrength.report.scorecard.chance import CONCLUSION_TESTS, chance_rates
from neckstrength.report.scorecard.rows import Context, _reason
from neckstrength.report.scorecard.settings import ScorecardSettings
from neckstrength.report.scorecard.sources import source_for
from neckstrength.report.scorecard.tolerances import (
    BY_CONSTRUCTION,
    CALIBRATED,
    CHAPTER_ORDER,
    COLUMNS,
    DIFFERS,
    INDEPENDENT,
    KINDS,
    MATCHES,
    NOT_EVALUATED,
    SAME_CONCLUSION,
    VERDICTS,
    Tolerance,
    tolerances,
)


def _finalize(df: pd.DataFrame, tols: Mapping[str, Tolerance], seed: int) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Chance rate of every conclusion test on these rows, then each row's verdict, conclusion note and reason."""
    cmax = tols["conclusion_chance_max"].value
    live = df[df["verdict"] != NOT_EVALUATED]
    chance = chance_rates(live, seed)
    rate = dict(zip(chance["test"], chance["chance_rate"]))
    verdicts, notes, reasons, rates = [], [], [], []
    for r in df.to_dict("records"):
        if r["verdict"] == NOT_EVALUATED:
            verdicts.append(NOT_EVALUATED), notes.append(r["conclusion"]), reasons.append(r["reason"])
            rates.append(math.nan)
            continue
        key = r["_test"]
        c = rate.get(key, math.nan) if key else math.nan
        usable = bool(key) and not math.isnan(c) and c <= cmax
        same = usable and bool(r["_agree"])
        v = MATCHES if r["_within"] else (SAME_CONCLUSION if same else DIFFERS)
        note = r["conclusion"]
        if key:
            note += (f" [chance rate {c:.2f}]" if usable else
                     f" [not a conclusion test here: chance rate {c:.2f} > {cmax:g}; the row can only match or differ]")
        always = (("construction",) if r["kind"] == BY_CONSTRUCTION else ()) + tuple(r["_always"])
        verdicts.append(v), notes.append(note), reasons.append(_reason(v, r["_codes"], always)), rates.append(c)
    df = df.assign(verdict=verdicts, conclusion=notes, reason=reasons, chance_rate=rates)
    return df, chance


def _agreement(df: pd.DataFrame) -> pd.Series:
    """Observed agreement of each row's conclusion test (vectorised per test: ranks need the whole stratum)."""
    out = pd.Series(False, index=df.index)
    for key in CONCLUSION_TESTS:
        sub = df[(df["_test"] == key) & (df["verdict"] != NOT_EVALUATED)]
        if len(sub):
            ok = CONCLUSION_TESTS[key].agree(sub["_tv"].to_numpy(float), sub["_ov"].to_numpy(float),
                                             sub[["_aux0", "_aux1"]].to_numpy(float),
                                             sub["_stratum"].astype(str).to_numpy())
            out[sub.index] = ok
    return out


def build_scorecard(paths: Iterable[str], settings: ScorecardSettings,
                    overrides: Mapping[str, float] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Score every registered comparison table among ``paths``.

    Returns ``(scorecard, not_evaluated)``: scored rows (verdict in :data:`VERDICTS`, kind in :data:`KINDS`) and the
    items this configuration could not evaluate. ``scorecard.attrs["chance"]`` holds the chance rate of every
    conclusion test (:func:`chance_rates`), for :func:`tolerance_table`.
    """
    tols = tolerances(overrides)
    rows: list[dict] = []
    for p in paths:
        hit = source_for(str(p))
        if not hit:
            continue
        s, m = hit
        rows += s.loader(Context(settings=settings, tols=tols, match=m, path=Path(p), rel=str(p)))
    return score_rows(rows, settings, overrides)


def score_rows(rows: Sequence[dict], settings: ScorecardSettings,
               overrides: Mapping[str, float] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Verdicts of loader rows (:func:`_row`): chance rate of each conclusion test on these rows, then per row
    matches / same conclusion (only by a test whose chance rate is small) / differs."""
    tols = tolerances(overrides)
    df = pd.DataFrame(list(rows))
    if not len(df):
        empty = pd.DataFrame(columns=COLUMNS)
        empty.attrs["chance"] = chance_rates(pd.DataFrame(columns=["_test"]))
        return empty, empty.copy()
    df["_agree"] = _agreement(df)
    df, chance = _finalize(df, tols, int(settings.seed))
    order = {c: i for i, c in enumerate(CHAPTER_ORDER)}
    df["_o"] = df["chapter"].map(lambda c: order.get(c, len(order)))
    df = df.sort_values("_o", kind="stable").reset_index(drop=True)
    df = df[COLUMNS]
    skipped = df[df["verdict"] == NOT_EVALUATED].reset_index(drop=True)
    scored = df[df["verdict"] != NOT_EVALUATED].reset_index(drop=True)
    bad = set(scored["verdict"]) - set(VERDICTS)
    if bad:
        raise AssertionError(f"invalid verdicts {bad}")
    if set(scored["kind"]) - set(KINDS):
        raise AssertionError(f"invalid kinds {set(scored['kind']) - set(KINDS)}")
    scored.attrs["chance"] = chance
    return scored, skipped


SUMMARY_COLUMNS = ["chapter", "kind", "items", "matches", "same_conclusion", "differs", "not_evaluated"]


def summarize(scored: pd.DataFrame, skipped: pd.DataFrame | None = None) -> pd.DataFrame:
    """Counts per chapter, kind (independent, calibrated, by construction) and verdict, items not evaluated (on the
    chapter's independent row: claims this configuration cannot check and scorer errors), and totals per kind
    (chapter 'all'). Narrow on purpose (the report's front page shows it)."""
    skipped = skipped if skipped is not None else pd.DataFrame(columns=COLUMNS)
    chapters = [c for c in CHAPTER_ORDER if c in set(scored["chapter"]) | set(skipped["chapter"])]
    chapters += sorted((set(scored["chapter"]) | set(skipped["chapter"])) - set(chapters))
    rows = []
    for c in chapters + ["all"]:
        for kind in KINDS:
            sc = scored if c == "all" else scored[scored["chapter"] == c]
            sc = sc[sc["kind"] == kind]
            sk = skipped if c == "all" else skipped[skipped["chapter"] == c]
            counts = {v: int((sc["verdict"] == v).sum()) for v in VERDICTS}
            rows.append({"chapter": c, "kind": kind, "items": len(sc), "matches": counts[MATCHES],
                         "same_conclusion": counts[SAME_CONCLUSION], "differs": counts[DIFFERS],
                         "not_evaluated": len(sk) if kind == INDEPENDENT else 0})
    return pd.DataFrame(rows, columns=SUMMARY_COLUMNS)


def headline(summary: pd.DataFrame) -> str:
    """One sentence: independent counts first, calibrated and by-construction counts separately, then the items
    not evaluated. A summary without a kind's rows (written before that kind existed) counts it as zero."""
    s = summary.set_index(["chapter", "kind"])

    def part(kind):
        r = s.loc[("all", kind)] if ("all", kind) in s.index else dict.fromkeys(SUMMARY_COLUMNS[2:], 0)
        return (f"{int(r['items'])} {kind} items: {int(r['matches'])} match, {int(r['same_conclusion'])} same "
                f"conclusion, {int(r['differs'])} differ")
    n_ne = int(summary.loc[summary["chapter"] == "all", "not_evaluated"].sum())
    return (part(INDEPENDENT) + "; " + part(CALIBRATED) + " (calibrated: agreement shows the calibration); "
            + part(BY_CONSTRUCTION) + " (shown, never counted as reproduced); "
            + f"{n_ne} not evaluated")


def _source_family(source: str) -> str:
    """'Table B.3 (s3m24)' -> 'Table B.3'; 'Sec. 4.3.2' -> 'Sec. 4.3'."""
    s = re.sub(r"\s*\(.*\)$", "", source)
    return re.sub(r"^Sec\. (\d+\.\d+)\..*$", r"Sec. \1", s)


def header_lines(settings: ScorecardSettings, tols: Mapping[str, Tolerance]) -> list[str]:
    over = [k for k, t in tols.items() if t.overridden]
    return ["thesis scorecard: every number the thesis prints that we reproduce, ours beside it "
            "(neckstrength.report.scorecard; tolerances, conclusion tests and chance rates: scorecard_tolerances.csv)",
            f"kinds: {' / '.join(KINDS)} (calibrated = an input was fitted or drawn to the thesis numbers that "
            f"determine this one; by construction = the agreement follows from the setup, shown but never counted "
            f"as reproduced); verdicts: {' / '.join(VERDICTS)}; difference = ours - thesis; seed "
            f"{settings.seed}",
            f"model.unprinted_strengths: {settings.unprinted_strengths}; model.grouping_supplements: "
            f"{settings.grouping_supplements}",
            "tolerance overrides from config report.tolerances: " + (", ".join(over) if over else "none")]
