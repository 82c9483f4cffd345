"""The ask/tell API as a client uses it (Starlette's TestClient): a whole session, resume, export, the same numbers
as the terminal's engine and as ``session replay``, the token and Host checks, bad input named, concurrent tells."""

from __future__ import annotations

import json
import threading

from app_constants import CFG, HDR, P2M7, TOKEN

from neckstrength.session import LOG, InputError, Session, SessionLog, SessionOptions, replay_into
from neckstrength.session.log import release


def _create(client, name="P01", **kw):
    r = client.post("/api/sessions", json={"name": name, **P2M7, **kw})
    assert r.status_code == 201, r.text
    return r.json()


def _rows(state):
    return [(r["muscle"], r["f_c"], r["sd_c"]) for r in state["snapshot"]["estimate"]["rows"]]


def _data_lines(path):
    return [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]


def test_whole_session_matches_replay(client, tmp_path, cache_dir):
    st = _create(client)
    assert st["snapshot"]["step"] == 1 and st["snapshot"]["proposal"]["test"]
    ask = client.get("/api/sessions/P01/ask").json()
    first = ask["proposal"]["test"]
    assert ask["proposal"]["alternatives"][0]["proposed"] and ask["step"] == 1
    # five tells: the proposed test, best-of-3 trials, another test named, EMG, a trial number
    r = client.post("/api/sessions/P01/tell", json={"force_N": 150.0, "expect_step": 1}).json()
    assert r["record"]["direction"] == first and r["record"]["force_N"] == 150.0 and r["state"]["snapshot"]["step"] == 2
    r = client.post("/api/sessions/P01/tell", json={"trials_N": [101.0, 118.5, 112.0]}).json()
    assert r["record"]["force_N"] == 118.5
    untested = r["state"]["snapshot"]["remaining"]
    named = [t for t in untested if t != r["state"]["snapshot"]["proposal"]["test"]][0]
    r = client.post("/api/sessions/P01/tell", json={"direction": named, "posture": "neutral", "force_N": 90}).json()
    assert r["record"]["direction"] == named
    r = client.post("/api/sessions/P01/tell", json={"force_N": 80.5, "activations": {"TS-B": 0.4}}).json()
    assert r["record"]["activations"] == {"TS-B": 0.4}
    r = client.post("/api/sessions/P01/tell", json={"force_N": 133, "trial": 2}).json()
    assert r["state"]["snapshot"]["n_tested"] == 5
    trials = [json.loads(x) for x in (client.root / "P01" / "trials.jsonl").read_text().splitlines()]
    assert [t["trials_N"] for t in trials] == [[101.0, 118.5, 112.0], [133.0]] and trials[1]["trial"] == 2
    # undo the last one, then a sixth test
    r = client.post("/api/sessions/P01/undo", json={}).json()
    assert r["message"].startswith("undone") and r["state"]["snapshot"]["n_tested"] == 4
    r = client.post("/api/sessions/P01/tell", json={"force_N": 140}).json()
    before = client.get("/api/sessions/P01").json()
    # reload: the app gives the folder back and resumes it from the log: the same state
    assert client.post("/api/sessions/P01/close").json() == {"closed": True}
    again = client.get("/api/sessions/P01").json()
    assert again["snapshot"] == before["snapshot"]
    # stop: the outputs, downloadable; the report
    r = client.post("/api/sessions/P01/stop", json={}).json()
    assert set(r["outputs"]) == {"summary_csv", "summary_png", "steps_csv", "measurements_csv", "report_html"}
    assert r["state"]["stopped"]
    for f in ("summary.csv", "measurements.csv", "steps.csv", "summary.png", "report.html"):
        got = client.get(f"/api/sessions/P01/files/{f}")
        assert got.status_code == 200 and got.content == (client.root / "P01" / f).read_bytes()
    rep = client.get("/s/P01/report").text
    assert "P(deficit)" not in rep or "calibrated" in rep
    assert f"{before['view']['groups'][0]['pct_expected']:.0f} %" in rep
    # the same entries through `session replay`: the same numbers
    out = tmp_path / "replay"
    opts = SessionOptions(participant="P01", config=CFG, cache=cache_dir, **{k: v for k, v in P2M7.items()
                                                                             if k != "participant"})
    assert replay_into(out, opts, client.root / "P01" / "measurements.csv", threads=1) == 0
    assert _data_lines(out / "summary.csv") == _data_lines(client.root / "P01" / "summary.csv")
    assert _data_lines(out / "steps.csv") == _data_lines(client.root / "P01" / "steps.csv")
    release(out)


