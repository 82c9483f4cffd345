"""The terminal front end: the prompt loop and the CSV replay, both through the engine's API
=====================================================================================

:func:`run_interactive` reads a line, parses it (:func:`~neckstrength.session.parse.parse_entry`), hands the entry
to :meth:`Session.tell` (log first, then the estimate) and prints the screen (:mod:`neckstrength.session.render`);
:func:`replay_csv` drives the same calls from a CSV of measurements. Only this module reads input or prints.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Callable

from neckstrength.errors import InputError
from neckstrength.io import MAX_PLAUSIBLE_FORCE_N
from neckstrength.session.log import release
from neckstrength.session.parse import check_posture, parse_entry, read_measurements_csv
from neckstrength.session.render import HELP, final_table, proposed_text
from neckstrength.session.state import Session, SessionOptions


def run_interactive(session: Session, input_fn: Callable[[str], str] = input, out=sys.stdout) -> int:
    """The prompt loop: a line is parsed (:meth:`Session.parse`), handed to :meth:`Session.tell` (a stop to
    :meth:`Session.stop`) and the next screen printed. Returns 0 on stop, 3 when paused (end of input)."""
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
            e = session.parse(line)
            if e.kind == "help":
                say(HELP.format(max=MAX_PLAUSIBLE_FORCE_N))
                continue
            ack = session.stop() if e.kind == "stop" else session.tell(e)
        except InputError as exc:
            say(f"invalid: {exc}")
            continue
        say(ack["message"])
        if e.kind == "stop":
            say(final_table(session))
            say(f"wrote {ack['outputs']['summary_csv']} and {ack['outputs']['summary_png']}")
            return 0
        say(session.render())



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
        print(f"step {len(session.state.tested) + 1}: proposed {proposed_text(session, session.choice(p))}; "
              f"{session.tell(e)['message']}", file=out, flush=True)
    ack = session.stop()
    print(final_table(session), file=out)
    print(f"wrote {ack['outputs']['summary_csv']} and {ack['outputs']['summary_png']}", file=out, flush=True)
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
        s = Session.create(out, opts, progress, threads)
        return replay_csv(s, csv, stdout)
    except BaseException:
        if out.is_dir():
            _discard_created(out, before, root)
        raise


def _discard_created(out: Path, before: set, root: Path | None) -> None:
    """Remove the entries of ``out`` that are not in ``before`` (and the folders from ``out`` up to ``root`` when
    this run created them and they are empty then); release this process's lock on ``out`` first."""
    import shutil

    release(out)
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


