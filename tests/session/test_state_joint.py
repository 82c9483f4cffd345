"""Clinician session on s3m24 (issue 18 item 4): the joint posterior and joint EIG by default, P(deficit) with its
trend on the screen, undo and resume on the joint posterior, the thesis's criterion as an option."""

import io
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from neckstrength.session import Session, SessionOptions, run_interactive
from neckstrength.session.worker import DecisionProcess
from neckstrength.testing import assert_close

ROOT = Path(__file__).resolve().parents[2]
CFG = str(ROOT / "config" / "config.ci.yaml")      # clinician.session.s3m24: joint_eig, N 300


def _drive(s, lines):
    it = iter(lines)

    def inp(_prompt):
        try:
            return next(it)
        except StopIteration:
            raise EOFError from None

    buf = io.StringIO()
    code = run_interactive(s, inp, buf)
    return code, buf.getvalue()


def test_s3m24_session_defaults_to_joint_eig_and_shows_deficit_trend(tmp_path):
    out = tmp_path / "j"
    s = Session.start(out, SessionOptions(model="s3m24", config=CFG, cache=str(tmp_path / "c")), progress=lambda x: None)
    assert s.joint and s.criterion == "joint_eig" and s.settings.n_candidates == 300
    hdr = json.loads((out / "session.json").read_text())
    assert hdr["options"]["criterion"] == "joint_eig"             # resolved default recorded for resume
    code, text = _drive(s, ["150", "undo", "150", "measure backLow 120"])
    assert code == 3
    assert "Expected information gain about the joint strengths" in text
    # the deficit decision (issue 31): P(deficit) from the Bayes factor of two hypotheses, its trend, what it
    # depends on, and that its Monte Carlo error is a heuristic
    assert "Deep neck extensors (mf, both sides) weak?" in text and "P(deficit) =" in text
    last = text.rsplit("Deep neck extensors", 1)[1].split("\n")
    assert last[0].count("->") == 2 and "trend:" in last[0]          # prior + 2 measurements after the undo
    assert "Bayes factor deficit : normal" in last[1] and "heuristic" in last[1] and "prevalence 50%" in last[1]
    assert "depends on:" in last[2] and "noise 5%" in last[2]
    # CI sizes (300 candidates per hypothesis) are not those the shipped recalibration was measured at (1000)
    # the misfit guard's own line (issue 31): not checked before the decision's minimum number of tests
    assert last[3].strip().startswith("misfit guard: not checked before")
    assert "NOT calibrated: heuristic" in last[4] and "n_candidates 300" in last[4] and "docs/clinician.md" in last[4]
    snap = s.snapshot()
    assert snap["decision"]["calibrated"] is False and "heuristic" in snap["decision"]["label"]
    assert s.decision is not None and len(s.decision.history) == 3
    assert any(w in last[0] for w in ("DEFICIT", "NO DEFICIT", "UNDECIDED"))
    assert len(s.state.tested) == 2
    r = Session.resume(out, progress=lambda x: None)
    assert r.render().split("===", 2)[2] == s.render().split("===", 2)[2]   # same proposal, estimate, P(deficit)
    r.write_summary()
    steps = pd.read_csv(out / "steps.csv", comment="#")
    assert sorted(steps["step"].unique()) == [0, 1, 2] and steps["p_deficit"].between(0, 1).all()
    assert steps["p_deficit_se"].between(0, 0.5).all() and steps["log_bf"].notna().all()
    assert np.allclose(steps.groupby("step")["p_deficit"].first(), [h["p_deficit"] for h in r.decision.history],
                       rtol=1e-5)


def test_s3m24_thesis_criterion_stays_available(tmp_path):
    s = Session.start(tmp_path / "t", SessionOptions(model="s3m24", config=CFG, criterion="thesis", n_candidates=2000,
                                                    cache=str(tmp_path / "c")), progress=lambda x: None)
    assert not s.joint and s.sim is not None
    text = s.render()
    assert "Eq. 6.6; score Eq. 6.7" in text and "thesis scheme" in text and "P(deep-extensor deficit" in text
    with pytest.raises(ValueError, match="priorities"):
        Session.start(tmp_path / "p", SessionOptions(model="s3m24", config=CFG, priorities={"mf-R": 1.0}),
                      progress=lambda x: None)


