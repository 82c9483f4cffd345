"""The terminal front end (src/neckstrength/session/repl.py): the interactive program driven through a
pseudo-terminal (pexpect): a normal session, invalid inputs, skip, undo, stop, a SIGKILL and resume, and the CSV
replay giving the same results as the interactive run. Small N_F (8,000) keeps it under a minute. (Parsing:
test_parse.py; the log: test_log.py.)"""

import json
import os
import signal
import sys
from pathlib import Path

import pytest

from neckstrength.io import MAX_PLAUSIBLE_FORCE_N
from neckstrength.session import effective_entries

pexpect = pytest.importorskip("pexpect")

ROOT = Path(__file__).resolve().parents[2]
N_F = "8000"
DIRS = ["forehead", "backHigh", "chinFront", "chinUnder", "backLow", "back", "noseBelow"]
MUSCLES = ["TC-E", "TC-F", "TS-B", "TS-E", "TS-F", "CS-E", "CS-F"]
PROMPT = r"\[help\]> |command \(measure/undo/stop/help\)> "


# --------------------------------------------------------------------------- the program in a pseudo-terminal

def spawn(args, cwd=ROOT):
    env = dict(os.environ, PYTHONUNBUFFERED="1", COLUMNS="120")
    child = pexpect.spawn(sys.executable, ["-m", "neckstrength.cli", "session", *args], cwd=str(cwd), env=env,
                          encoding="utf-8", timeout=60, dimensions=(50, 200))
    return child


def start_args(out, cache, participant="P01"):
    return ["start", "--out", str(out), "--model", "p2m7", "--participant", participant, "--n-candidates", N_F,
            "--cache", str(cache)]


def send(child, line, expect=PROMPT):
    child.sendline(line)
    child.expect(expect)
    return child.before


def records(out):
    return [json.loads(x) for x in (Path(out) / "session.log.jsonl").read_text().splitlines()]


def data_rows(path):
    return [x for x in Path(path).read_text().splitlines() if not x.startswith("#")]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("session_cache")


def test_interactive_session_validation_skip_undo_stop_and_replay(tmp_path, cache):
    out = tmp_path / "s1"
    c = spawn(start_args(out, cache))
    c.expect(PROMPT)
    first = c.before
    assert "Proposed:" in first and "the head pushes" in first                     # where to push
    assert "Expected entropy reduction" in first and "<- proposed" in first        # bar chart
    assert sum(d in first for d in DIRS) == 7 and "█" in first
    assert "Current estimate" in first and all(m in first for m in MUSCLES)        # estimate +- sd
    assert "criterion" in first
    proposed = first.split("Proposed: ")[1].split()[0]

    bad = {"abc": "not a number", "-5": "negative", "0": "force 0 N", "5000": f"bound {MAX_PLAUSIBLE_FORCE_N:g} N",
           "120 kN": "wrong unit 'kN'", "12 Nm": "a moment", "measure nowhere 100": "unknown direction 'nowhere'",
           "measure forehead 100 act=TS-B:1.5": r"outside [0, 1]", "undo": "nothing to undo", "": "empty input"}
    for line, msg in bad.items():
        text = send(c, line)
        assert "invalid:" in text and msg in text, (line, text)
    assert not (out / "session.log.jsonl").exists() or records(out) == []          # nothing invalid logged

    assert "Commands:" in send(c, "help")
    assert f"recorded {proposed}: 150 N" in send(c, "150")
    text = send(c, f"measure {proposed} 120")
    assert "already been tested" in text
    other = next(d for d in DIRS if d != proposed)
    assert f"recorded {other}: 110 N with activations TS-B 0.4" in send(c, f"measure {other} 110 act=TS-B:0.4")
    text = send(c, "skip")
    assert "skipped" in text and "(skipped)" in text
    assert "undone: skip" in send(c, "undo")
    text = send(c, "undo")
    assert f"undone: measurement {other}" in text
    assert f"recorded {other}: 115 N" in send(c, f"measure {other} 115")
    third = c.before.split("Proposed: ")[1].split()[0]
    send(c, "135")
    c.sendline("stop")
    c.expect("wrote .*summary.png")
    c.expect(pexpect.EOF)
    c.close()
    assert c.exitstatus == 0
    assert (out / "summary.csv").exists() and (out / "summary.png").stat().st_size > 1000
    acts = [r["action"] for r in records(out)]
    assert acts == ["measure", "measure", "skip", "undo", "undo", "measure", "measure", "stop"]
    assert [r["direction"] for r in effective_entries(records(out))] == [proposed, other, third]

    # the same measurements from a CSV: identical summary and trajectory
    out2 = tmp_path / "s2"
    r = spawn(["replay", "--csv", str(out / "measurements.csv"), *start_args(out2, cache)[1:]])
    r.expect(pexpect.EOF)
    r.close()
    assert r.exitstatus == 0, r.before
    assert data_rows(out2 / "summary.csv") == data_rows(out / "summary.csv")
    assert (out2 / "summary.csv").read_text() == (out / "summary.csv").read_text()
    assert (out2 / "steps.csv").read_text() == (out / "steps.csv").read_text()


