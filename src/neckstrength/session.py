"""Clinician-in-the-loop session on top of the Chapter 6 sequential estimator (Algorithms 7-9).

One session = one participant, one model. At every step the program shows the proposed test direction (Eq. 6.7,
or Eq. 6.8 with muscle priorities), the expected entropy reduction of every remaining direction (Eq. 6.6, a
text bar chart like Fig. 6.8), the current estimate (posterior mean +- sd per muscle) and a stop
recommendation; the clinician enters a force, measures another direction, skips, undoes or stops.

Pieces:

- :func:`parse_entry`      one line at the prompt -> an :class:`Entry` or an :class:`InputError` with the message
  shown to the clinician (forces in N, ``0 < F <= MAX_PLAUSIBLE_FORCE_N``, directions known and untested,
  activations in [0, 1]). Nothing that fails here reaches the log.
- :class:`SessionLog`      the append-only JSON-lines log (``session.log.jsonl``); every accepted entry is written
  and fsync'd *before* the estimate is updated; a torn last line (a kill mid-write) is dropped on resume.
- :class:`Session`         the state machine: header (``session.json``), the candidate set (built once, cached on
  disk by :func:`neckstrength.sequential.sim_key`), :class:`~neckstrength.sequential.SequentialState`, the
  proposals (deterministic per set of tested directions, so undo, resume and replay give the same numbers).
- :func:`run_interactive`, :func:`replay_csv`  the prompt loop and the non-interactive replay of a CSV of
  measurements through the same code path.

Choices the thesis does not make (docs/session.md): the prior is ``N(a f'_base, (0.3 a f'_base)^2)`` with ``a`` a
session option (default 1) because Sec. 6.5.1's ``a`` needs every measurement up front; the stop recommendation
is the prospective criterion of :func:`~neckstrength.sequential.stop_by_expected_gain` (best Eq. 6.7/6.8 score
below ``gain_frac`` of the first step's; config ``chapter6.stop.gain_frac``).
"""

from __future__ import annotations

import difflib
import json
import os
import re
import sys
import threading
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from neckstrength.config import derive_rng, seed_sequence
from neckstrength.io import MAX_PLAUSIBLE_FORCE_N
from neckstrength.sequential.algorithms import (
    Proposal,
    SequentialState,
    SimulatedSet,
    StrengthGrid,
    pdf_entropy,
    sample_prior,
    sim_key,
)

HEADER = "session.json"


LOG = "session.log.jsonl"


MODELS = ("p2m7", "s3m24", "p3m12")


# next-test criteria: on the joint posterior (joint_eig, marginal_entropy) or the thesis's scheme (Algorithms 7-9)
CRITERIA = ("joint_eig", "marginal_entropy", "thesis")


HELP = """Commands:
  <force>                          force in N for the proposed direction, e.g. 142 or 142 N
  <force> act=MUSCLE:VALUE,...     the same with EMG activations in [0, 1], e.g. 142 act=TS-B:0.4,TS-E:0.7
  measure <direction> <force> [act=MUSCLE:VALUE,...]   a force for another (untested) direction
  measure <posture>:<direction> <force> [act=...]      sessions with --postures: a test in that posture, e.g.
                                   measure flex20:back 183 (a bare direction is taken in the proposed posture)
  skip                             do not test the proposed direction now (it is proposed no more)
  undo                             remove the last measurement or skip
  stop                             finish: write summary.csv and summary.png
  help                             this text
Forces are in newtons, 0 < F <= {max:g} N. Ctrl-D pauses (resume with `neckstrength session resume --out DIR`)."""


class InputError(ValueError):
    """A rejected line at the prompt; ``str(exc)`` is the message shown before the re-prompt."""


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


_LOCKS: dict[str, object] = {}       # session folder -> the open lock file this process holds (one per folder)


class SessionLockedError(ValueError):
    """Another process holds the session folder's lock (a second ``session resume`` of the same session)."""


class SessionLog:
    """Append-only JSON lines; each record is flushed and fsync'd before :meth:`append` returns.

    Integrity: every record the log writes carries ``prev``, the SHA-256 of the previous record's line (of the empty
    string for the first), and the session gives it ``seq`` (1, 2, ...). :meth:`read` refuses a log with a gap, a
    duplicate or a broken chain, naming the line; records written before ``prev`` existed are checked by ``seq``
    only. A torn last line (killed mid-write, never acknowledged) is kept in ``<log>.torn``, reported in
    :attr:`notice` and dropped. While a log is open, its folder is locked (``session.lock``, ``fcntl.flock``): a
    second process is refused with the holder's pid.
    """

    LOCK = "session.lock"

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.notice: str | None = None       # what read() had to repair (the torn last line), for the user
        self._last: bytes | None = None      # the last record's line as on disk (None: not read yet)
        if self.path.parent.is_dir():
            self.lock()

    # -- the folder lock
    def lock(self) -> None:
        """Take the folder's exclusive lock (kept until the process ends); raises :class:`SessionLockedError`
        naming the pid of the process that holds it."""
        import fcntl

        key = str(self.path.parent.resolve())
        if key in _LOCKS:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(self.path.parent / self.LOCK, "a+")
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.seek(0)
            holder = fh.read().strip() or "unknown"
            fh.close()
            raise SessionLockedError(
                f"{self.path.parent}: the session is open in another process ({holder}); close it there first "
                "(two processes writing one log would corrupt it)") from None
        fh.seek(0)
        fh.truncate()
        fh.write(f"pid {os.getpid()} since {time.strftime('%Y-%m-%dT%H:%M:%S')}\n")
        fh.flush()
        _LOCKS[key] = fh

    # -- reading and verifying
    @staticmethod
    def digest(line: bytes) -> str:
        import hashlib

        return hashlib.sha256(line).hexdigest()

    def read(self) -> list[dict]:
        """Records on disk, verified (see the class); a torn last line is moved to ``<log>.torn``."""
        self.lock()
        self.notice = None
        if not self.path.exists():
            self._last = b""
            return []
        raw = self.path.read_bytes()
        lines = raw.split(b"\n")
        out, good, last = [], 0, b""
        chained = False
        prev_seq = None
        for k, ln in enumerate(lines):
            if not ln.strip():
                good += len(ln) + 1
                continue
            try:
                rec = json.loads(ln)
                if not isinstance(rec, dict):
                    raise json.JSONDecodeError("not an object", ln.decode(errors="replace"), 0)
            except (json.JSONDecodeError, UnicodeDecodeError):
                if k < len(lines) - 1 and any(x.strip() for x in lines[k + 1:]):
                    raise ValueError(f"{self.path}: line {k + 1} is corrupt") from None
                self._drop_torn(raw, good, k + 1)
                break
            if k == len(lines) - 1:                    # complete JSON but no newline: cut before the newline
                self._drop_torn(raw, good, k + 1)
                break
            where = f"{self.path}: line {k + 1}"
            if "seq" in rec:
                seq = int(rec["seq"])
                if prev_seq is not None and seq <= prev_seq:
                    raise ValueError(f"{where}: seq {seq} after seq {prev_seq}: a duplicated or reordered record; "
                                     "refusing to replay it")
                if seq != (prev_seq or 0) + 1:
                    raise ValueError(f"{where}: seq {seq} after seq {prev_seq or 0}: a record is missing (gap); "
                                     "refusing to replay it")
                prev_seq = seq
            if "prev" in rec:
                if rec["prev"] != self.digest(last):
                    raise ValueError(f"{where}: broken chain (its 'prev' is not the hash of the line before it: a "
                                     "record was removed, inserted or edited); refusing to replay it")
                chained = True
            elif chained:
                raise ValueError(f"{where}: record without 'prev' after chained records (inserted or edited); "
                                 "refusing to replay it")
            out.append(rec)
            good += len(ln) + 1
            last = ln
        self._last = last
        return out

    def _drop_torn(self, raw: bytes, good: int, line: int) -> None:
        torn = self.path.with_name(self.path.name + ".torn")
        with open(torn, "ab") as fh:                  # kept (appended: an earlier torn line is not lost)
            fh.write(raw[good:].rstrip(b"\n") + b"\n")
            fh.flush()
            os.fsync(fh.fileno())
        with open(self.path, "r+b") as fh:
            fh.truncate(good)
            fh.flush()
            os.fsync(fh.fileno())
        self.notice = (f"{self.path}: line {line} was cut off mid-write (an entry never acknowledged); it is kept in "
                       f"{torn} and left out of the session")

    def append(self, record: dict) -> None:
        if self._last is None:
            self.read()
        line = json.dumps({**record, "prev": self.digest(self._last)}, sort_keys=True).encode()
        with open(self.path, "ab") as fh:
            fh.write(line + b"\n")
            fh.flush()
            os.fsync(fh.fileno())
        self._last = line


