"""Clinician session over (posture, direction) tests (issue 20): ``--postures`` runs the posture joint posterior,
the proposal names a posture and a direction, the entry takes ``posture:direction`` (a bare direction in the
proposed posture), bad postures are rejected naming the field and the allowed values, undo / resume / replay
give the same numbers as a fresh run, and without ``--postures`` nothing changes. p2m7, N 300: seconds."""

import hashlib
import io
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from neckstrength.session import (
    InputError,
    Session,
    SessionOptions,
    parse_entry,
    replay_csv,
    resolve_postures,
    run_interactive,
)

ROOT = Path(__file__).resolve().parents[2]
CFG = str(ROOT / "config" / "config.ci.yaml")
KNOWN = ["neutral", "flex20", "ext20", "rotL30", "rotR30", "bendL15", "bendR15"]
DIRS = ["forehead", "backHigh", "chinFront", "chinUnder", "backLow", "back", "noseBelow"]
MUSCLES = ["TC-E", "TC-F", "TS-B", "TS-E", "TS-F", "CS-E", "CS-F"]
POSTURES = ["neutral", "flex20", "ext20"]
LABELS = [d if p == "neutral" else f"{p}:{d}" for p in POSTURES for d in DIRS]


def _opts(tmp_path, **kw):
    base = {"model": "p2m7", "config": CFG, "n_candidates": 300, "cache": str(tmp_path / "cache")}
    base.update(kw)
    return SessionOptions(**base)


def _quiet(_):
    pass


def _drive(s, lines):
    it = iter(lines)

    def inp(_prompt):
        try:
            return next(it)
        except StopIteration:
            raise EOFError from None

    buf = io.StringIO()
    return run_interactive(s, inp, buf), buf.getvalue()


def _body(s):
    return s.render().split("===", 2)[2]


# --------------------------------------------------------------------------- parsing, no session

def test_resolve_postures():
    assert resolve_postures(None, KNOWN) is None
    assert resolve_postures("neutral", KNOWN) is None                      # neutral only = the default session
    assert resolve_postures("ext20, flex20,ext20", KNOWN) == ["neutral", "ext20", "flex20"]
    assert resolve_postures("all", KNOWN) == KNOWN
    with pytest.raises(ValueError, match=r"--postures: unknown posture 'flx20' \(did you mean flex20\?\); "
                                         r"allowed: all, neutral, flex20"):
        resolve_postures("flx20", KNOWN)


def test_parse_entry_with_postures():
    e = parse_entry("measure ext20:back 183 N", "flex20:chinFront", LABELS, [], MUSCLES, POSTURES, "flex20")
    assert (e.direction, e.force) == ("ext20:back", 183.0)
    # a bare direction is taken in the proposed posture; neutral: its plain name
    assert parse_entry("measure back 130", "flex20:chinFront", LABELS, [], MUSCLES, POSTURES,
                       "flex20").direction == "flex20:back"
    assert parse_entry("measure neutral:back 130", "flex20:chinFront", LABELS, [], MUSCLES, POSTURES,
                       "flex20").direction == "back"
    assert parse_entry("140", "flex20:chinFront", LABELS, [], MUSCLES, POSTURES, "flex20").direction == \
        "flex20:chinFront"
    with pytest.raises(InputError, match=r"unknown posture 'flx20' \(did you mean flex20\?\) in 'flx20:back' "
                                         r"\(posture:direction\); field posture must be one of: neutral, flex20, "
                                         r"ext20"):
        parse_entry("measure flx20:back 120", "back", LABELS, [], MUSCLES, POSTURES, "neutral")
    with pytest.raises(InputError, match="field posture must be one of"):      # a posture not in this session
        parse_entry("measure rotL30:back 120", "back", LABELS, [], MUSCLES, POSTURES, "neutral")
    with pytest.raises(InputError, match="unknown direction 'bak'"):
        parse_entry("measure flex20:bak 120", "back", LABELS, [], MUSCLES, POSTURES, "neutral")
    with pytest.raises(InputError, match=r"test 'flex20:back' \(posture flex20, direction back\) has already"):
        parse_entry("measure back 120", "flex20:forehead", LABELS, ["flex20:back"], MUSCLES, POSTURES, "flex20")
    with pytest.raises(InputError, match="measure flex20:back 120"):
        parse_entry("flex20:back 120", "back", LABELS, [], MUSCLES, POSTURES, "neutral")
    # a neutral-only session: a posture in the entry is refused with a pointer to --postures
    with pytest.raises(InputError, match="tests neutral only.*--postures"):
        parse_entry("measure flex20:back 120", "back", DIRS, [], MUSCLES)