def test_session_threads_change_speed_only(tmp_path):
    """--threads (the joint posterior's solver threads; default every core) is not in the header and does not change
    the numbers: a session resumed with another thread count renders the same screen."""
    import os

    from neckstrength.session import session_threads

    assert session_threads(None) == session_threads(0) == max(1, os.cpu_count() or 1)
    assert session_threads(3) == 3
    with pytest.raises(ValueError, match="--threads"):
        session_threads(-1)
    out = tmp_path / "t"
    s = Session.start(out, SessionOptions(model="s3m24", config=CFG), progress=lambda x: None, threads=1)
    assert s.state.post.n_threads == 1
    _drive(s, ["150", "measure backLow 120", "measure forehead 90"])
    assert "threads" not in json.loads((out / "session.json").read_text())["options"]
    r = Session.resume(out, progress=lambda x: None, threads=2)
    assert r.state.post.n_threads == 2
    assert r.render().split("===", 2)[2] == s.render().split("===", 2)[2]


def test_speed_switches_change_no_number(tmp_path):
    """The engine's speed switches (numpy's BLAS on one thread; the deficit decision updated beside the joint
    posterior in a worker process, or in a thread) change no number: with both off (the reference of
    benchmarks/bench_app.py) the same entries give the same snapshot, decision included, after every step and after
    an undo; a failing decision update leaves the joint posterior as it was. The samplers' untested wrenches deferred until read
    (JointPosterior.defer_untested) and their LP-free rejections (JointPosterior.dual_bound_reject) change none beyond
    the solver's rounding."""

    class Reference(Session):
        one_blas_thread = False
        concurrent_decision = False

    opts = SessionOptions(model="s3m24", config=CFG, cache=str(tmp_path / "c"))
    s = Session.start(tmp_path / "a", opts, threads=2)
    r = Reference.start(tmp_path / "b", opts, threads=2)
    u = Reference.start(tmp_path / "u", opts, threads=2)

    class InThread(Session):              # the decision in a second thread of this process
        decision_process = False

    t = InThread.start(tmp_path / "t", opts, threads=2)
    assert s.decision is not None
    for post in (u.state.post, *u.decision.posts.values()):    # the untested wrenches solved after every move,
        post.defer_untested = False                             # every rejection decided by LPs
        post.dual_bound_reject = False
    for line in ("150", "120", "undo", "125", "90"):
        s.tell(line)
        r.tell(line)
        u.tell(line)
        t.tell(line)
        a, b, c, d = s.snapshot(), r.snapshot(), u.snapshot(), t.snapshot()
        a.pop("screen"), b.pop("screen"), c.pop("screen"), d.pop("screen")
        assert a == b == d and a["decision"]["log_bf"] == b["decision"]["log_bf"] == d["decision"]["log_bf"]
        # the deferral solves the same LPs in other batches: equal to the solver's rounding
        assert_close(b, c, "snapshot")
    before = s.snapshot()

    assert isinstance(s.decision, DecisionProcess) and not isinstance(r.decision, DecisionProcess)
    assert not isinstance(t.decision, DecisionProcess)
    real_wait = s.decision.push_wait

    def broken():
        real_wait()                   # the worker applied the push: undone there, as a failing decision restores itself
        s.decision.undo()
        raise RuntimeError("decision failed")

    s.decision.push_wait = broken
    with pytest.raises(RuntimeError, match="decision failed"):
        s._push(s.state.likelihood(s.state.remaining[0], 100.0))
    del s.decision.push_wait
    assert s.snapshot() == before
    s.tell("110")                     # the worker in step with the session after the failure (the undone push's
    r.tell("110")                     # LPs left bases in its caches: equal to the solver's rounding)
    a, b = s.snapshot(), r.snapshot()
    a.pop("screen"), b.pop("screen")
    assert_close(a, b, "snapshot")
    assert a["decision"]["trend"][:-1] == b["decision"]["trend"][:-1]
