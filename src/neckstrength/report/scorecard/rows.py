"""A scorecard row before its verdict (:func:`_row`), an item not evaluated, the reason text, and the context a
source's loader receives.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import pandas as pd

from neckstrength.report.scorecard.chance import CONCLUSION_TESTS
from neckstrength.report.scorecard.settings import ScorecardSettings
from neckstrength.report.scorecard.tolerances import INDEPENDENT, MATCHES, NOT_EVALUATED, REASONS, Tolerance, _num


def _row(chapter, source, item, thesis, ours, difference, within, tolerance, conclusion, reason_codes, file, *,
         kind=INDEPENDENT, basis="", test="", tv=math.nan, ov=math.nan, aux=(math.nan, math.nan), stratum="",
         always=()) -> dict:
    """A scorecard row before its verdict: ``within`` the tolerance or not, and its conclusion test (``test`` key,
    thesis-side ``tv`` and our ``ov`` values, per-item ``aux`` parameters, permutation ``stratum``)."""
    if test and test not in CONCLUSION_TESTS:
        raise KeyError(f"unknown conclusion test {test!r}")
    return {"chapter": chapter, "source": source, "item": item, "kind": kind, "thesis": thesis, "ours": ours,
            "difference": difference, "verdict": "", "tolerance": tolerance, "conclusion": conclusion, "test": test,
            "chance_rate": math.nan, "reason": "", "basis": basis, "file": str(file),
            "_within": bool(within), "_codes": tuple(reason_codes), "_always": tuple(always), "_test": test,
            "_tv": _num(tv), "_ov": _num(ov), "_aux0": _num(aux[0]), "_aux1": _num(aux[1]),
            "_stratum": f"{file}|{stratum}"}


def _not_evaluated(chapter, source, item, conclusion, file, reason: str, thesis: str = "holds") -> dict:
    """An item this run does not score, with ``reason`` (why: not computed here, or the scorer's error)."""
    r = _row(chapter, source, item, thesis, NOT_EVALUATED, math.nan, False, "", conclusion, (), file)
    r["verdict"], r["reason"] = NOT_EVALUATED, reason
    return r


def _error_text(e: BaseException) -> str:
    """'scorer error: KeyError: 'x'' -- the reason of an item whose scorer raised."""
    return f"scorer error: {type(e).__name__}: {e}"


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
    settings: ScorecardSettings
    tols: Mapping[str, Tolerance]
    match: re.Match
    path: Path
    rel: str  # path as given (relative to the working directory)


B_TABLES = {"s3m24": "Table B.3", "p3m12": "Table B.5", "p2m7": "Table B.7"}
B_FILES = {"s3m24": "table_B3_params_s3m24.csv", "p3m12": "table_B5_params_p3m12.csv",
           "p2m7": "table_B7_params_p2m7.csv"}
GROUPING_FILES = {"s3m24": "table_B2_groups_s3m24.csv", "p3m12": "table_B4_groups_p3m12.csv",
                  "p2m7": "table_B6_groups_p2m7.csv"}


def _key(name: str) -> str:
    return re.sub(r"\s+", " ", str(name).strip().lower())
