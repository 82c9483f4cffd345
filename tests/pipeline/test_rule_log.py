"""Rule scripts log through pipeline.common.rule_log: a failure's traceback reaches the job's log and Snakemake's
output (with ``sys.stderr`` assigned to a log that ``with open(...)`` had closed, Python printed only "lost
sys.stderr")."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = """
import types
from neckstrength.pipeline.common import rule_log
snakemake = types.SimpleNamespace(log=[{log!r}])
with rule_log(snakemake):
    print("progress line")
    raise ValueError("the reason it failed")
"""


def test_traceback_reaches_the_log_and_stderr(tmp_path):
    log = tmp_path / "job.log"
    r = subprocess.run([sys.executable, "-c", SCRIPT.format(log=str(log))], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 1
    text = log.read_text()
    assert "progress line" in text and "ValueError: the reason it failed" in text and "Traceback" in text
    assert "ValueError: the reason it failed" in r.stderr and "lost sys.stderr" not in r.stderr


def test_every_rule_script_uses_it():
    scripts = sorted((ROOT / "workflow" / "scripts").glob("*.py"))
    assert len(scripts) > 30
    bad = [p.name for p in scripts if "sys.stderr =" in p.read_text() or "rule_log(snakemake)" not in p.read_text()]
    assert not bad, f"rule scripts that assign sys.stderr themselves or do not log through rule_log: {bad}"