def test_kill_mid_session_and_resume(tmp_path, cache):
    out = tmp_path / "k"
    c = spawn(start_args(out, cache, "P02"))
    c.expect(PROMPT)
    send(c, "150")
    send(c, "measure backLow 95")
    before_kill = c.before.split("===", 1)[1]          # the display after two measurements
    c.kill(signal.SIGKILL)
    c.close(force=True)
    assert [r["action"] for r in records(out)] == ["measure", "measure"]

    r = spawn(["resume", "--out", str(out)])
    r.expect(PROMPT)
    assert "resumed" in r.before and "2 measurements" in r.before
    assert r.before.split("===", 1)[1] == before_kill  # same proposal, bar chart, estimate and advice
    send(r, "measure chinFront 120")
    r.sendline("stop")
    r.expect(pexpect.EOF)
    r.close()
    assert r.exitstatus == 0
    # the killed-and-resumed session equals an uninterrupted replay of its measurements
    out2 = tmp_path / "k2"
    p = spawn(["replay", "--csv", str(out / "measurements.csv"), *start_args(out2, cache, "P02")[1:]])
    p.expect(pexpect.EOF)
    p.close()
    assert p.exitstatus == 0
    assert (out2 / "summary.csv").read_text() == (out / "summary.csv").read_text()


def test_errors_on_reuse_missing_and_bad_csv(tmp_path, cache):
    out = tmp_path / "e"
    bad = tmp_path / "bad.csv"
    bad.write_text("direction,force_N\nforehead,150\nback,12 kN\n")
    p = spawn(["replay", "--csv", str(bad), *start_args(out, cache)[1:]])
    p.expect(pexpect.EOF)
    p.close()
    assert p.exitstatus == 2 and "row 3" in p.before and "wrong unit 'kN'" in p.before
    assert not (out / "session.log.jsonl").exists()                 # the whole CSV is checked before logging
    assert not out.exists()                                           # a failed replay removes what it created
    bad.with_name("good.csv").write_text("direction,force_N\nforehead,150\n")
    p = spawn(["replay", "--csv", str(bad.with_name("good.csv")), *start_args(out, cache)[1:]])
    p.expect(pexpect.EOF)
    p.close()
    assert p.exitstatus == 0, p.before
    p = spawn(start_args(out, cache))
    p.expect(pexpect.EOF)
    p.close()
    assert p.exitstatus == 2 and "already holds a session" in p.before
    p = spawn(["resume", "--out", str(tmp_path / "none")])
    p.expect(pexpect.EOF)
    p.close()
    assert p.exitstatus == 2 and "no session.json" in p.before


def test_failed_replay_removes_only_what_it_created_and_the_corrected_replay_works(tmp_path, cache):
    out = tmp_path / "r"
    out.mkdir()
    (out / "notes.txt").write_text("the clinician's notes\n")        # existed before: never touched
    bad = tmp_path / "bad.csv"
    bad.write_text("direction,force_N\nforehead,150\nback,abc\n")
    p = spawn(["replay", "--csv", str(bad), *start_args(out, cache)[1:]])
    p.expect(pexpect.EOF)
    p.close()
    assert p.exitstatus == 2 and "row 3" in p.before
    assert sorted(x.name for x in out.iterdir()) == ["notes.txt"]     # no session.json, log or lock left
    assert (out / "notes.txt").read_text() == "the clinician's notes\n"
    bad.write_text("direction,force_N\nforehead,150\nback,120\n")    # corrected
    p = spawn(["replay", "--csv", str(bad), *start_args(out, cache)[1:]])
    p.expect(pexpect.EOF)
    p.close()
    assert p.exitstatus == 0, p.before
    assert [r["action"] for r in records(out)] == ["measure", "measure", "stop"]
    assert (out / "summary.csv").exists() and (out / "notes.txt").exists()
    # a replay into a folder that holds a session is refused and removes nothing
    kept = sorted(x.name for x in out.iterdir())
    p = spawn(["replay", "--csv", str(bad), *start_args(out, cache)[1:]])
    p.expect(pexpect.EOF)
    p.close()
    assert p.exitstatus == 2 and "already holds a session" in p.before
    assert sorted(x.name for x in out.iterdir()) == kept