def effective_entries(records: Sequence[dict]) -> list[dict]:
    """The measure/skip records still in force after the undos (in order)."""
    stack: list[dict] = []
    for r in records:
        if r["action"] in ("measure", "skip"):
            stack.append(r)
        elif r["action"] == "undo" and stack:
            stack.pop()
    return stack


def bar_chart(labels: Sequence[str], values: Sequence[float], width: int = 30, mark: str | None = None,
              marks: Mapping[str, str] | None = None) -> str:
    """Compact horizontal text bars (Fig. 6.8 as text): one line per label, scaled to the largest value."""
    vals = np.asarray(values, float)
    top = max(float(np.nanmax(vals)), 1e-12) if len(vals) else 1.0
    lw = max((len(x) for x in labels), default=0)
    lines = []
    blocks = " ▏▎▍▌▋▊▉█"
    for lab, v in zip(labels, vals):
        x = max(v, 0.0) / top * width
        full = int(x)
        part = blocks[int(round((x - full) * 8))] if full < width else ""
        bar = ("█" * full + part.strip()).ljust(width)
        note = (marks or {}).get(lab, "")
        if lab == mark:
            note = ("<- proposed " + note).strip()
        lines.append(f"  {lab:<{lw}} {bar} {v:7.3f}  {note}".rstrip())
    return "\n".join(lines)


def _normal_words(n: np.ndarray) -> str:
    words = []
    for comp, pos, neg in ((n[0], "forward", "backward"), (n[1], "up", "down"), (n[2], "to the right", "to the left")):
        if abs(comp) >= 0.3:
            words.append(pos if comp > 0 else neg)
    return " and ".join(words) or "along the normal"


def where_to_push(directions: pd.DataFrame, spec_csv: str | Path | None) -> dict[str, str]:
    """Direction name -> where the pad sits on the head and which way the head pushes (outward normal)."""
    spec = {}
    if spec_csv and Path(spec_csv).exists():
        s = pd.read_csv(spec_csv, comment="#")
        spec = {r["name"]: (r.get("mirror_of"), r.get("rationale")) for r in s.to_dict("records")}
    out = {}
    for r in directions.to_dict("records"):
        name = r["name"]
        mirror, why = spec.get(name, (None, None))
        if isinstance(mirror, str) and mirror:
            why = spec.get(mirror, (None, ""))[1]
            why = f"as {mirror} on the left side: {why}" if isinstance(why, str) else f"mirror of {mirror}"
        n = np.array([r["nx"], r["ny"], r["nz"]], float)
        side = f"point ({r['px']:.3f}, {r['py']:.3f}, {r['pz']:.3f}) m in the skull frame"
        where = why if isinstance(why, str) and why else side
        out[name] = f"{where}; the head pushes {_normal_words(n)} against the pad"
    return out


@dataclass
class SessionOptions:
    """Everything that fixes a session's numbers (written to ``session.json``)."""

    model: str = "p2m7"
    participant: str = "anonymous"
    priorities: dict = field(default_factory=dict)     # Eq. 6.8 gamma {muscle: weight}; empty = Eq. 6.7
    config: str = "config/config.yaml"
    n_candidates: int | None = None                     # None = config chapter6.n_candidates (per model)
    prior_scale: float = 1.0                            # a in f_0 = a f'_base
    gain_frac: float | None = None                      # None = config chapter6.stop.gain_frac
    cache: str | None = None                            # candidate-set cache folder
    seed: int | None = None                             # None = config seed
    criterion: str | None = None                        # joint_eig / marginal_entropy (joint posterior) or thesis
                                                        # (Algorithms 7-9); None = config clinician.session.<model>
    postures: list | str | None = None                  # tests in these postures (issue 20; 'all' = config
                                                        # postures.postures); None = neutral only (the thesis's tests)
    posture_change_cost: float = 0.0                    # nats charged per posture change by the criterion
    prevalence: float | None = None                     # prior P(deficit) of the decision; None = config
                                                        # clinician.decision.prevalence
    noise: float | None = None                          # the decision's measurement noise (sd of the relative
                                                        # force error); None = config clinician.decision.noise
    noise_source: str | None = None                     # where ``noise`` comes from (printed with the answer)


def session_threads(threads: int | None) -> int:
    """Threads of the joint posterior's solver calls (directions solved concurrently; the numbers are the same for
    any count). None or 0: every core of this machine (``os.cpu_count()``), as an interactive session has the
    machine to itself; the step times of docs/clinician.md were measured with 2 threads on 2 cores."""
    if threads is None or int(threads) == 0:
        return max(1, os.cpu_count() or 1)
    if int(threads) < 0:
        raise ValueError(f"--threads: {threads!r} must be >= 0 (0 = every core)")
    return int(threads)


