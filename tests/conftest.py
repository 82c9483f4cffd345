"""Shared fixtures: one temporary copy of the workflow, and one run of the reduced (CI) pipeline in it.

``tests/pipeline/test_pipeline.py``, ``tests/report/test_report.py`` and ``tests/browser/test_report_page.py`` need the
reduced pipeline's outputs; the session fixture :func:`ci_pipeline` runs it once (about 2-3 minutes on 2 cores) for
all, and :func:`ci_report` builds its report once. The copy never touches a user's
``results/``.
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]
CI_CONFIG = "config/config.ci.yaml"
BASE_ENV = [sys.executable, str(ROOT / "tests" / "base_env.py")]    # Python with the main dependencies only


def run_cmd(cmd, cwd, timeout=900):
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="session")
def repo_copy(tmp_path_factory):
    """Snakefile, workflow/, config/ and data/ copied to a temporary directory."""
    d = tmp_path_factory.mktemp("wf")
    for item in ("Snakefile", "workflow", "config", "data"):
        src = ROOT / item
        if src.is_dir():
            shutil.copytree(src, d / item)
        else:
            shutil.copy(src, d / item)
    return d


@pytest.fixture(scope="session")
def ci_pipeline(repo_copy):
    """The reduced pipeline run once in :func:`repo_copy` (``snakemake -c2 --configfile config/config.ci.yaml``)."""
    return run_cmd(SNAKEMAKE + ["-c2", "--configfile", CI_CONFIG], repo_copy, timeout=1800)


@pytest.fixture(scope="session")
def ci_report(repo_copy, ci_pipeline):
    """The reduced pipeline's report, built as a user builds it after ``bash run.sh``: ``snakemake --report`` with
    the main dependencies only (tests/base_env.py hides the test extras) and the repository's default profile
    (profiles/default, which Snakemake loads in the repository). ``report.html`` and ``report.zip`` in
    :func:`repo_copy`; used by tests/report/test_report.py and tests/browser/test_report_page.py."""
    assert ci_pipeline.returncode == 0, ci_pipeline.stdout[-3000:] + ci_pipeline.stderr[-3000:]
    if not (repo_copy / "profiles").exists():
        shutil.copytree(ROOT / "profiles", repo_copy / "profiles")
    for name in ("report.html", "report.zip"):
        r = run_cmd(BASE_ENV + ["-m", "snakemake", "--configfile", CI_CONFIG, "--report", name], repo_copy)
        assert r.returncode == 0, (f"snakemake --report {name} with the main dependencies only:\n"
                                   + r.stdout[-3000:] + r.stderr[-3000:])
    return repo_copy


@pytest.fixture(scope="session")
def p2m7_full_config():
    """(full config, p2m7 model, the 25 test directions), built from the repository root."""
    import os

    from neckstrength.config import build_directions, full_model_from_config, load_config, model_from_config

    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        cfg = load_config(ROOT / "config" / "config.yaml")
        return cfg, model_from_config(full_model_from_config(cfg), cfg, "p2m7"), build_directions(cfg)
    finally:
        os.chdir(cwd)