def test_terminal_to_browser_and_back(client, cache_dir):
    """A session started by the engine as the terminal drives it resumes in the app, and back, identically."""
    folder = client.root / "T1"
    opts = SessionOptions(participant="P01", config=CFG, cache=cache_dir, **{k: v for k, v in P2M7.items()
                                                                             if k != "participant"})
    s = Session.create(folder, opts, threads=1)
    for line in ("160", "skip", "120 N"):
        s.tell(line)
    snap = s.snapshot()
    release(folder)                                    # the terminal pauses (Ctrl-D)
    st = client.get("/api/sessions/T1").json()
    assert st["snapshot"] == snap
    st = client.post("/api/sessions/T1/tell", json={"force_N": 99.5}).json()["state"]
    assert client.post("/api/sessions/T1/close").json()["closed"]
    back = Session.resume(folder, threads=1)           # the terminal again
    assert back.snapshot() == st["snapshot"]
    release(folder)


def test_emg_channels_chosen_at_start(client, cache_dir):
    """The start page's EMG channels: offered per model (surface EMG of config chapter6.emg_groups, the deficit group
    as deep channels), stored in session.json, the only channels a tell (or the terminal's act=) accepts; a bad value
    or another channel is a 422 naming the channel; a terminal resume sees the same channels."""
    offer = client.get("/api/sessions").json()["emg"]
    assert offer["p2m7"] == {"surface": ["TS-B", "TS-E"], "deep": []}
    assert offer["s3m24"]["deep"] == ["mf-R", "mf-L"] and "SCM-R" in offer["s3m24"]["surface"]
    r = client.post("/api/sessions", json={"name": "E0", **P2M7, "emg_channels": ["TS-X"]})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "emg_channels"]
    assert "TS-B" in r.json()["detail"][0]["msg"]
    st = _create(client, "E1", emg_channels=["TS-E", "TS-B"])
    assert st["snapshot"]["emg"]["channels"] == ["TS-B", "TS-E"]        # in the model's muscle order
    assert json.loads((client.root / "E1" / "session.json").read_text())["options"]["emg_channels"] == ["TS-B", "TS-E"]
    for acts, loc in (({"TC-E": 0.3}, ["body", "activations", "TC-E"]), ({"TS-E": -0.1}, ["body", "activations", "TS-E"]),
                      ({"TS-B": 0.2, "TS-E": 2}, ["body", "activations", "TS-E"])):
        r = client.post("/api/sessions/E1/tell", json={"force_N": 100, "activations": acts})
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == loc, r.text
    assert "not chosen" in client.post("/api/sessions/E1/tell", json={"force_N": 100, "activations": {"TC-E": 0.3}}
                                       ).json()["detail"][0]["msg"]
    r = client.post("/api/sessions/E1/tell", json={"force_N": 100, "activations": {"TS-E": 0.35}}).json()
    assert r["record"]["activations"] == {"TS-E": 0.35}
    assert client.post("/api/sessions/E1/close").json()["closed"]
    s = Session.resume(client.root / "E1", threads=1)                 # the terminal sees the same channels
    assert s.emg_channels == ["TS-B", "TS-E"] and s.snapshot()["emg"]["channels"] == ["TS-B", "TS-E"]
    try:
        s.tell("90 act=TC-E:0.2")
        raise AssertionError("act= of a channel not chosen was accepted")
    except InputError as exc:
        assert "not chosen" in str(exc)
    release(client.root / "E1")
    st = _create(client, "E2", emg_channels=[])                      # none ticked: forces only
    assert st["snapshot"]["emg"]["channels"] == []
    r = client.post("/api/sessions/E2/tell", json={"force_N": 100, "activations": {"TS-B": 0.3}})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "activations", "TS-B"]