def resolve_postures(spec: str | Sequence[str] | None, known: Sequence[str]) -> list[str] | None:
    """``--postures`` -> the session's postures, neutral first; None for neutral only (the default session).
    ``spec``: a comma-separated string or a list; ``'all'`` = every posture of ``known`` (config postures.postures)."""
    if spec is None:
        return None
    items = [x.strip() for x in (spec.split(",") if isinstance(spec, str) else spec)]
    items = [x for x in items if x]
    if not items:
        raise ValueError(f"--postures: no posture given; allowed: all, {', '.join(known)}")
    if items == ["all"]:
        items = list(known)
    out = ["neutral"]
    for x in items:
        if x not in known:
            close = difflib.get_close_matches(x, list(known), n=1)
            hint = f" (did you mean {close[0]}?)" if close else ""
            raise ValueError(f"--postures: unknown posture '{x}'{hint}; allowed: all, {', '.join(known)}")
        if x not in out:
            out.append(x)
    return None if out == ["neutral"] else out


class Session:
    """One participant's session in folder ``out`` (header, log, outputs)."""

    def __init__(self, out: str | Path, opts: SessionOptions, progress: Callable[[str], None] = print,
                 threads: int | None = None):
        from neckstrength.config import (
            build_directions,
            chapter6_settings,
            deficit_definition,
            full_model_from_config,
            joint_settings,
            load_config,
            model_from_config,
            session_defaults,
        )
        from neckstrength.estimation.datasets import model_directions_table

        self.out = Path(out)
        self.progress = progress
        self.threads = session_threads(threads)     # not in the header: the numbers do not depend on it
        cfg = load_config(opts.config)
        self.cfg = cfg
        defaults = session_defaults(cfg, opts.model)
        postures = resolve_postures(opts.postures, list(cfg.get("postures", {}).get("postures", ["neutral"])))
        cost = float(opts.posture_change_cost)
        if not np.isfinite(cost) or cost < 0:
            raise ValueError(f"--posture-change-cost: {opts.posture_change_cost!r} must be >= 0 (nats)")
        if cost > 0 and postures is None:
            raise ValueError("--posture-change-cost needs --postures (a session in neutral only never changes posture)")
        crit = opts.criterion or defaults.get("criterion", "thesis")
        if crit not in CRITERIA:
            raise ValueError(f"unknown criterion {crit!r}; known: {', '.join(CRITERIA)}")
        if postures is not None and crit == "thesis":
            if opts.criterion == "thesis":
                raise ValueError("--postures needs the joint posterior (--criterion joint_eig or marginal_entropy): "
                                 "the thesis's scheme (Algorithms 7-9) has no posture model")
            crit = "joint_eig"
        if opts.n_candidates is None and crit != "thesis" and "n_candidates" in defaults:
            opts = replace(opts, n_candidates=int(defaults["n_candidates"]))
        # resolved: the header fixes the session's numbers
        self.opts = opts = replace(opts, criterion=crit, postures=postures, posture_change_cost=cost)
        self.postures = postures
        self.criterion = crit
        self.joint = crit != "thesis"
        self.deficit = deficit_definition(cfg)
        full = full_model_from_config(cfg)
        self.model = model_from_config(full, cfg, opts.model)
        self.muscles = list(self.model.muscle_names)
        unknown = set(opts.priorities) - set(self.muscles)
        if unknown:
            raise ValueError(f"priorities for unknown muscles {sorted(unknown)}; muscles of {opts.model}: "
                             f"{', '.join(self.muscles)}")
        over = {} if opts.n_candidates is None else {"n_candidates": int(opts.n_candidates)}
        if self.joint and opts.priorities and crit == "joint_eig":
            raise ValueError("muscle priorities (Eq. 6.8) need --criterion marginal_entropy or thesis; joint_eig "
                             "scores the information about all muscles together")
        self.settings = (joint_settings(cfg, **over) if self.joint
                         else chapter6_settings(cfg, opts.model, **over))
        d, U = model_directions_table(self.model, build_directions(cfg))
        self.U = U
        self.dirtable = d
        self.directions = list(d["name"])
        self.base_directions = list(self.directions)
        self.push = where_to_push(d, cfg.get("geometry", {}).get("test_point_spec"))
        self.force_scale = d["force_scale"].to_numpy(float)
        self.pset = None
        if postures is not None:                # tests = (posture, direction) pairs, labelled posture:direction
            from neckstrength.postures import build_posture_set, load_posture_tables, pair_label

            tables = load_posture_tables(cfg["data"]["model_dir"], postures)
            self.pset = build_posture_set(full, self.model, tables, postures,
                                          cfg.get("postures", {}).get("force_length", "relative"))
            self.test_postures = [p for p in postures for _ in self.base_directions]
            self.directions = [pair_label(p, n) for p in postures for n in self.base_directions]
            self.U = np.vstack([U] * len(postures))
            self.force_scale = np.tile(self.force_scale, len(postures))
        self.gamma = (np.array([float(opts.priorities.get(n, 0.0)) for n in self.muscles])
                      if opts.priorities else None)
        self.gain_frac = (float(opts.gain_frac) if opts.gain_frac is not None
                          else float(cfg["chapter6"].get("stop", {}).get("gain_frac", 0.2)))
        self.seed = int(cfg["seed"] if opts.seed is None else opts.seed)
        s = self.settings
        self.f0 = float(opts.prior_scale) * self.model.strengths
        self.skipped: list[str] = []
        self.entries: list[dict] = []          # effective measure/skip records, in order
        self._proposals: dict[tuple, Proposal] = {}
        self.log = SessionLog(self.out / LOG)
        self._seq = 0
        self.decision = None                   # the deficit decision (joint posterior sessions in neutral posture)
        if self.joint:                         # the joint posterior: candidates drawn and solved at start (N x K)
            self.sim = None
            what = (f"tests ({len(postures)} postures x {len(self.base_directions)} directions, change cost "
                    f"{cost:g} nats)" if postures else "directions")
            progress(f"joint posterior: {s.n_candidates} candidates x {len(self.directions)} {what} "
                     f"({self.model.name}), criterion {crit} ...")
            t0 = time.time()
            self.state = self._joint_state()
            self.key = self.state.key
            progress(f"  ready in {time.time() - t0:.1f} s")
            self.decision = self._decision(cfg)
            return
        ss = seed_sequence(self.seed, f"session/{opts.model}")
        F = sample_prior(self.f0, s.prior_sd_rel, s.n_candidates, np.random.default_rng(ss))
        grid = StrengthGrid.around(self.f0, s.prior_sd_rel, s.n_bins, s.bin_range_sd)
        self.key = sim_key(SimpleNamespace(F=F, U=U, grid=grid, iw=np.ones(len(F))))
        cache_dir = Path(opts.cache) if opts.cache else Path("results") / "session_cache"
        self.cache_path = cache_dir / f"{opts.model}_N{s.n_candidates}_{s.n_wbins}w_{s.n_bins}b_{self.key}.npz"
        self.sim = self._candidate_set(U, F, grid)
        self.state = SequentialState(self.model, self.sim, d["force_scale"].to_numpy(float), s, seed=self.seed)

    def _joint_state(self):
        from neckstrength.sequential.joint_state import JointState

        rng = derive_rng(self.seed, f"session/{self.opts.model}/joint")
        if self.pset is None:
            return JointState(self.model, self.directions, self.U, self.force_scale, self.f0, self.settings, rng,
                              self.criterion, self.deficit, n_threads=self.threads)
        from neckstrength.postures.sequential import PostureJointPosterior

        post = PostureJointPosterior(self.pset, self.directions, self.U, self.force_scale, self.test_postures,
                                     self.f0, self.settings, rng, change_cost=self.opts.posture_change_cost,
                                     n_threads=self.threads)
        return JointState(self.model, self.directions, self.U, self.force_scale, self.f0, self.settings, rng,
                          self.criterion, self.deficit, posterior=post,
                          key_extra="postures=" + ",".join(self.postures) + f";cost={self.opts.posture_change_cost!r}")


    def _decision(self, cfg):
        """The deficit decision (issue 31; :mod:`neckstrength.sequential.decision`) beside the joint posterior, for a
        model with the group and tests in neutral posture; None otherwise."""
        from neckstrength.config import decision_settings
        from neckstrength.sequential.decision import DeficitDecision

        over = {}
        if self.opts.prevalence is not None:
            over["prevalence"] = float(self.opts.prevalence)
        if self.opts.noise is not None:
            over["noise"] = float(self.opts.noise)
            over["noise_source"] = self.opts.noise_source or "given at session start"
        try:
            ds = decision_settings(cfg, **over)
        except ValueError as exc:
            raise ValueError(f"session decision settings: {exc}") from None
        if self.postures or not len(ds.group_indices(self.muscles)):
            return None
        t0 = time.time()
        dec = DeficitDecision(self.model, self.directions, self.U, self.force_scale, self.f0, ds, self.settings,
                              derive_rng(self.seed, f"session/{self.opts.model}/decision"), n_threads=self.threads)
        self.progress(f"deficit decision: {ds.n_candidates} candidates per hypothesis, ready in "
                      f"{time.time() - t0:.1f} s")
        return dec

    def _push(self, step) -> None:
        if self.joint:
            self.state.push(step)
            if getattr(self, "decision", None) is not None:
                try:
                    self.decision.push(step.direction, step.force, step.activations)
                except Exception:
                    self.state.undo()
                    raise
        else:
            self.state.steps.append(step)

    # -- candidate set: built once, cached on disk by its key
    def _candidate_set(self, U, F, grid) -> SimulatedSet:
        if self.cache_path.exists():
            try:
                sim = SimulatedSet.load(self.cache_path)
                if sim_key(sim) == self.key:
                    self.progress(f"candidate set: {sim.N} candidates x {sim.K} directions loaded from {self.cache_path}")
                    return sim
                self.progress(f"candidate set cache {self.cache_path} has another key; rebuilding")
            except Exception as exc:    # unreadable cache (e.g. killed while saving): rebuild
                self.progress(f"candidate set cache {self.cache_path} unreadable ({exc}); rebuilding")
        N, K = F.shape[0], U.shape[0]
        self.progress(f"building the candidate set once: {N} candidates x {K} directions ({self.model.name}) ...")
        done = threading.Event()
        t0 = time.time()

        def tick():
            while not done.wait(5.0):
                self.progress(f"  ... still building ({time.time() - t0:.0f} s)")

        th = threading.Thread(target=tick, daemon=True)
        th.start()
        try:
            sim, = SimulatedSet.build(self.model, self.directions, U, F, [grid], self.settings.n_wbins,
                                      progress=lambda s: self.progress("  " + s))
        finally:
            done.set()
            th.join()
        sim.save(self.cache_path)
        self.progress(f"  built in {time.time() - t0:.1f} s; cached in {self.cache_path}")
        return sim

    # -- header
    def header(self) -> dict:
        h = {"format": "neckstrength-session/1", "options": asdict(self.opts), "seed": self.seed,
             "settings": asdict(self.settings), "sim_key": self.key, "directions": self.directions,
             "muscles": self.muscles, "gain_frac": self.gain_frac}
        if getattr(self, "decision", None) is not None:
            h["decision"] = asdict(self.decision.settings)
        return h

    @classmethod
    def start(cls, out: str | Path, opts: SessionOptions, progress=print, threads: int | None = None) -> "Session":
        out = Path(out)
        if (out / LOG).exists() or (out / HEADER).exists():
            raise FileExistsError(f"{out} already holds a session; use `neckstrength session resume --out {out}`")
        out.mkdir(parents=True, exist_ok=True)
        s = cls(out, opts, progress, threads)
        tmp = out / (HEADER + ".tmp")
        tmp.write_text(json.dumps(s.header(), indent=2, sort_keys=True))
        os.replace(tmp, out / HEADER)
        return s

    @classmethod
    def resume(cls, out: str | Path, progress=print, threads: int | None = None) -> "Session":
        out = Path(out)
        if not (out / HEADER).exists():
            raise FileNotFoundError(f"{out}: no {HEADER}; start a session with `neckstrength session start`")
        h = json.loads((out / HEADER).read_text())
        o = dict(h["options"])
        o.setdefault("criterion", "thesis")     # sessions started before the joint posterior: the thesis's scheme
        s = cls(out, SessionOptions(**o), progress, threads)
        if s.key != h["sim_key"]:
            raise ValueError(f"{out}: the candidate set differs from the one the session started with (key "
                             f"{h['sim_key']}, now {s.key}); the config or the package changed")
        dec = getattr(s, "decision", None)
        if "decision" in h and (dec is None or json.loads(json.dumps(asdict(dec.settings))) != h["decision"]):
            raise ValueError(f"{out}: the deficit decision's settings differ from the ones the session started with "
                             f"({h['decision']}); the config (clinician.decision) changed")
        recs = s.log.read()                    # verified: seq and hash chain; a torn last line set aside
        if s.log.notice:
            progress(s.log.notice)
        s._seq = max((int(r.get("seq", 0)) for r in recs), default=0)
        for r in effective_entries(recs):
            s._apply(r)
        n_meas = sum(r["action"] == "measure" for r in s.entries)
        progress(f"resumed {out}: {len(recs)} log records replayed; {n_meas} measurements "
                 f"({', '.join(s.state.tested) or 'none'}), skipped: {', '.join(s.skipped) or 'none'}")
        return s

    # -- state changes (log first, then the estimate)
    def _apply(self, r: dict) -> None:
        if r["action"] == "measure":
            step = self.state.likelihood(r["direction"], r["force_N"], r.get("activations"))
            self._push(step)
            if r["direction"] in self.skipped:
                self.skipped.remove(r["direction"])
        elif r["action"] == "skip":
            self.skipped.append(r["direction"])
        self.entries.append(r)

    def _unapply(self) -> dict:
        r = self.entries.pop()
        if r["action"] == "measure":
            self.state.undo()
            if getattr(self, "decision", None) is not None:
                self.decision.undo()
        else:
            self.skipped.remove(r["direction"])
        return r

    def accept(self, e: Entry) -> str:
        """Apply a validated entry: log (fsync'd) first, then update the estimate. Returns a one-line echo."""
        if e.kind == "measure":
            _check_direction(e.direction, self.directions, self.state.tested)
            # Algorithm 8 first (nothing changes yet), so that a failing computation never reaches the log
            step = self.state.likelihood(e.direction, e.force, e.activations)
            rec = {"action": "measure", "direction": e.direction, "force_N": e.force, "activations": e.activations}
            self.log.append(self._stamp(rec))
            self._push(step)
            if e.direction in self.skipped:
                self.skipped.remove(e.direction)
            self.entries.append(rec)
            act = "" if not e.activations else " with activations " + ", ".join(
                f"{k} {v:g}" for k, v in e.activations.items())
            what = ("posture {} / direction {}".format(*self.split(e.direction)) if self.postures else e.direction)
            return f"recorded {what}: {e.force:g} N{act}"
        if e.kind == "skip":
            rec = {"action": "skip", "direction": e.direction}
            self.log.append(self._stamp(rec))
            self.skipped.append(e.direction)
            self.entries.append(rec)
            return f"skipped {e.direction} (not proposed again; 'measure {e.direction} <force>' still records it)"
        if e.kind == "undo":
            if not self.entries:
                raise InputError("nothing to undo")
            self.log.append(self._stamp({"action": "undo"}))
            r = self._unapply()
            what = f"measurement {r['direction']} ({r['force_N']:g} N)" if r["action"] == "measure" else \
                f"skip of {r['direction']}"
            return f"undone: {what}"
        if e.kind == "stop":
            self.log.append(self._stamp({"action": "stop"}))
            return "stopped"
        raise ValueError(e.kind)

    def _stamp(self, rec: dict) -> dict:
        self._seq += 1
        return {"seq": self._seq, "time": time.strftime("%Y-%m-%dT%H:%M:%S"), **rec}

    # -- proposals (deterministic per set of tested directions)
    def proposal(self) -> Proposal | None:
        if not self.state.remaining:
            return None
        key = tuple(sorted(self.state.tested))
        if key not in self._proposals:
            rng = derive_rng(self.seed, ";".join(key), 6)
            self._proposals[key] = self.state.propose(rng, self.gamma)
        return self._proposals[key]

    def first_score(self) -> float:
        if () not in self._proposals:
            rng = derive_rng(self.seed, "", 6)
            fresh = (self._joint_state() if self.joint else
                     SequentialState(self.model, self.sim, self.state.force_scale, self.settings))
            self._proposals[()] = fresh.propose(rng, self.gamma)
        return float(self._proposals[()].table()["score"].max())

    def choice(self, p: Proposal | None) -> str | None:
        """The best remaining direction that has not been skipped (Eq. 6.7/6.8 score)."""
        if p is None:
            return None
        t = p.table()
        t = t[~t["direction"].isin(self.skipped)]
        return None if t.empty else str(t.loc[t["score"].idxmax(), "direction"])

    def _score_name(self) -> str:
        if self.criterion == "joint_eig":
            return "expected information gain"
        return "expected entropy reduction"

    def recommendation(self, p: Proposal | None) -> tuple[bool, str]:
        what = {"joint_eig": "expected information gain about the joint strengths",
                "marginal_entropy": "expected entropy reduction on the joint posterior (Eq. 6.7"
                                    f"{'/6.8' if self.gamma is not None else ''} score)",
                "thesis": f"expected entropy reduction (Eq. 6.7{'/6.8' if self.gamma is not None else ''} score)"}
        crit = f"criterion: best {what[self.criterion]} below {self.gain_frac:.0%} of the first step's"
        if p is None:
            return True, "STOP: every direction has been tested"
        best_dir = self.choice(p)
        if best_dir is None:
            return True, "STOP: every remaining direction has been skipped (measure one explicitly, undo, or stop)"
        t = p.table().set_index("direction")
        best, first = float(t.loc[best_dir, "score"]), self.first_score()
        ratio = best / first if first > 0 else 0.0
        if not self.state.tested:
            return False, f"continue: no measurement yet ({crit})"
        dec = getattr(self, "decision", None)
        if dec is not None and dec.decision() in ("deficit", "no deficit"):
            return True, (f"STOP recommended: the deficit question is decided ({dec.decision()}, P(deficit) "
                          f"{dec.p_deficit():.2f}); further tests would only refine the strength estimates")
        if ratio < self.gain_frac:
            return True, (f"STOP recommended: best {self._score_name()} {best:.3f} nats is {ratio:.0%} of the "
                          f"first step's {first:.3f} ({crit})")
        return False, (f"continue: best {self._score_name()} {best:.3f} nats is {ratio:.0%} of the first step's "
                       f"{first:.3f} ({crit})")

    def estimate(self) -> pd.DataFrame:
        e = self.state.estimate()
        e.insert(1, "f_0", self.f0)
        e.insert(2, "sd_0", self.settings.prior_sd_rel * self.f0)
        return e

    # -- display
    def render(self) -> str:
        p = self.proposal()
        prop = self.choice(p)
        n_t = len(self.state.tested)
        what = "tests (posture:direction)" if self.postures else "directions"
        lines = [f"=== step {n_t + 1} · participant {self.opts.participant} · model {self.model.name} · "
                 f"{n_t} of {len(self.directions)} {what} tested"
                 + (f" ({', '.join(self.state.tested)})" if n_t else "") + " ==="]
        if prop is not None and self.postures:
            post, dname = self.split(prop)
            now = self.state.post.current_posture
            change = f"; posture change from {now}" if post != now else ""
            cost = (f", charged {self.opts.posture_change_cost:g} nats" if change and self.opts.posture_change_cost
                    else "")
            lines.append(f"Proposed: posture {post} / direction {dname}{change}{cost}  -- {self.push.get(dname, '')}")
        elif prop is not None:
            lines.append(f"Proposed: {prop}  -- {self.push.get(prop, '')}")
        if p is not None:
            t = p.table()
            g = "Eq. 6.8 with priorities" if self.gamma is not None else "Eq. 6.7, mean over muscles"
            if self.criterion == "joint_eig":
                lines.append("Expected information gain about the joint strengths of each remaining direction "
                             "(joint posterior; nats):")
            elif self.criterion == "marginal_entropy":
                lines.append(f"Expected entropy reduction of each remaining direction (Eq. 6.6 on the joint "
                             f"posterior; score {g}; nats):")
            else:
                lines.append(f"Expected entropy reduction of each remaining direction (Eq. 6.6; score {g}; nats):")
            marks = {d: "(skipped)" for d in self.skipped}
            cost = self.opts.posture_change_cost
            if self.postures and cost > 0:        # the bars are gain - cost for a pair in another posture
                lines[-1] = lines[-1][:-1] + f"; minus {cost:g} nats for a posture change):"
                now = self.state.post.current_posture
                for d, v in zip(t["direction"], t["score"]):
                    if self.split(d)[0] != now:
                        marks[d] = (marks.get(d, "") + f" (gain {v + cost:.3f} - {cost:g} posture change)").strip()
            # ties (e.g. mirror-image directions) in the direction order: the scores' last bits depend on which
            # optimal LP vertex the solver's cache history returns, so a resumed session could swap them otherwise
            order = t.assign(_key=t["score"].round(9)).sort_values("_key", ascending=False, kind="stable")
            lines.append(bar_chart(list(order["direction"]), list(order["score"]), mark=prop, marks=marks))
        e = self.estimate()
        lines.append("Current estimate (posterior mean ± sd, N; prior in brackets). The sd assumes the model fits every "
                     "direction within the kernel width; on real participants it does not (docs/calibration.md): read it "
                     "as a lower bound of the uncertainty, not a calibrated interval"
                     + (" (tests in several postures: not checked by simulation, heuristic)" if self.postures
                        else " (on s3m24 it is not calibrated even on simulated data at session sizes)" if self.joint
                        else "") + ":")
        lw = max(len(m) for m in self.muscles)
        for r in e.to_dict("records"):
            lines.append(f"  {r['muscle']:<{lw}} {r['f_c']:8.1f} ± {r['sd_c']:6.1f}   "
                         f"[{r['f_0']:7.1f} ± {r['sd_0']:6.1f}]")
        lines.extend(self.deficit_lines())
        lines.append(self.recommendation(p)[1])
        return "\n".join(lines)

    # -- P(deficit) of the configured group (clinician.deficit), with its trend
    def deficit_trend(self) -> list[float]:
        """P(deficit) before any test and after each measurement so far (empty if the model lacks the group)."""
        if getattr(self, "decision", None) is not None:
            return [h["p_deficit"] for h in self.decision.history]
        if not self.deficit.applies(self.muscles):
            return []
        if self.joint:
            return [h["p_deficit"] for h in self.state.history]
        from neckstrength.sequential.algorithms import posterior_from_loglik

        cum = np.zeros_like(self.state.log_prior)
        out = [self.deficit.probability_marginal(posterior_from_loglik(self.state.log_prior, cum), self.sim.grid,
                                                 self.f0, self.muscles)]
        for st in self.state.steps:
            cum = cum + st.loglik
            out.append(self.deficit.probability_marginal(posterior_from_loglik(self.state.log_prior, cum),
                                                         self.sim.grid, self.f0, self.muscles))
        return out

    def decision_lines(self) -> list[str]:
        """The deficit decision in a clinician's words, with what it depends on (issue 31)."""
        dec = self.decision
        s = dec.settings
        h = dec.history[-1]
        tr = [x["p_deficit"] for x in dec.history]
        arrows = ("... -> " if len(tr) > 8 else "") + " -> ".join(f"{x:.2f}" for x in tr[-8:])
        word = {"deficit": "DEFICIT", "no deficit": "NO DEFICIT", "undecided": "UNDECIDED",
                "model misfit": "NOT DECIDABLE (the model does not fit these forces)"}[h["decision"]]
        lo, hi = s.deficit_range
        bf = h["log_bf"]
        bft = f"{np.exp(bf):.3g}" if abs(bf) < 50 else ("> 1e21" if bf > 0 else "< 1e-21")
        return [
            f"Deep neck extensors ({'+'.join(s.group)}, both sides) weak? {word}: P(deficit) = {h['p_deficit']:.2f} "
            f"(decided at >= {s.p_decide:.2f} or <= {1 - s.p_decide:.2f})   trend: {arrows}",
            f"  Bayes factor deficit : normal = {bft} (log {bf:+.1f} ± {h['log_bf_se']:.1f}, Monte Carlo error, "
            f"heuristic); prior prevalence {s.prevalence:.0%} (clinician.decision.prevalence)",
            f"  depends on: deficit = each side at {lo:.0%}-{hi:.0%} of normal (uniform), normal = at least "
            f"{hi:.0%}; every muscle varies with sd {s.population_sd:.0%}; noise {s.noise:.0%} ({s.noise_source}); "
            f"{s.n_candidates} candidates per hypothesis"
            + (f"; best fit {h['misfit_rms']:.0%} RMS" if np.isfinite(h["misfit_rms"]) else ""),
        ] + ([f"  WARNING: no strength vector of the model fits these forces better than {h['misfit_rms']:.0%} RMS, "
              f"more than {s.misfit_factor:g} x the {s.noise:.0%} noise: the Bayes factor then says which hypothesis "
              f"misfits less, not whether the muscle is weak (docs/clinician.md; the gap diagnosis says where the "
              f"model misses)"] if h["decision"] == "model misfit" else []) + [
            "  P(deficit) is NOT calibrated (heuristic): on simulated patients of this model it was conservative "
            "between 0.2 and 0.6 and the rule's sensitivity and false alarms are measured there (docs/clinician.md, "
            "decision study); not checked under model misfit, which real participants have"]

    def deficit_lines(self) -> list[str]:
        if getattr(self, "decision", None) is not None:
            return self.decision_lines()
        tr = self.deficit_trend()
        if not tr:
            return []
        arrows = " -> ".join(f"{x:.2f}" for x in tr[-8:])
        more = "... -> " if len(tr) > 8 else ""
        how = (f"joint posterior, {self.settings.n_candidates} candidates" if self.joint
               else "thesis scheme, the group's muscles taken as independent")
        se = ""
        if self.joint:
            h = self.state.history[-1]
            e, k = h.get("p_deficit_se", float("nan")), h.get("mc_clusters", float("nan"))
            se = f" ± {e:.2f} (Monte Carlo error, 1 se)" if np.isfinite(e) else ""
            if se and k < MIN_MC_CLUSTERS:
                se = (f" ± ? (Monte Carlo error unknown: the candidates descend from about {k:.0f} independent "
                      "draws; the sampler has collapsed, do not trust this value)")
        out = [f"P(deep-extensor deficit: {self.deficit.label()}) = {tr[-1]:.2f}{se}   trend (prior -> now): "
               f"{more}{arrows}",
               f"  ({how}. NOT a calibrated probability: checked only on simulated participants of this model "
               f"(how often it finds a deficit: docs/clinician.md), never under model misfit)"]
        if se:
            out.append("  (the ± is the Monte Carlo error of the candidates, from their genealogy; heuristic: "
                       "independent candidate sets differed by 0.9-2 times it in the benchmark, docs/clinician.md)")
        return out

    def split(self, label: str) -> tuple[str, str]:
        """(posture, direction) of a test label ('neutral' for a plain direction)."""
        from neckstrength.postures.model import split_label

        return split_label(label)

    def default_posture(self) -> str:
        """The posture a bare direction at the prompt is taken in: the proposed test's, else the last test's."""
        if not self.postures:
            return "neutral"
        prop = self.choice(self.proposal())
        return self.split(prop)[0] if prop else self.state.post.current_posture

    def prompt(self) -> str:
        prop = self.choice(self.proposal())
        return f"force (N) for {prop}, or a command [help]> " if prop else "command (measure/undo/stop/help)> "

    # -- outputs
    def write_summary(self) -> tuple[Path, Path]:
        """``summary.csv`` (estimate per muscle) and ``summary.png``; also ``steps.csv`` and ``measurements.csv``
        (the measurements in order, in the format :func:`replay_csv` reads)."""
        from neckstrength.io import atomic_write_csv

        e = self.estimate()
        hdr = [f"clinician session: participant {self.opts.participant}, model {self.model.name}, "
               f"{len(self.state.tested)} of {len(self.directions)} directions: {', '.join(self.state.tested)}",
               (f"joint posterior, criterion {self.criterion}, N {self.settings.n_candidates}, kernel noise_rel "
                f"{self.settings.noise_rel}; " if self.joint else
                f"N_F {self.settings.n_candidates}, N_S {self.settings.n_sim}, bins {self.settings.n_bins}; ")
               + "prior f_0 = "
               f"{self.opts.prior_scale:g} f'_base, sd 0.3 f_0; seed {self.seed}; candidate key {self.key}",
               "f_c = posterior mean, sd_c = posterior sd (N; not calibrated under model misfit, docs/calibration.md); "
               "entropy in nats (Eq. 6.3)"]
        if self.decision is not None:
            dec = self.decision
            hdr.append(f"deficit decision: {dec.decision()}, P(deficit) {dec.p_deficit():.3f}, log Bayes factor "
                       f"{dec.log_bf():+.2f} ± {dec.log_bf_se():.2f} (Monte Carlo, heuristic); "
                       f"{dec.settings.label()}; how well it decides: docs/clinician.md")
        atomic_write_csv(e, self.out / "summary.csv", hdr, float_format="%.6g")
        # per-step trajectory (iteration 0 = prior)
        rows = []
        pdef = self.deficit_trend()
        if self.joint:
            for t, h in enumerate(self.state.history):
                for r in h["estimate"].to_dict("records"):
                    rows.append({"step": t, "direction": h["direction"], "force_N": h["force"], "muscle": r["muscle"],
                                 "f_c": r["f_c"], "sd_c": r["sd_c"], "entropy": r["entropy"]})
        steps = [] if self.joint else list(self.state.steps)
        from neckstrength.sequential.algorithms import pdf_moments, posterior_from_loglik
        cum = None if self.joint else np.zeros_like(self.state.log_prior)
        for t in range(0 if self.joint else len(steps) + 1):
            if t:
                cum = cum + steps[t - 1].loglik
            pdf = posterior_from_loglik(self.state.log_prior, cum)
            E, V = pdf_moments(pdf, self.sim.grid)
            H = pdf_entropy(pdf, self.sim.grid)
            for j, m in enumerate(self.muscles):
                rows.append({"step": t, "direction": steps[t - 1].direction if t else "",
                             "force_N": steps[t - 1].force if t else np.nan, "muscle": m, "f_c": E[j],
                             "sd_c": np.sqrt(V[j]), "entropy": H[j]})
        traj = pd.DataFrame(rows)
        if pdef:
            traj["p_deficit"] = np.asarray(pdef)[traj["step"].to_numpy()]
            if getattr(self, "decision", None) is not None:
                hist = pd.DataFrame(self.decision.history)
                for c in ("log_bf", "log_bf_se", "p_deficit_se", "decision"):
                    traj[c] = hist[c].to_numpy()[traj["step"].to_numpy()]
            elif self.joint:
                se = [h.get("p_deficit_se", np.nan) for h in self.state.history]
                traj["p_deficit_mc_se"] = np.asarray(se)[traj["step"].to_numpy()]
        atomic_write_csv(traj, self.out / "steps.csv", hdr[:2], float_format="%.6g")
        meas = [r for r in self.entries if r["action"] == "measure"]
        mdf = pd.DataFrame({"direction": [r["direction"] for r in meas], "force_N": [r["force_N"] for r in meas],
                            "activations": [",".join(f"{k}:{v:g}" for k, v in (r.get("activations") or {}).items())
                                            for r in meas]})
        if self.postures:                       # posture column, direction without the posture prefix
            pairs = [self.split(r["direction"]) for r in meas]
            mdf["direction"] = [d for _, d in pairs]
            mdf.insert(0, "posture", [p for p, _ in pairs])
        atomic_write_csv(mdf, self.out / "measurements.csv", [f"measurements of session {self.out.name} "
                                                              "(replay: neckstrength session replay --csv ...)"])
        png = self.out / "summary.png"
        _summary_figure(traj, e, png, f"{self.opts.participant} · {self.model.name}")
        return self.out / "summary.csv", png


