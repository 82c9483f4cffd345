"""A killed run resumes by rerunning the README's command (`bash run.sh TARGET`): the default workflow profile
(profiles/default, rerun-incomplete) is loaded, and the lock the killed Snakemake left is removed by run.sh."""

import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TARGET = "results/chapter5/p2m7/S003/estimate.csv"      # one Algorithm 4 run (~15 s on 2 cores)


def _copy(tmp_path) -> Path:
    d = tmp_path / "wf"
    d.mkdir()
    for item in ("Snakefile", "workflow", "config", "data", "profiles", "run.sh"):
        src = ROOT / item
        if src.exists():
            (shutil.copytree if src.is_dir() else shutil.copy)(src, d / item)
    (d / "setup.sh").write_text("#!/usr/bin/env bash\n")          # the environment exists: nothing to install
    (d / ".venv").symlink_to(ROOT / ".venv")
    return d


def _working_in(d: Path) -> list[int]:
    """Processes (of this user) whose working directory is ``d``: what the killed run started."""
    out = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            try:
                if os.readlink(proc / "cwd") == str(d):
                    out.append(int(proc.name))
            except OSError:
                pass
    return out


def test_default_profile_is_loaded(tmp_path):
    d = _copy(tmp_path)
    r = subprocess.run([str(d / ".venv" / "bin" / "snakemake"), "-n", "results/geometry/directions.csv"], cwd=d,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Using workflow specific profile profiles/default" in r.stdout + r.stderr


def test_killed_run_resumes_with_the_same_command(tmp_path):
    d = _copy(tmp_path)
    log = open(tmp_path / "first.log", "w")
    p = subprocess.Popen(["bash", "run.sh", TARGET], cwd=d, stdout=log, stderr=subprocess.STDOUT,
                         start_new_session=True)
    try:
        deadline = time.time() + 240
        while "rule chapter5_estimate" not in (tmp_path / "first.log").read_text():
            assert p.poll() is None and time.time() < deadline, (tmp_path / "first.log").read_text()
            time.sleep(0.5)
        time.sleep(2)
    finally:
        os.killpg(p.pid, signal.SIGKILL)                          # the whole run, mid-job
        p.wait()
        for pid in _working_in(d):                                # a job Snakemake started in its own session
            os.kill(pid, signal.SIGKILL)
    assert not (d / TARGET).exists()
    assert os.listdir(d / ".snakemake" / "locks") and os.listdir(d / ".snakemake" / "incomplete")
    r = subprocess.run(["bash", "run.sh", TARGET], cwd=d, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "removing the lock an interrupted run left behind" in r.stderr
    assert (d / TARGET).exists()
    assert not os.listdir(d / ".snakemake" / "incomplete")