def test_token_and_host(make_app):
    from fastapi.testclient import TestClient

    app, _ = make_app()
    c = TestClient(app, base_url="http://127.0.0.1")
    assert c.get("/api/sessions").status_code == 403
    assert c.get("/api/sessions", headers={"X-Neckstrength-Token": "wrong"}).status_code == 403
    assert c.get("/", params={"token": TOKEN[:-1]}).status_code == 403
    r = c.get("/", params={"token": TOKEN})              # the URL the app prints: sets the cookie
    cookie = r.headers["set-cookie"]
    assert r.status_code == 200 and "HttpOnly" in cookie and "SameSite=Strict" in cookie
    assert c.get("/api/sessions").status_code == 200     # GET with the cookie
    r = c.post("/api/sessions", json={"name": "X", **P2M7})   # a write with the cookie only: refused
    assert r.status_code == 403 and "X-Neckstrength-Token" in r.json()["detail"][0]["msg"]
    for host in ("evil.example", "127.0.0.1.evil.example", "localhost.evil:80"):
        r = c.get("/api/sessions", headers={**HDR, "host": host})
        assert r.status_code == 403 and r.json()["detail"][0]["loc"] == ["host"]
    for host in ("localhost:8000", "127.0.0.1:1234", "[::1]:80"):
        assert c.get("/api/sessions", headers={**HDR, "host": host}).status_code == 200
    assert c.get("/openapi.json", headers=HDR).status_code == 200
    assert c.get("/docs", headers=HDR).status_code == 404        # no CDN-loaded docs page


BAD_TELLS = [
    ({"force_N": "abc"}, "force_N"), ({"force_N": -1}, "force_N"), ({"force_N": 0}, "force_N"),
    ({"force_N": 2500}, "force_N"), ({}, "force_N"), ({"force_N": 100, "trials_N": [100]}, "force_N"),
    ({"trials_N": [100, -2]}, "trials_N"), ({"trials_N": []}, "trials_N"),
    ({"force_N": 100, "direction": "sideways"}, "direction"), ({"force_N": 100, "test": "flex20:back"}, "test"),
    ({"force_N": 100, "activations": {"XX": 0.3}}, ("activations", "XX")),
    ({"force_N": 100, "activations": {"TS-B": 1.5}}, ("activations", "TS-B")),
    ({"force_N": 100, "activations": {"TS-B": "high"}}, ("activations", "TS-B")), ({"force_N": 100, "colour": "red"}, "colour"),
    ({"force_N": 100, "trial": 0}, "trial"), ({"force_N": 100, "expect_step": "two"}, "expect_step"),
]


def test_bad_tell_names_the_field(client):
    _create(client)
    for body, field in BAD_TELLS:
        r = client.post("/api/sessions/P01/tell", json=body)
        assert r.status_code == 422, (body, r.text)
        loc = r.json()["detail"][0]["loc"]
        assert (tuple(loc[-2:]) if isinstance(field, tuple) else loc[-1]) == field, (body, r.json())
    assert client.get("/api/sessions/P01").json()["snapshot"]["n_tested"] == 0     # nothing changed
    assert not (client.root / "P01" / LOG).exists() or not (client.root / "P01" / LOG).read_text().strip()


