"""The session engine's programmatic API (src/neckstrength/session/state.py): create, propose, tell, undo, stop and
snapshot(), the calls a front end other than the terminal uses. Checked: each acknowledged record is the log's last line
on disk when tell returns; a rejected entry changes nothing; snapshot() is plain JSON (no NaN) and a resumed session's
snapshot() equals the state before the pause; the terminal (run_interactive) and the API give identical numbers for
identical entries. Small sizes (p2m7, N_F 2,000; s3m24 joint, N 300) keep it to a few seconds."""

import io
import json
from pathlib import Path

import pandas as pd
import pytest

from neckstrength.session import Entry, InputError, Session, SessionOptions, run_interactive
from neckstrength.session.log import release

ROOT = Path(__file__).resolve().parents[2]
CFG = str(ROOT / "config" / "config.ci.yaml")
LOG = "session.log.jsonl"


def _opts(tmp_path, **kw):
    base = {"model": "p2m7", "participant": "P01", "config": CFG, "n_candidates": 2000, "criterion": "thesis",
            "cache": str(tmp_path / "cache")}
    base.update(kw)
    return SessionOptions(**base)


def _last_record(out):
    return json.loads((Path(out) / LOG).read_text().splitlines()[-1])


def test_create_propose_tell_undo_stop(tmp_path):
    out = tmp_path / "s"
    s = Session.create(out, _opts(tmp_path))
    with pytest.raises(FileExistsError, match="already holds a session"):
        Session.create(out, _opts(tmp_path))
    prop = s.propose()
    assert prop["test"] == s.choice(s.proposal()) and prop["units"] == "nats"
    alts = prop["alternatives"]
    assert len(alts) == 7 and sum(a["proposed"] for a in alts) == 1
    scores = [a["score"] for a in alts]
    assert scores == sorted(scores, reverse=True) and alts[0]["test"] == prop["test"] and min(scores) > 0
    assert set(alts[0]["per_muscle"]) == set(s.muscles)

    ack = s.tell("150")                                  # a prompt line: the proposed test
    rec = ack["record"]
    assert (rec["action"], rec["direction"], rec["force_N"], rec["seq"]) == ("measure", prop["test"], 150.0, 1)
    assert _last_record(out) == rec                      # on disk (fsync'd) before tell returned
    assert ack["message"] == f"recorded {prop['test']}: 150 N"
    other = next(a["test"] for a in s.propose()["alternatives"] if not a["proposed"])
    ack2 = s.tell(Entry("measure", other, 90.0, {"TS-B": 0.3}))
    assert _last_record(out) == ack2["record"] and ack2["record"]["seq"] == 2

    n_lines = len((out / LOG).read_text().splitlines())
    before = s.snapshot()
    for bad, msg in [("measure forehead 5000", "implausibly large"), (f"measure {other} 80", "already been tested"),
                     ("help", "terminal command"), ("12 Nm", "wrong unit")]:
        with pytest.raises(InputError, match=msg):
            s.tell(bad)
    assert len((out / LOG).read_text().splitlines()) == n_lines and s.snapshot() == before   # nothing changed

    st = s.snapshot()
    json.dumps(st, allow_nan=False)
    assert (st["step"], st["n_tested"], st["tested"]) == (3, 2, [prop["test"], other])
    assert [m["force_N"] for m in st["measurements"]] == [150.0, 90.0]
    assert st["measurements"][1]["activations"] == {"TS-B": 0.3}
    assert all(m["predicted_N"] > 0 for m in st["measurements"]) and "posterior-mean" in st["predicted_label"]
    rows = pd.DataFrame(st["estimate"]["rows"])
    assert list(rows["muscle"]) == s.muscles and (rows["sd_c"] > 0).all() and (rows["sd_c"] < rows["sd_0"]).any()
    assert "not a calibrated interval" in st["estimate"]["uncertainty_label"] and not st["estimate"]["calibrated"]
    assert st["screen"] == s.render() and st["recommendation"]["text"] in st["screen"]
    assert st["decision"] is None                         # p2m7 has no deep-extensor group

    u = s.undo()
    assert u["message"] == f"undone: measurement {other} (90 N)" and _last_record(out) == u["record"]
    assert s.snapshot()["tested"] == [prop["test"]]
    with pytest.raises(InputError, match="not an untested"):
        s.tell(Entry("skip", prop["test"]))               # a tested direction cannot be skipped

    done = s.stop()
    assert done["record"]["action"] == "stop" and _last_record(out) == done["record"]
    summary = pd.read_csv(done["outputs"]["summary_csv"], comment="#")
    assert summary["f_c"].to_numpy() == pytest.approx(pd.DataFrame(s.snapshot()["estimate"]["rows"])["f_c"], rel=1e-5)
    assert all(Path(p).exists() for p in done["outputs"].values())