# --------------------------------------------------------------------------- sessions

def test_default_session_unchanged(tmp_path):
    """No --postures (or --postures neutral): the plain directions, the same candidates and key as before."""
    a = Session.start(tmp_path / "a", _opts(tmp_path, criterion="joint_eig"), progress=_quiet)
    b = Session.start(tmp_path / "b", _opts(tmp_path, criterion="joint_eig", postures="neutral"), progress=_quiet)
    assert a.postures is None and b.postures is None and a.pset is None
    assert a.directions == DIRS and b.directions == DIRS
    assert _body(a) == _body(b) and "posture" not in a.render()
    # the key of a session without postures is the pre-postures one (sessions started before resume)
    post = a.state.post
    key = hashlib.sha256(np.ascontiguousarray(post.F).tobytes() + np.ascontiguousarray(a.U, float).tobytes())
    assert a.key == key.hexdigest()[:16]
    hdr = json.loads((tmp_path / "a" / "session.json").read_text())
    assert hdr["options"]["postures"] is None and hdr["directions"] == DIRS
    with pytest.raises(ValueError, match="--posture-change-cost needs --postures"):
        Session.start(tmp_path / "c", _opts(tmp_path, posture_change_cost=1.0), progress=_quiet)


def test_posture_session_proposes_posture_and_replay_equals_run(tmp_path):
    out = tmp_path / "run"
    s = Session.start(out, _opts(tmp_path, postures="flex20,ext20"), progress=_quiet)
    assert s.joint and s.criterion == "joint_eig"                  # p2m7's default (thesis) has no posture model
    assert s.directions == LABELS
    text = s.render()
    prop = s.choice(s.proposal())
    post, d = s.split(prop)
    assert post in POSTURES and d in DIRS
    assert f"Proposed: posture {post} / direction {d}" in text
    assert f"force (N) for {prop}" in s.prompt()
    hdr = json.loads((out / "session.json").read_text())
    assert hdr["options"]["postures"] == POSTURES and hdr["directions"] == LABELS
    lines = ["150", "measure ext20:back 120", "measure flx20:chinFront 90", "undo", "measure ext20:forehead 95",
             "skip", "measure flex20:chinUnder 80"]
    code, log = _drive(s, lines)
    assert code == 3
    assert "invalid: unknown posture 'flx20' (did you mean flex20?)" in log
    assert s.state.tested == [prop, "ext20:forehead", "flex20:chinUnder"]
    assert s.state.post.current_posture == "flex20"
    # resume: the same proposal and estimate
    r = Session.resume(out, progress=_quiet)
    assert r.state.tested == s.state.tested and _body(r) == _body(s)
    r.accept(parse_entry("undo", None, r.directions, r.state.tested, r.muscles))
    assert r.state.post.current_posture == "ext20"              # undo restores the posture of the last test
    r.accept(parse_entry("measure flex20:chinUnder 80", None, r.directions, r.state.tested, r.muscles,
                         r.postures, "neutral"))
    r.write_summary()
    meas = pd.read_csv(out / "measurements.csv", comment="#", dtype=str, keep_default_na=False)
    assert list(meas.columns[:2]) == ["posture", "direction"]
    assert list(meas["posture"]) == [post, "ext20", "flex20"]
    # replay of the measurements in a fresh session: the same estimate as the interactive run
    rep = tmp_path / "replay"
    buf = io.StringIO()
    assert replay_csv(Session.start(rep, _opts(tmp_path, postures="flex20,ext20"), progress=_quiet),
                      out / "measurements.csv", buf) == 0
    assert "proposed posture" in buf.getvalue()
    a = pd.read_csv(out / "summary.csv", comment="#")
    b = pd.read_csv(rep / "summary.csv", comment="#")
    pd.testing.assert_frame_equal(a, b)
    assert not np.allclose(a["f_c"], a["f_0"])                     # the measurements moved the estimate