def test_bad_requests_are_4xx(client):
    assert client.post("/api/sessions", json={"name": "../x", **P2M7}).json()["detail"][0]["loc"] == ["body", "name"]
    assert client.post("/api/sessions", json={"name": "A", "model": "p9"}).json()["detail"][0]["loc"] == ["body",
                                                                                                          "model"]
    r = client.post("/api/sessions", json={"name": "A", **P2M7, "postures": "upside"})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "postures"]
    assert not (client.root / "A").exists()                 # a refused session leaves no folder behind
    assert client.post("/api/sessions", json={"name": "A", "n_candidates": 10**9}).status_code == 422
    assert client.post("/api/sessions", json={"name": "A", "speed": 3}).json()["detail"][0]["loc"] == ["body", "speed"]
    _create(client)
    assert client.post("/api/sessions", json={"name": "P01", **P2M7}).status_code == 409
    assert client.get("/api/sessions/nobody").status_code == 404
    assert client.get("/api/sessions/..%2Fx").status_code in (404, 422)
    assert client.post("/api/sessions/P01/undo").status_code == 422                 # nothing to undo
    assert client.get("/api/sessions/P01/files/summary.csv").status_code == 422     # not stopped yet
    assert client.get("/api/sessions/P01/files/secret.txt").status_code == 422
    r = client.post("/api/sessions/P01/tell", json={"force_N": 100, "expect_step": 3})
    assert r.status_code == 409 and "moved on" in r.json()["detail"][0]["msg"]
    assert client.post("/api/sessions/P01/tell", content=b"{not json", headers={"content-type":
                                                                                 "application/json"}).status_code == 422
    assert client.post("/api/sessions/P01/tell", content=b'{"force_N": NaN}',
                       headers={"content-type": "application/json"}).status_code == 422


def test_concurrent_tells_keep_the_log_intact(client):
    """Eight clients tell at once (two for each of four tests): every request is answered (200, or 422 for a test
    already taken), the log's hash chain verifies, and it holds one measurement per test."""
    _create(client)
    tests = client.get("/api/sessions/P01").json()["snapshot"]["tests"][:4]
    codes = []

    def tell(t, f):
        codes.append(client.post("/api/sessions/P01/tell", json={"direction": t, "force_N": f}).status_code)

    threads = [threading.Thread(target=tell, args=(t, 100 + i)) for i in range(2) for t in tests]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert sorted(codes) == [200] * 4 + [422] * 4
    folder = client.root / "P01"
    assert client.post("/api/sessions/P01/close").json()["closed"]
    recs = SessionLog(folder / LOG).read()             # verifies seq and the hash chain
    assert [r["seq"] for r in recs] == [1, 2, 3, 4] and sorted(r["direction"] for r in recs) == sorted(tests)
    release(folder)


def test_locked_folder_is_refused_clearly(client, cache_dir):
    """A session open in another process (the terminal) is refused with 409 naming the holder."""
    import subprocess
    import sys

    folder = client.root / "L1"
    opts = SessionOptions(participant="P01", config=CFG, cache=cache_dir, **{k: v for k, v in P2M7.items()
                                                                             if k != "participant"})
    Session.create(folder, opts, threads=1)
    release(folder)
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl,sys,time; f=open(sys.argv[1],'a+'); "
                               "fcntl.flock(f, fcntl.LOCK_EX); f.write('pid terminal'); f.flush(); "
                               "print('ok', flush=True);"
                               " time.sleep(60)", str(folder / "session.lock")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "ok"
        r = client.get("/api/sessions/L1")
        assert r.status_code == 409 and "another process" in r.json()["detail"][0]["msg"]
    finally:
        holder.kill()
        holder.wait()


def test_pages_escape_what_a_user_typed(client):
    """A participant name with markup is shown as text on every page and in the report, never run."""
    _create(client, participant='<script>alert(1)</script>"x')
    client.post("/api/sessions/P01/tell", json={"force_N": 150})
    client.post("/api/sessions/P01/stop", json={})
    for path in ("/", "/s/P01/end", "/s/P01/report"):
        html = client.get(path).text
        assert "<script>alert(1)" not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html, path
    assert "<script>alert(1)" not in (client.root / "P01" / "report.html").read_text()
