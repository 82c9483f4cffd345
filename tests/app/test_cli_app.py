"""`neckstrength app` as a user starts it: it prints a 127.0.0.1 URL with its token and serves it; killed (SIGKILL)
right after acknowledging a measurement, it has lost nothing: started again, the session resumes with it."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request

import pytest

from app_constants import CFG, P2M7, ROOT


def _start(root, cache):
    p = subprocess.Popen([sys.executable, "-m", "neckstrength.cli", "app", "--root", str(root), "--config", CFG,
                          "--cache", cache, "--threads", "1", "--no-browser"], cwd=ROOT, stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    line = p.stdout.readline()
    m = re.search(r"open (http://127\.0\.0\.1:(\d+)/)\?token=([0-9a-f]{48})\b", line)
    assert m, line
    return p, m.group(1), m.group(3)


def _call(url, token, method="GET", body=None):
    req = urllib.request.Request(url, method=method, headers={"X-Neckstrength-Token": token,
                                                              "Content-Type": "application/json"},
                                 data=None if body is None else json.dumps(body).encode())
    for _ in range(100):
        try:
            with urllib.request.urlopen(req, timeout=120) as r:
                return r.status, json.load(r) if "json" in r.headers.get("content-type", "") else r.read()
        except urllib.error.URLError as exc:      # not listening yet
            if isinstance(exc, urllib.error.HTTPError):
                raise
            time.sleep(0.1)
    raise RuntimeError(f"{url}: no answer")


def test_app_command_serves_and_a_kill_loses_nothing(tmp_path, cache_dir):
    root = tmp_path / "sessions"
    p, base, token = _start(root, cache_dir)
    try:
        status, page = _call(base + f"?token={token}", token)
        assert status == 200 and b"New session" in page
        with pytest.raises(urllib.error.HTTPError) as e:
            _call(base + "api/sessions", "0" * 48)
        assert e.value.code == 403
        _call(base + "api/sessions", token, "POST", {"name": "K", **P2M7})
        status, ans = _call(base + "api/sessions/K/tell", token, "POST", {"force_N": 155.5})
        assert status == 200 and ans["record"]["seq"] == 1
    finally:
        p.send_signal(signal.SIGKILL)           # killed right after the acknowledgement
        p.wait(30)
    p, base, token = _start(root, cache_dir)
    try:
        _, st = _call(base + "api/sessions/K", token)
        assert [m["force_N"] for m in st["snapshot"]["measurements"]] == [155.5]
        assert st["snapshot"]["measurements"][0]["test"] == ans["record"]["direction"]
    finally:
        p.send_signal(signal.SIGINT)            # Ctrl-C: a clean stop
        assert p.wait(30) == 0
