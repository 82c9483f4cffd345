"""Per-participant, per-ROI muscle fat infiltration data: schema and validation.

One row per measurement of one region of interest (ROI) quartile: participant,
group, sex, age, BMI, NDI, side, cervical level, quartile, rater, trial, MFI
(thesis Sec. 3.3.2: MFI = IF / (IF + IW), each value the mean of 5 axial slices
spanning the level).  Participant attributes (group, sex, age, BMI, NDI) repeat
on every row of a participant and must agree.  The whole-ROI value of Table 3.2
is not a row: it is derived as the mean of the four quartiles (quartiles hold
equal pixel counts, Sec. 3.3.2).

Example (``# units:`` line optional; when present the units must match)::

    # units: age=years; bmi=kg/m^2; ndi=%; mfi=1
    participant,group,sex,age,bmi,ndi,side,level,quartile,rater,trial,mfi
    P01,WAD,F,31.0,28.2,44,L,C3,Q1,A,1,0.331
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from neckstrength.io import Column, DataValidationError, Schema, read_table

GROUPS = ("Control", "Recovered", "WAD")          # Table 3.2 column order


LEVELS = ("C3", "C4", "C5", "C6", "C7")


QUARTILES = ("Q1", "Q2", "Q3", "Q4")              # Q1 medial .. Q4 lateral (Fig. 3.1)


SIDES = ("L", "R")


SEXES = ("F", "M")


#: Attributes of a participant that must be identical on all of the participant's rows.
PARTICIPANT_FIELDS = ("group", "sex", "age", "bmi", "ndi")


#: One measurement is identified by these fields.
KEY_FIELDS = ("participant", "side", "level", "quartile", "rater", "trial")


MFI_SCHEMA = Schema(
    name="per-ROI muscle fat infiltration (Chapter 3)",
    columns=(
        Column("participant", "str"),
        Column("group", "str", choices=GROUPS),
        Column("sex", "str", choices=SEXES),
        Column("age", "float", "years", 0.0, 120.0),
        Column("bmi", "float", "kg/m^2", 10.0, 80.0),
        Column("ndi", "float", "%", 0.0, 100.0, allow_missing=True),   # blank for controls (Table 3.1)
        Column("side", "str", choices=SIDES),
        Column("level", "str", choices=LEVELS),
        Column("quartile", "str", choices=QUARTILES),
        Column("rater", "str"),
        Column("trial", "int", None, 1, 99),
        Column("mfi", "float", "1", 0.0, 1.0),
    ),
    allow_extra_columns=True,
)


def _line_of(df: pd.DataFrame, row: int) -> int:
    """File line of 1-based data row ``row`` (comment lines, then the header, then data)."""
    return len(df.attrs.get("comments", [])) + 1 + row


def validate_mfi_frame(df: pd.DataFrame, path: str | Path = "<data frame>") -> pd.DataFrame:
    """Cross-row checks on a frame that passed the per-field schema checks.

    - a participant's group, sex, age, BMI and NDI agree on all of its rows;
    - no measurement appears twice (same participant, side, level, quartile, rater, trial).

    Raises :class:`DataValidationError` naming the file, the offending row (and
    line) and the field.  Returns ``df`` unchanged.
    """
    if len(df) == 0:
        raise DataValidationError(path, "no data rows")
    first: dict[str, int] = {}
    records = df.to_dict("records")
    for i, r in enumerate(records):
        p = r["participant"]
        if p not in first:
            first[p] = i
            continue
        r0 = records[first[p]]
        for f in PARTICIPANT_FIELDS:
            a, b = r0.get(f), r.get(f)
            if (a is None or a != a) and (b is None or b != b):   # both missing (None or NaN)
                continue
            if a != b:
                raise DataValidationError(
                    path, f"participant '{p}' has {f} '{b}' here but '{a}' at row {first[p] + 1} "
                    f"(participant attributes must be the same on all of its rows)",
                    i + 1, _line_of(df, i + 1), f)
    seen: dict[tuple, int] = {}
    for i, key in enumerate(zip(*(df[k].tolist() for k in KEY_FIELDS))):
        if key in seen:
            raise DataValidationError(
                path, f"duplicate measurement {dict(zip(KEY_FIELDS, key))} (first at row {seen[key]})",
                i + 1, _line_of(df, i + 1), "trial")
        seen[key] = i + 1
    return df


def read_mfi(path: str | Path) -> pd.DataFrame:
    """Read and validate a per-ROI MFI file (see module docstring for the layout)."""
    df = read_table(path, MFI_SCHEMA)
    validate_mfi_frame(df, path)
    df["trial"] = df["trial"].astype(int)
    return df