def test_resume_gives_identical_state_and_continues(tmp_path):
    out = tmp_path / "s"
    s = Session.create(out, _opts(tmp_path))
    u = Session.create(tmp_path / "u", _opts(tmp_path))          # the same entries, never paused
    s.tell("150")
    s.tell("skip")
    other = next(a["test"] for a in s.propose()["alternatives"] if not a["proposed"] and not a["skipped"])
    for line in ("150", "skip", f"measure {other} 120"):
        u.tell(line)
    s.tell(f"measure {other} 120")
    before = s.snapshot()
    del s                                                       # paused
    r = Session.resume(out)
    assert r.snapshot() == before == u.snapshot()
    assert r.tell("95")["message"] == u.tell("95")["message"]   # and it goes on as the uninterrupted session
    assert r.snapshot() == u.snapshot() and len(r.snapshot()["tested"]) == 3
    assert [x["seq"] for x in map(json.loads, (out / LOG).read_text().splitlines())] == [1, 2, 3, 4]


def test_terminal_and_api_give_identical_numbers(tmp_path):
    lines = ["150", "skip", "measure chinFront 95 act=TS-B:0.4", "undo", "90 N", "stop"]
    a = Session.create(tmp_path / "a", _opts(tmp_path))
    it = iter(lines)
    assert run_interactive(a, lambda _: next(it), io.StringIO()) == 0
    b = Session.create(tmp_path / "b", _opts(tmp_path))
    for line in lines:
        b.tell(line)
    assert a.snapshot() == b.snapshot()
    for f in ("summary.csv", "steps.csv", "measurements.csv"):
        assert ((tmp_path / "a" / f).read_text().replace("session a ", "session b ")
                == (tmp_path / "b" / f).read_text())


def test_joint_session_state_carries_the_decision_and_resumes(tmp_path):
    out = tmp_path / "j"
    s = Session.create(out, SessionOptions(model="s3m24", config=CFG, cache=str(tmp_path / "c")), threads=1)
    assert s.criterion == "joint_eig" and s.propose()["score_name"] == "expected information gain"
    s.tell("150")
    s.tell("measure backLow 120")
    st = s.snapshot()
    json.dumps(st, allow_nan=False)
    dec = st["decision"]
    assert dec["decision"] in ("deficit", "no deficit", "undecided", "model misfit")
    assert len(dec["trend"]) == 3 and 0 <= dec["p_deficit"] <= 1 and dec["trend"][-1] == dec["p_deficit"]
    assert dec["settings"]["prevalence"] > 0 and dec["settings_label"] and "heuristic" in dec["label"]
    assert "\n".join(dec["text"]) in st["screen"]
    assert Session.resume(out, threads=1).snapshot() == st


def test_undo_and_remeasure_with_another_force_proposes_afresh(tmp_path):
    """Undo, then the same test with another force: the next proposal is computed from the new force (as a resume
    computes it), not reused from the undone measurement's."""
    s = Session.create(tmp_path / "u", _opts(tmp_path))
    s.tell("150")
    s.tell("133")
    s.propose()                     # the proposal after 133 N is computed (the screen shows it)
    s.undo()
    s.tell("80")
    st = s.snapshot()
    release(tmp_path / "u")
    assert Session.resume(tmp_path / "u").snapshot() == st
