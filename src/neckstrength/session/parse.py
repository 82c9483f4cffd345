"""Parsing what the clinician enters: a prompt line or a row of a replayed CSV -> an :class:`Entry`
================================================================================================

Every check a value passes before it may reach the log: forces in newtons (``0 < F <= MAX_PLAUSIBLE_FORCE_N``, a
unit other than N rejected with its name), directions (and postures) known to the session and not yet tested,
activations in [0, 1] of model muscles. A rejected value raises :class:`~neckstrength.errors.InputError` whose
message is shown to the clinician as is. Nothing here reads or writes the session.
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.errors import InputError
from neckstrength.io import MAX_PLAUSIBLE_FORCE_N


@dataclass(frozen=True)
class Entry:
    """One parsed command: ``kind`` in measure, skip, undo, stop, help."""

    kind: str
    direction: str | None = None
    force: float | None = None
    activations: dict | None = None


_UNITS_OTHER = {"kn": "kN", "mn": "mN", "nm": "N m", "n.m": "N m", "n*m": "N m", "n-m": "N m", "n·m": "N m",
                "lb": "lb", "lbs": "lb", "lbf": "lbf", "kg": "kg", "kgf": "kgf", "g": "g", "dan": "daN", "%": "%"}


_NUM = r"[-+]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?"


def parse_force(text: str) -> float:
    """A force in newtons from ``'142'``, ``'142 N'`` or ``'142N'``; every other unit and value is rejected."""
    t = text.strip()
    if not t:
        raise InputError("no force given: enter the measured force in N, e.g. 142")
    m = re.fullmatch(rf"({_NUM})\s*([^\d\s].*)?", t)
    if m is None:
        raise InputError(f"'{t}' is not a number: enter the measured force in N, e.g. 142 (type 'help' for commands)")
    unit = (m.group(2) or "").strip()
    if unit and unit not in ("N", "n", "newton", "newtons"):
        known = _UNITS_OTHER.get(unit.lower().replace(" ", ""))
        what = f"'{known}'" if known else f"'{unit}'"
        extra = " (a moment, not a force)" if known == "N m" else ""
        raise InputError(f"wrong unit {what}{extra}: enter the force in newtons (N), e.g. 142 or 142 N")
    f = float(m.group(1))
    if not np.isfinite(f):
        raise InputError(f"'{t}' is not a finite number")
    if f < 0:
        raise InputError(f"force {f:g} N is negative: enter the magnitude of the measured force (> 0 N)")
    if f == 0:
        raise InputError("force 0 N: a maximum-effort test gives a positive force; use 'skip' if it could not be done")
    if f > MAX_PLAUSIBLE_FORCE_N:
        raise InputError(f"force {f:g} N is implausibly large (bound {MAX_PLAUSIBLE_FORCE_N:g} N): check the "
                         f"reading and its unit")
    return f


def parse_activations(text: str, muscles: Sequence[str]) -> dict:
    """``'act=TS-B:0.4,TS-E:0.7'`` -> {muscle: activation}; names must be model muscles, values in [0, 1]."""
    body = text.strip()
    if not body.lower().startswith("act="):
        raise InputError(f"unexpected '{body}': activations are written act=MUSCLE:VALUE,... (type 'help')")
    body = body[4:]
    out: dict[str, float] = {}
    for item in filter(None, (x.strip() for x in body.split(","))):
        name, sep, val = item.rpartition(":")
        if not sep or not name:
            raise InputError(f"activation '{item}' is not MUSCLE:VALUE (e.g. {muscles[0]}:0.4)")
        name = name.strip()
        if name not in muscles:
            close = difflib.get_close_matches(name, muscles, n=1)
            hint = f" (did you mean {close[0]}?)" if close else ""
            raise InputError(f"unknown muscle '{name}'{hint}; muscles: {', '.join(muscles)}")
        try:
            a = float(val)
        except ValueError:
            raise InputError(f"activation '{val.strip()}' of {name} is not a number in [0, 1]") from None
        if not np.isfinite(a) or a < 0 or a > 1:
            raise InputError(f"activation {val.strip()} of {name} is outside [0, 1] (a fraction of maximum, not %)")
        if name in out:
            raise InputError(f"activation of {name} given twice")
        out[name] = a
    if not out:
        raise InputError("act= needs at least one MUSCLE:VALUE")
    return out


def _check_direction(name: str, directions: Sequence[str], tested: Sequence[str]) -> str:
    if name not in directions:
        low = {d.lower(): d for d in directions}
        if name.lower() in low:
            return _check_direction(low[name.lower()], directions, tested)
        close = difflib.get_close_matches(name, directions, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise InputError(f"unknown direction '{name}'{hint}; directions: {', '.join(directions)}")
    if name in tested:
        raise InputError(f"direction '{name}' has already been tested (each direction is tested once; 'undo' "
                         f"removes the last entry)")
    return name


def check_posture(posture: str, postures: Sequence[str], where: str = "") -> str:
    """A posture name of this session (case-insensitive), or :class:`InputError` naming the field and the allowed
    values."""
    if posture in postures:
        return posture
    low = {p.lower(): p for p in postures}
    if posture.lower() in low:
        return low[posture.lower()]
    close = difflib.get_close_matches(posture, list(postures), n=1)
    hint = f" (did you mean {close[0]}?)" if close else ""
    raise InputError(f"unknown posture '{posture}'{hint}{where}; field posture must be one of: {', '.join(postures)}")


def _check_test(name: str, directions: Sequence[str], tested: Sequence[str], postures: Sequence[str] | None,
                default_posture: str | None) -> str:
    """A test of this session from ``posture:direction`` or a bare direction (in ``default_posture``)."""
    from neckstrength.postures.model import SEPARATOR, pair_label

    if postures is None:
        if SEPARATOR in name and name not in directions:
            raise InputError(f"'{name}' names a posture, but this session tests neutral only (start a session with "
                             f"--postures to test other postures)")
        return _check_direction(name, directions, tested)
    if SEPARATOR in name:
        p, d = name.split(SEPARATOR, 1)
        p = check_posture(p.strip(), postures, f" in '{name}' (posture:direction)")
    else:
        p, d = default_posture or "neutral", name
    base = list(dict.fromkeys(x.split(SEPARATOR, 1)[-1] for x in directions))
    d = _check_direction(d.strip(), base, [])
    label = pair_label(p, d)
    if label in tested:
        raise InputError(f"test '{label}' (posture {p}, direction {d}) has already been tested (each test is done "
                         f"once; 'undo' removes the last entry)")
    return label


def parse_entry(line: str, proposed: str | None, directions: Sequence[str], tested: Sequence[str],
                muscles: Sequence[str], postures: Sequence[str] | None = None,
                default_posture: str | None = None) -> Entry:
    """One prompt line -> :class:`Entry`; :class:`InputError` (with the message to show) when invalid.

    With ``postures`` (a session over (posture, direction) tests, ``directions`` = their labels
    ``posture:direction``) ``measure`` takes ``POSTURE:DIRECTION`` or a bare direction, which is taken in
    ``default_posture`` (the proposed test's posture)."""
    t = line.strip()
    if not t:
        raise InputError("empty input: enter a force in N, or a command (help)")
    word, _, rest = t.partition(" ")
    w = word.lower()
    if w in ("help", "?", "h"):
        return Entry("help")
    if w in ("skip", "undo", "stop"):
        if rest.strip():
            raise InputError(f"'{w}' takes no arguments")
        if w == "skip" and proposed is None:
            raise InputError("nothing to skip: no direction is proposed")
        return Entry(w, direction=proposed if w == "skip" else None)
    if w in ("measure", "m"):
        parts = rest.split(None, 1)
        if not parts:
            raise InputError("measure needs a direction and a force: measure <direction> <force> [act=...]")
        d = _check_test(parts[0], directions, tested, postures, default_posture)
        if len(parts) < 2:
            raise InputError(f"measure {d}: the force is missing (measure {d} <force in N>)")
        force_txt, act = _split_act(parts[1])
        return Entry("measure", d, parse_force(force_txt), parse_activations(act, muscles) if act else None)
    bare = [d.lower() for d in directions] + [d.split(":", 1)[-1].lower() for d in directions]
    if (w in bare or (postures is not None and ":" in w)) and rest.strip():
        raise InputError(f"to measure another direction write: measure {word} {rest.strip()}")
    # a force (with optional activations) for the proposed direction
    force_txt, act = _split_act(t)
    if proposed is None:
        parse_force(force_txt)
        raise InputError("no direction is proposed: use measure <direction> <force>, undo or stop")
    return Entry("measure", proposed, parse_force(force_txt), parse_activations(act, muscles) if act else None)


def _split_act(text: str) -> tuple[str, str | None]:
    i = text.lower().find("act=")
    if i < 0:
        return text.strip(), None
    return text[:i].strip(), text[i:].strip()



def read_measurements_csv(path: str | Path) -> pd.DataFrame:
    df = pd.read_csv(path, comment="#", dtype=str, keep_default_na=False)
    miss = {"direction", "force_N"} - set(df.columns)
    if miss:
        raise InputError(f"{path}: missing columns {sorted(miss)} (needs direction, force_N[, activations, posture])")
    return df



def parse_priorities(items: Sequence[str] | None) -> dict:
    """``['TS-E=2', 'CS-F=0.5']`` -> {muscle: weight} (Eq. 6.8's gamma; unlisted muscles weigh 0)."""
    out = {}
    for it in items or []:
        name, sep, val = it.partition("=")
        if not sep:
            raise ValueError(f"--priority {it!r}: expected MUSCLE=WEIGHT")
        w = float(val)
        if not np.isfinite(w) or w < 0:
            raise ValueError(f"--priority {it!r}: the weight must be >= 0")
        out[name.strip()] = w
    return out

