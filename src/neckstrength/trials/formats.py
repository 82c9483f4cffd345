"""The trial table: one row per maximum-effort trial (documented in ``docs/trials.md``).

Columns (CSV, ``#`` comment lines allowed, optional ``# units:`` line checked against the units below):

============== ======== ==================================================================================
column         unit     meaning
============== ======== ==================================================================================
participant    --       participant id (``S003``, ``P01``, ...): becomes a column of the max-force table
direction      --       a configured test direction (``forehead``, ``back``, ...) or a cardinal direction
                        (``extension``, ``flexion``, ``sidebendR``, ``sidebendL``, ``rotationR``,
                        ``rotationL``)
block          --       optional: ``start`` / ``main`` / ``end`` (default ``main``); cardinal directions at
                        the start and end of the session are compared for fatigue
trial          --       trial number within (participant, direction, block), 1, 2, 3 in the order measured
frame          --       frame the six wrench components are in: ``skull`` (C0-C1 origin) or a frame named in
                        the import settings (default ``pad``: axes of the skull frame, origin at the centre of
                        the lower posterior pad)
Mx, My, Mz     N*m      moment of the wrench the head exerts on the device (peak, 100 ms average)
Fx, Fy, Fz     N        force of that wrench
peak_time_s    s        optional: time of the peak wrench in the trial's EMG time base (signals file)
emg_<m>_<s>    any      optional: rectified, filtered EMG envelope 250 ms before the peak wrench; ``m`` in
                        SCM, trap, SSCap, SpCap, LS; ``s`` in R, L; empty = channel not recorded
emgmax_<m>_<s> same     optional: that trial's maximum of the same envelope (the normaliser is the maximum
                        over all trials of the participant); without it, the maximum of ``emg_<m>_<s>``
============== ======== ==================================================================================

Every problem raises :class:`~neckstrength.io.DataValidationError` naming the file, the row (and its line)
and the field, before anything is written.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.io import MEASUREMENT_SCHEMA, Column, DataValidationError, Schema, excerpt, read_table

WRENCH = ("Mx", "My", "Mz", "Fx", "Fy", "Fz")

#: EMG muscles of Appendix A (Table A.1) and sides
EMG_MUSCLES = ("SCM", "trap", "SSCap", "SpCap", "LS")
EMG_SIDES = ("R", "L")
EMG_CHANNELS = tuple(f"{m}_{s}" for m in EMG_MUSCLES for s in EMG_SIDES)

#: Cardinal directions (Appendix A: measured at the start and end for fatigue), as pure-moment unit wrenches
#: in the skull frame (x anterior, y superior, z right; the wrench the head exerts on the device: extension
#: pushes the back of the head backwards = +Mz, right side-bend = +Mx, left rotation = +My).
CARDINAL = {"extension": (0, 0, 1), "flexion": (0, 0, -1), "sidebendR": (1, 0, 0), "sidebendL": (-1, 0, 0),
            "rotationL": (0, 1, 0), "rotationR": (0, -1, 0)}

BLOCKS = ("start", "main", "end")

#: Plausibility bounds per wrench component. Forces as for the max-force table (a unit error, kN or N*m
#: entered as N, lands outside); moments: the largest neck moments in the literature are below about 100 N*m,
#: and a load cell mounted a few cm from the head adds at most |F| x 0.15 m.
MAX_COMPONENT_FORCE_N = 2000.0
MAX_COMPONENT_MOMENT_NM = 400.0

_KEY = ("participant", "direction", "block", "trial")


def trial_schema(frames: Sequence[str]) -> Schema:
    cols = [Column("participant", "str"), Column("direction", "str"),
            Column("block", "str", required=False, allow_missing=True, choices=BLOCKS),
            Column("trial", "int", min=1, max=99), Column("frame", "str", choices=tuple(frames))]
    cols += [Column(c, "float", "N*m", -MAX_COMPONENT_MOMENT_NM, MAX_COMPONENT_MOMENT_NM) for c in WRENCH[:3]]
    cols += [Column(c, "float", "N", -MAX_COMPONENT_FORCE_N, MAX_COMPONENT_FORCE_N) for c in WRENCH[3:]]
    cols += [Column("peak_time_s", "float", "s", required=False, allow_missing=True)]
    emg = Column("", "float", None, 0.0, None, allow_missing=True)
    chan = "|".join(EMG_CHANNELS)
    return Schema(name="trial table", columns=tuple(cols), allow_extra_columns=False,
                  pattern_columns=((rf"emg_({chan})", emg), (rf"emgmax_({chan})", emg)))


def emg_channels(df: pd.DataFrame) -> list[str]:
    """EMG channels (``SCM_R``, ...) with a column ``emg_<channel>`` in ``df``, in Appendix A order."""
    return [c for c in EMG_CHANNELS if f"emg_{c}" in df.columns]


def read_trials(path: str | Path, directions: Sequence[str], frames: Sequence[str] = ("skull", "pad")) -> pd.DataFrame:
    """Read and validate a trial table (see the module docstring).

    ``directions``: the configured test-direction names; cardinal names are always accepted.
    Returns the table with columns ``row`` and ``line`` (position in the file, for later messages) and
    ``block`` filled (``main``). Raises :class:`DataValidationError` (file, row, field) for: a binary or
    non-UTF-8 file, a missing or unexpected column, a wrong declared unit, an unknown direction, a missing or
    unknown frame, a wrench component out of range, a duplicated trial, an all-zero wrench, a cardinal
    direction outside the start/end blocks.
    """
    df = read_table(path, trial_schema(frames))
    n_comment = len(df.attrs.get("comments", []))
    df.insert(0, "row", np.arange(1, len(df) + 1))
    df.insert(1, "line", df["row"] + n_comment + 1)
    if len(df) == 0:
        raise DataValidationError(path, "no trials (the table has a header but no rows)")
    if "block" not in df.columns:
        df["block"] = "main"
    df["block"] = [b if b else "main" for b in df["block"]]
    known = set(directions) | set(CARDINAL)
    for r in df.itertuples():
        if (not re.fullmatch(r"[A-Za-z][A-Za-z0-9_-]*", r.participant)
                or MEASUREMENT_SCHEMA.column(r.participant) is None):
            raise DataValidationError(path, f"participant id '{excerpt(r.participant)}' must look like S003 or P01 "
                                      "(a letter, then up to 63 letters, digits, _ or -): it becomes a column of "
                                      "the max-force table", r.row, r.line, "participant")
        if r.direction not in known:
            raise DataValidationError(path, f"unknown test direction '{excerpt(r.direction)}' (configured: "
                                      f"{', '.join(directions)}; cardinal: {', '.join(CARDINAL)})",
                                      r.row, r.line, "direction")
        if r.direction in CARDINAL and r.block == "main":
            raise DataValidationError(path, f"cardinal direction '{excerpt(r.direction)}' needs block 'start' "
                                      "or 'end'",
                                      r.row, r.line, "block")
        if r.direction not in CARDINAL and r.block != "main":
            raise DataValidationError(path, f"test direction '{excerpt(r.direction)}' in block '{r.block}': "
                                      "only cardinal directions are measured at the start and end",
                                      r.row, r.line, "block")
        w = np.array([getattr(r, c) for c in WRENCH])
        if not np.any(w != 0):
            raise DataValidationError(path, "all six wrench components are zero (no effort recorded)",
                                      r.row, r.line, "Mx")
    seen: dict = {}
    for r in df.itertuples():
        key = (r.participant, r.direction, r.block, r.trial)
        if key in seen:
            raise DataValidationError(path, f"duplicated trial: participant {excerpt(r.participant)}, direction "
                                      f"{excerpt(r.direction)}, "
                                      f"block {r.block}, trial {r.trial} already at row {seen[key]}",
                                      r.row, r.line, "trial")
        seen[key] = r.row
    for c in emg_channels(df):
        mx = f"emgmax_{c}"
        if mx in df.columns:
            for r in df.itertuples():
                v, m = df.at[r.Index, f"emg_{c}"], df.at[r.Index, mx]
                if np.isfinite(v) and not np.isfinite(m):
                    raise DataValidationError(path, f"EMG value without its trial maximum {mx}", r.row, r.line, mx)
    for c in list(df.columns):
        if c.startswith("emgmax_") and f"emg_{c[7:]}" not in df.columns:
            raise DataValidationError(path, f"column {c} without emg_{c[7:]}", field_name=c)
    df.attrs["source"] = str(path)
    return df