def _summary_figure(traj: pd.DataFrame, est: pd.DataFrame, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [2, 1]})
    x = np.arange(len(est))
    ax[0].errorbar(x - 0.12, est["f_0"], yerr=est["sd_0"], fmt="o", color="0.6", label="prior f_0 ± sd")
    ax[0].errorbar(x + 0.12, est["f_c"], yerr=est["sd_c"], fmt="o", color="C0", label="estimate f_c ± sd")
    ax[0].set_xticks(x, est["muscle"], rotation=60 if len(x) > 10 else 0, fontsize=8)
    ax[0].set_ylabel("strength (N)")
    ax[0].legend(fontsize=8)
    h = traj.groupby("step")["entropy"].mean()
    labels = traj.drop_duplicates("step")["direction"].tolist()
    ax[1].plot(h.index, h.values, "o-")
    ax[1].set_xticks(h.index, ["prior"] + labels[1:], rotation=60, fontsize=8)
    ax[1].set_ylabel("mean posterior entropy (nats)")
    if "p_deficit" in traj.columns:
        pd_ = traj.groupby("step")["p_deficit"].first()
        tw = ax[1].twinx()
        tw.plot(pd_.index, pd_.values, "s--", color="C3")
        tw.set_ylim(0, 1)
        tw.set_ylabel("P(deep-extensor deficit) (not calibrated)", color="C3")
    fig.suptitle(f"Clinician session: {title}")
    fig.tight_layout()
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)


