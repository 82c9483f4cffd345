"""The session's append-only, hash-chained, fsync'd log (``session.log.jsonl``) and its folder lock
============================================================================================

Every accepted entry is written and fsync'd *before* the estimate changes; :meth:`SessionLog.read` verifies the
sequence numbers and the SHA-256 chain and sets a torn last line aside; :func:`effective_entries` folds the undos.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Sequence

from neckstrength.errors import SessionLockedError

HEADER = "session.json"


LOG = "session.log.jsonl"


_LOCKS: dict[str, object] = {}       # session folder -> the open lock file this process holds (one per folder)


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

    def append(self, record: dict) -> dict:
        """Write ``record`` with its ``prev`` (the hash of the line before) as one line, flushed and fsync'd; returns
        the record as written."""
        if self._last is None:
            self.read()
        rec = {**record, "prev": self.digest(self._last)}
        line = json.dumps(rec, sort_keys=True).encode()
        with open(self.path, "ab") as fh:
            fh.write(line + b"\n")
            fh.flush()
            os.fsync(fh.fileno())
        self._last = line
        return json.loads(line)


def effective_entries(records: Sequence[dict]) -> list[dict]:
    """The measure/skip records still in force after the undos (in order)."""
    stack: list[dict] = []
    for r in records:
        if r["action"] in ("measure", "skip"):
            stack.append(r)
        elif r["action"] == "undo" and stack:
            stack.pop()
    return stack


def release(folder: str | Path) -> None:
    """Give up this process's lock on a session folder (a replay that failed and removes what it created)."""
    fh = _LOCKS.pop(str(Path(folder).resolve()), None)
    if fh is not None:
        fh.close()
