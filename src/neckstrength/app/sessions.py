"""The app's open sessions: one :class:`~neckstrength.session.Session` per folder, each behind a lock
===================================================================================================

A session folder under the app's root is opened once (created, or resumed from its log) and kept; every request
on it takes its lock, so two tabs or two clients on one session are served one after the other and never write the
log concurrently. (The folder lock of the session log keeps a second *process* out: a session open in the terminal
is refused here with the holder's pid, and :meth:`Registry.close` gives the folder back to the terminal.)
"""

from __future__ import annotations

import json
import re
import threading
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from neckstrength.session import HEADER, LOG, Session, SessionOptions
from neckstrength.session.log import release

NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
TRIALS = "trials.jsonl"          # the app's record of repeat trials (best-of-N) beside the engine's log


class NotFound(Exception):
    """No session of that name in the root folder."""


class Conflict(Exception):
    """The request conflicts with the session's state (exists already, open elsewhere, moved on)."""


@dataclass
class OpenSession:
    name: str
    session: Session
    lock: threading.Lock = field(default_factory=threading.Lock)


def check_name(name: str) -> str:
    """A session folder name: letters, digits, '.', '_', '-' (1-64 characters, not starting with '.')."""
    if not isinstance(name, str) or not NAME_RE.fullmatch(name):
        raise ValueError(f"'{name}' is not a session name: 1-64 letters, digits, '.', '_' or '-', starting with a "
                         "letter or digit")
    return name


class Registry:
    """Sessions under ``root`` (one sub-folder each), opened on first use and kept open."""

    def __init__(self, root: str | Path, config: str = "config/config.yaml", cache: str | None = None,
                 threads: int | None = None):
        self.root = Path(root)
        self.config = config
        self.cache = cache
        self.threads = threads
        self._open: dict[str, OpenSession] = {}
        self._lock = threading.Lock()

    def folder(self, name: str) -> Path:
        return self.root / check_name(name)

    def listing(self) -> list[dict]:
        """Every session folder under the root: name, participant, model, tests measured, stopped, open here."""
        out = []
        if not self.root.is_dir():
            return out
        for d in sorted(p for p in self.root.iterdir() if (p / HEADER).is_file() and NAME_RE.fullmatch(p.name)):
            try:
                h = json.loads((d / HEADER).read_text())
                o = h.get("options", {})
            except (OSError, ValueError):
                out.append({"name": d.name, "error": f"unreadable {HEADER}"})
                continue
            recs = []
            if (d / LOG).is_file():
                for line in (d / LOG).read_text(errors="replace").splitlines():
                    try:
                        recs.append(json.loads(line)["action"])
                    except (ValueError, KeyError, TypeError):
                        pass
            n, stack = 0, []
            for a in recs:
                if a in ("measure", "skip"):
                    stack.append(a)
                elif a == "undo" and stack:
                    stack.pop()
            n = stack.count("measure")
            out.append({"name": d.name, "participant": o.get("participant"), "model": o.get("model"),
                        "criterion": o.get("criterion"), "n_measured": n, "stopped": bool(recs) and recs[-1] == "stop",
                        "open_here": d.name in self._open})
        return out

    def create(self, name: str, opts: SessionOptions) -> OpenSession:
        """A new session in ``root/name`` (:class:`Conflict` when the folder holds one)."""
        folder = self.folder(name)
        with self._lock:
            if name in self._open or (folder / HEADER).exists() or (folder / LOG).exists():
                raise Conflict(f"session '{name}' exists already; open it to resume, or choose another name")
            existed = folder.exists()
            try:
                s = Session.create(folder, opts, threads=self.threads)
            except BaseException:
                release(folder)                    # bad options: leave no half-made folder behind
                if not existed and folder.is_dir() and {p.name for p in folder.iterdir()} <= {"session.lock"}:
                    (folder / "session.lock").unlink(missing_ok=True)
                    folder.rmdir()
                raise
            o = self._open[name] = OpenSession(name, s)
            return o

    def get(self, name: str) -> OpenSession:
        """The open session ``name``, resumed from its folder on first use (:class:`NotFound`, :class:`Conflict`
        when another process holds it)."""
        folder = self.folder(name)
        with self._lock:
            if name in self._open:
                return self._open[name]
            if not (folder / HEADER).is_file():
                raise NotFound(f"no session '{name}' in {self.root}")
            from neckstrength.errors import SessionLockedError

            try:
                s = Session.resume(folder, threads=self.threads)
            except SessionLockedError as exc:
                raise Conflict(str(exc)) from None
            o = self._open[name] = OpenSession(name, s)
            return o

    def close(self, name: str) -> bool:
        """Give the folder back (the terminal can resume it); False when it was not open here."""
        with self._lock:
            o = self._open.pop(check_name(name), None)
            if o is None:
                return False
            with o.lock:
                release(o.session.out)
            return True

    @contextmanager
    def using(self, name: str):
        """The open session ``name`` with its lock held (requests on one session are served one at a time)."""
        o = self.get(name)
        with o.lock:
            if self._open.get(name) is not o:      # closed while we waited
                raise Conflict(f"session '{name}' was closed; open it again")
            yield o

    def close_all(self) -> None:
        for name in list(self._open):
            self.close(name)