MIN_MC_CLUSTERS = 10     # below this effective number of independent draws the Monte Carlo error is not shown


def run_interactive(session: Session, input_fn: Callable[[str], str] = input, out=sys.stdout) -> int:
    """The prompt loop. Returns 0 on stop, 3 when paused (end of input)."""
    def say(s=""):
        print(s, file=out, flush=True)

    say(session.render())
    while True:
        try:
            line = input_fn(session.prompt())
        except EOFError:
            say("")
            say(f"paused: the log is on disk; resume with `neckstrength session resume --out {session.out}`")
            return 3
        try:
            e = parse_entry(line, session.choice(session.proposal()), session.directions, session.state.tested,
                            session.muscles, session.postures, session.default_posture())
            if e.kind == "help":
                say(HELP.format(max=MAX_PLAUSIBLE_FORCE_N))
                continue
            msg = session.accept(e)
        except InputError as exc:
            say(f"invalid: {exc}")
            continue
        say(msg)
        if e.kind == "stop":
            csv, png = session.write_summary()
            say(_final_table(session))
            say(f"wrote {csv} and {png}")
            return 0
        say(session.render())


def _final_table(session: Session) -> str:
    e = session.estimate()
    cols = ["muscle", "f_0", "f_c", "sd_c", "entropy"]
    return ("Final estimate (" + (", ".join(session.state.tested) or "no measurements") + "):\n"
            + e[cols].to_string(index=False, float_format=lambda v: f"{v:.1f}"))


