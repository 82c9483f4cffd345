"""The session log's integrity: a hash chain and sequence numbers verified on resume (gap, duplicate, broken chain
named by line), old logs without the chain still read, a torn last line kept in ``.torn`` and reported, and one
process per session folder (the lock names the holder's pid)."""

import hashlib
import json
import os
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

import pytest

from neckstrength.cli import main
from neckstrength.session import SessionLog, SessionOptions, effective_entries

ROOT = Path(__file__).resolve().parents[2]


def _write(path, n=3):
    log = SessionLog(path)
    for k in range(1, n + 1):
        log.append({"seq": k, "action": "measure", "direction": f"d{k}", "force_N": 100.0 + k})
    return path.read_bytes().splitlines()


def _reread(path):
    return SessionLog(path).read()


def test_every_record_carries_the_hash_of_the_previous_line(tmp_path):
    lines = _write(tmp_path / "session.log.jsonl")
    recs = [json.loads(x) for x in lines]
    assert recs[0]["prev"] == hashlib.sha256(b"").hexdigest()
    assert [r["prev"] for r in recs[1:]] == [hashlib.sha256(x).hexdigest() for x in lines[:-1]]
    assert [r["seq"] for r in _reread(tmp_path / "session.log.jsonl")] == [1, 2, 3]


def test_duplicated_record_is_refused(tmp_path):
    p = tmp_path / "session.log.jsonl"
    lines = _write(p)
    p.write_bytes(b"\n".join(lines[:2] + [lines[1], lines[2]]) + b"\n")
    with pytest.raises(ValueError, match=r"session.log.jsonl: line 3: seq 2 after seq 2: a duplicated or reordered "
                                         r"record; refusing to replay it"):
        _reread(p)


def test_removed_record_is_refused(tmp_path):
    p = tmp_path / "session.log.jsonl"
    lines = _write(p)
    p.write_bytes(b"\n".join([lines[0], lines[2]]) + b"\n")
    with pytest.raises(ValueError, match=r"line 2: seq 3 after seq 1: a record is missing \(gap\)"):
        _reread(p)


def test_edited_or_renumbered_record_breaks_the_chain(tmp_path):
    p = tmp_path / "session.log.jsonl"
    lines = _write(p)
    p.write_bytes(b"\n".join([lines[0], lines[1].replace(b"102.0", b"152.0"), lines[2]]) + b"\n")
    with pytest.raises(ValueError, match=r"line 3: broken chain \(its 'prev' is not the hash of the line before it"):
        _reread(p)


def _legacy(p, seqs):
    p.write_text("".join(json.dumps({"seq": s, "action": "skip", "direction": f"d{s}"}, sort_keys=True) + "\n"
                         for s in seqs))


def test_old_log_without_chain_still_reads_and_is_chained_on(tmp_path):
    p = tmp_path / "session.log.jsonl"
    _legacy(p, [1, 2])
    log = SessionLog(p)
    assert [r["seq"] for r in log.read()] == [1, 2]
    log.append({"seq": 3, "action": "undo"})
    last_old = p.read_bytes().splitlines()[1]
    assert json.loads(p.read_bytes().splitlines()[2])["prev"] == hashlib.sha256(last_old).hexdigest()
    assert [r["direction"] for r in effective_entries(_reread(p))] == ["d1"]


@pytest.mark.parametrize("seqs, message", [
    ([1, 2, 2, 3], r"line 3: seq 2 after seq 2: a duplicated or reordered record"),
    ([1, 3], r"line 2: seq 3 after seq 1: a record is missing \(gap\)"),
])
def test_old_log_gap_or_duplicate_is_refused(tmp_path, seqs, message):
    p = tmp_path / "session.log.jsonl"
    _legacy(p, seqs)
    with pytest.raises(ValueError, match=message):
        _reread(p)


def test_torn_last_line_is_kept_and_reported(tmp_path):
    p = tmp_path / "session.log.jsonl"
    _write(p, 2)
    with open(p, "ab") as fh:
        fh.write(b'{"action": "meas')
    log = SessionLog(p)
    assert [r["seq"] for r in log.read()] == [1, 2]
    assert (tmp_path / "session.log.jsonl.torn").read_bytes() == b'{"action": "meas\n'
    assert "line 3 was cut off mid-write" in log.notice and "session.log.jsonl.torn" in log.notice
    assert p.read_bytes().endswith(b"}\n")


_HOLDER = """
import sys, time
from neckstrength.session import SessionLog
SessionLog(sys.argv[1]).read()
print("locked", flush=True)
time.sleep(60)
"""


@pytest.fixture()
def held(tmp_path):
    """A session folder whose lock another process holds."""
    folder = tmp_path / "s"
    folder.mkdir()
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(folder / "session.log.jsonl")],
                            stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert proc.stdout.readline().strip() == "locked"
        yield folder, proc.pid
    finally:
        proc.kill()
        proc.wait()


def test_second_process_is_refused_naming_the_holder(held):
    folder, pid = held
    with pytest.raises(ValueError, match=rf"the session is open in another process \(pid {pid} since "):
        SessionLog(folder / "session.log.jsonl")


def test_second_resume_is_refused(held, capsys, monkeypatch):
    folder, pid = held
    monkeypatch.chdir(ROOT)
    header = {"format": "neckstrength-session/1", "options": asdict(SessionOptions(model="p2m7", criterion="thesis",
                                                                                    n_candidates=2000)),
              "sim_key": "x"}
    (folder / "session.json").write_text(json.dumps(header))
    assert main(["session", "resume", "--out", str(folder)]) == 2
    err = capsys.readouterr().err
    assert f"the session is open in another process (pid {pid} since" in err
    assert not (folder / "session.log.jsonl").exists()


def test_log_drops_torn_tail_and_undo_folding(tmp_path):
    log = SessionLog(tmp_path / "l.jsonl")
    log.append({"action": "measure", "direction": "a", "force_N": 1.0})
    log.append({"action": "skip", "direction": "b"})
    log.append({"action": "undo"})
    with open(log.path, "ab") as fh:
        fh.write(b'{"action": "meas')                       # killed mid-write
    recs = log.read()
    assert [r["action"] for r in recs] == ["measure", "skip", "undo"]
    assert log.path.read_bytes().endswith(b"}\n")
    assert [r["direction"] for r in effective_entries(recs)] == ["a"]