def test_replay_posture_column_errors(tmp_path):
    csv = tmp_path / "m.csv"
    csv.write_text("direction,force_N,posture\nback,120,flex20\nforehead,90,flexx\n")
    s = Session.start(tmp_path / "p", _opts(tmp_path, postures="flex20"), progress=_quiet)
    with pytest.raises(InputError, match=r"m.csv, row 3: unknown posture 'flexx' \(did you mean flex20\?\); "
                                         r"field posture must be one of: neutral, flex20"):
        replay_csv(s, csv, io.StringIO())
    assert s.state.tested == []                                   # nothing logged from a bad file
    csv.write_text("direction,force_N,posture\nflex20:back,120,neutral\n")
    with pytest.raises(InputError, match="row 2: field posture 'neutral' contradicts"):
        replay_csv(s, csv, io.StringIO())
    csv.write_text("direction,force_N,posture\nback,120,flex20\n")
    n = Session.start(tmp_path / "n", _opts(tmp_path, criterion="joint_eig"), progress=_quiet)
    with pytest.raises(InputError, match="row 2: field posture: 'flex20', but this session tests neutral only"):
        replay_csv(n, csv, io.StringIO())


def test_change_cost_keeps_the_posture(tmp_path):
    """A cost larger than any gain: after a neutral test the proposal stays in neutral; without cost it leaves."""
    kw = {"postures": "flex20,ext20"}
    free = Session.start(tmp_path / "f", _opts(tmp_path, **kw), progress=_quiet)
    dear = Session.start(tmp_path / "d", _opts(tmp_path, posture_change_cost=100.0, **kw), progress=_quiet)
    for s in (free, dear):
        s.accept(parse_entry("measure neutral:back 150", None, s.directions, [], s.muscles, s.postures, "neutral"))
    assert free.split(free.choice(free.proposal()))[0] != "neutral"     # free: the best gain is in a posture
    assert dear.split(dear.choice(dear.proposal()))[0] == "neutral"
    t = dear.proposal().table()
    screen = dear.render()
    assert "posture change from" not in screen.split("\n")[1]
    assert "minus 100 nats for a posture change" in screen and "- 100 posture change)" in screen
    assert t["score"].max() > -50                                        # a neutral test scores its gain
    with pytest.raises(ValueError, match="thesis's scheme .* has no posture model"):
        Session.start(tmp_path / "t", _opts(tmp_path, criterion="thesis", **kw), progress=_quiet)


def test_s3m24_posture_session_has_the_deficit_decision_over_every_test(tmp_path):
    """The deficit decision runs in posture sessions too (issue 31: posture tests decided every patient of the
    benchmark set); its P is labelled heuristic (the recalibration was measured in neutral), undo and resume
    restore its evidence exactly."""
    out = tmp_path / "s"
    s = Session.start(out, _opts(tmp_path, model="s3m24", postures="flex20"), progress=_quiet)
    assert s.decision is not None and s.decision.postures == ["neutral", "flex20"]
    assert s.decision.directions == s.directions
    s.tell("150")
    s.tell("measure flex20:back 120")
    before = s.decision.log_bf()
    s.tell("measure flex20:forehead 80")
    s.undo()
    assert s.decision.log_bf() == before and len(s.decision.tested) == 2
    text = "\n".join(s.decision_lines())
    assert "tests in several postures, measured in neutral only" in text and "NOT calibrated" in text
    r = Session.resume(out, progress=_quiet)
    assert r.decision.log_bf() == s.decision.log_bf() and r.decision.tested == s.decision.tested