def read_measurements_csv(path: str | Path) -> pd.DataFrame:
    df = pd.read_csv(path, comment="#", dtype=str, keep_default_na=False)
    miss = {"direction", "force_N"} - set(df.columns)
    if miss:
        raise InputError(f"{path}: missing columns {sorted(miss)} (needs direction, force_N[, activations, posture])")
    return df


def replay_csv(session: Session, csv: str | Path, out=sys.stdout) -> int:
    """Drive ``session`` from a CSV of measurements (direction, force_N[, activations, posture]) through the same
    validation, log and update as the prompt; then stop and write the summary. ``posture`` (optional; empty =
    neutral) names the posture of the row's test; ``direction`` may also be written ``posture:direction``."""
    df = read_measurements_csv(csv)
    entries, tested = [], list(session.state.tested)
    for k, r in enumerate(df.to_dict("records"), start=2):      # validate every row before logging any
        act = (r.get("activations") or "").strip()
        name = r["direction"].strip()
        post = (r.get("posture") or "").strip()
        try:
            if post and session.postures is None and post != "neutral":
                raise InputError(f"field posture: '{post}', but this session tests neutral only (start it with "
                                 f"--postures to replay tests in other postures)")
            if post and session.postures is not None:
                post = check_posture(post, session.postures)
                if ":" in name and session.split(name)[0] != post:
                    raise InputError(f"field posture '{post}' contradicts the posture in field direction '{name}'")
                name = name.split(":", 1)[-1]
            line = f"measure {name} {r['force_N'].strip()}" + (f" act={act}" if act else "")
            e = parse_entry(line, None, session.directions, tested, session.muscles, session.postures,
                            post or "neutral")
        except InputError as exc:
            raise InputError(f"{csv}, row {k}: {exc}") from None
        entries.append(e)
        tested.append(e.direction)
    for e in entries:
        p = session.proposal()
        print(f"step {len(session.state.tested) + 1}: proposed {_proposed_text(session, session.choice(p))}; "
              f"{session.accept(e)}", file=out, flush=True)
    session.accept(Entry("stop"))
    csvp, png = session.write_summary()
    print(_final_table(session), file=out)
    print(f"wrote {csvp} and {png}", file=out, flush=True)
    return 0


