"""Shared fixtures: one temporary copy of the workflow, and one run of the reduced (CI) pipeline in it; one headless
Chromium for every browser test (the report page, the app).

``tests/pipeline/test_pipeline.py``, ``tests/report/test_report.py`` and ``tests/browser/test_report_page.py`` need the
reduced pipeline's outputs; the session fixture :func:`ci_pipeline` runs it once (about 2-3 minutes on 2 cores) for
all, and :func:`ci_report` builds its report once. The copy never touches a user's
``results/``.
"""

import os
import re
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


#: Fixtures of the workflow copy: the tests that use them share one copy and one reduced pipeline run
WORKFLOW_FIXTURES = ("repo_copy", "ci_pipeline", "ci_report")


def workflow_test_files() -> set[str]:
    """Test modules (``tests/...py``, as in node ids) that name a fixture of :data:`WORKFLOW_FIXTURES`."""
    pat = re.compile(r"\b(" + "|".join(WORKFLOW_FIXTURES) + r")\b")
    return {p.relative_to(ROOT).as_posix() for p in (ROOT / "tests").rglob("test_*.py") if pat.search(p.read_text())}


#: Modules whose tests must run in one process: test_batched's last test counts the LPs its module compared with
#: HiGHS in this session (>= 100,000)
WHOLE_MODULES = frozenset({"tests/wrench/test_batched.py"})


def pytest_xdist_make_scheduler(config, log):
    """With pytest-xdist and ``--dist loadgroup`` (test.sh: ``-n 2 --dist loadgroup``): every test of a module in
    :func:`workflow_test_files` runs in one worker, so the reduced pipeline is run once, as in a single process, and
    no two processes run Snakemake in one workflow copy; each module of :data:`WHOLE_MODULES` runs in one worker;
    every other test is its own unit, as with ``--dist load``.
    (Not the ``xdist_group`` mark: with pytest 9.2 xdist's group suffix on the node ids no longer takes effect.
    tests/test_imports.py checks that every test using these fixtures is in one of those modules.)"""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    files = workflow_test_files()

    class WorkflowInOneWorker(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            path = nodeid.split("::", 1)[0]
            return "workflow" if path in files else path if path in WHOLE_MODULES else nodeid

    return WorkflowInOneWorker(config, log)


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


@pytest.fixture
def figures(monkeypatch):
    """The figures the plotting functions would close, kept open for inspection (closed after the test)."""
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    yield kept
    monkeypatch.undo()
    for fig in kept:
        plt.close(fig)


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


# -- headless Chromium (Debian's ``chromium``, which test.sh installs when missing, driven by Playwright for Python
# with ``executable_path``: Playwright's own browser downloads are never used; a missing browser is a failure that
# says how to install it, not a skip). One session-scoped browser for all tests: Playwright's sync API cannot run
# two at once.

CHROMIUM_NAMES = ("chromium", "chromium-browser")


def chromium_path() -> str:
    """Path of the system Chromium (``$CHROMIUM`` first), or a clear error."""
    for name in (os.environ.get("CHROMIUM"), *CHROMIUM_NAMES):
        if name and shutil.which(name):
            return shutil.which(name)
    raise RuntimeError("no Chromium found: install Debian's `chromium` (apt-get install chromium; test.sh does "
                       "this when missing) or set CHROMIUM to a Chromium executable")


@pytest.fixture(scope="session")
def browser():
    """One headless Chromium for the session (Playwright, system browser)."""
    from playwright.sync_api import sync_playwright

    path = chromium_path()
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=path, headless=True, args=["--no-sandbox", "--disable-gpu"])
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def page_at(browser):
    """``page_at(width, height)``: a fresh page (own context) with that window size; closed after the test."""
    contexts = []

    def make(width: int = 1400, height: int = 1000):
        ctx = browser.new_context(viewport={"width": width, "height": height})
        contexts.append(ctx)
        return ctx.new_page()

    yield make
    for ctx in contexts:
        ctx.close()