def replay_into(out: str | Path, opts: SessionOptions, csv: str | Path, threads: int | None = None,
                progress=print, stdout=sys.stdout) -> int:
    """``session replay``: start a session in ``out`` and drive it from ``csv`` (:func:`replay_csv`). A replay
    that fails (a bad CSV row, an error while computing, an interrupt) removes what it created in this run: the
    header, the log, the lock file, outputs, and ``out`` itself (and the parent folders it created) when it did not
    exist before; nothing that existed before is touched. The corrected replay into the same ``out`` then works."""
    out = Path(out)
    root = None                                 # the topmost folder this run creates (None: ``out`` existed)
    for p in [out, *out.parents]:
        if p.exists() or p.is_symlink():
            break
        root = p
    before = set(os.listdir(out)) if root is None and out.is_dir() else set()
    try:
        s = Session.start(out, opts, progress, threads)
        return replay_csv(s, csv, stdout)
    except BaseException:
        if out.is_dir():
            _discard_created(out, before, root)
        raise


def _discard_created(out: Path, before: set, root: Path | None) -> None:
    """Remove the entries of ``out`` that are not in ``before`` (and the folders from ``out`` up to ``root`` when
    this run created them and they are empty then); release this process's lock on ``out`` first."""
    import shutil

    fh = _LOCKS.pop(str(out.resolve()), None)
    if fh is not None:
        fh.close()
    for name in set(os.listdir(out)) - before:
        p = out / name
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
    if root is not None:
        for p in [out, *out.parents]:
            try:
                p.rmdir()                       # only when empty: never anything another process put there
            except OSError:
                break
            if p == root:
                break


def _proposed_text(session: Session, label: str | None) -> str:
    if label is None or not session.postures:
        return str(label)
    p, d = session.split(label)
    return f"posture {p} / direction {d}"


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
