"""The Snakemake report a user builds after ``bash run.sh`` (issue 33): it builds with the main dependencies only
(not the test extras: tests/base_env.py hides them), stays under 20 MB, and its front page opens at its title in
headless Chromium at 1400x1000, the title inside the window and reachable.

The report is the one tests/report checks too, built once from the reduced pipeline run the tests already make
(``ci_report`` in tests/conftest.py) with the repository's default profile (profiles/default), which a user's
``snakemake --report`` in the repository loads too.
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BASE_ENV = [sys.executable, str(ROOT / "tests" / "base_env.py")]
MAX_MB = 20.0


@pytest.fixture(scope="module")
def report(ci_report):
    return ci_report / "report.html"


def test_base_environment_hides_what_only_the_extras_install():
    """The hook is not vacuous: pytest (test extra) is hidden, and so is pygments once it is not a main
    dependency, which is exactly how the report failed for a new user before pygments was declared."""
    for args, ok in ((["-c", "import pygments, snakemake, numpy"], True), (["-c", "import pytest"], False),
                     (["-c", "import playwright"], False), (["--drop", "pygments", "-c", "import pygments"], False)):
        r = subprocess.run(BASE_ENV + args, capture_output=True, text=True, timeout=120)
        assert (r.returncode == 0) == ok, (args, r.stderr[-1500:])
        if not ok:
            assert "not a main dependency" in r.stderr


def _tiny_workflow(tmp_path: Path, profile: bool) -> Path:
    """A one-rule workflow whose report front page is much taller than the window."""
    (tmp_path / "workflow" / "report").mkdir(parents=True)
    shutil.copy(ROOT / "workflow" / "report" / "stylesheet.css", tmp_path / "workflow" / "report")
    if profile:
        shutil.copytree(ROOT / "profiles", tmp_path / "profiles")
    paragraphs = "\n\n".join(f"Paragraph {i}: " + "words to make the front page tall. " * 6 for i in range(80))
    (tmp_path / "workflow" / "report" / "workflow.rst").write_text(
        f"The first line of the front page\n\nThe title\n=========\n\n{paragraphs}\n")
    (tmp_path / "Snakefile").write_text('report: "workflow/report/workflow.rst"\n\nrule all:\n'
                                        '    output: report("a.txt", category="x")\n    shell: "echo a > {output}"\n')
    for args in (["-c1"], ["--report", "report.html"]):
        r = subprocess.run(BASE_ENV + ["-m", "snakemake", *args], cwd=tmp_path, capture_output=True, text=True,
                           timeout=300)
        assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return tmp_path / "report.html"


@pytest.mark.parametrize("profile", [True, False], ids=["with profiles/default", "without"])
def test_tall_front_page_opens_at_its_top_with_the_profile(tmp_path, page_at, profile):
    """profiles/default's stylesheet keeps a tall front page at its top; without it Snakemake's own style centres
    the page in the window and the first line lands far above it (the check can fail)."""
    page = page_at(1400, 1000)
    page.goto(_tiny_workflow(tmp_path, profile).as_uri(), wait_until="load")
    first = page.get_by_text("The first line of the front page").first
    first.wait_for(state="attached", timeout=30_000)
    y = first.bounding_box()["y"]
    assert (0 <= y < 1000) == profile, f"first line at y = {y:.0f} px"


def test_report_is_small_enough(report):
    mb = report.stat().st_size / 1e6
    assert mb < MAX_MB, f"{report.name} is {mb:.1f} MB (limit {MAX_MB:g} MB)"


def test_front_page_opens_at_its_title(report, page_at):
    page = page_at(1400, 1000)
    page.goto(report.as_uri(), wait_until="load")
    title = page.get_by_text("What was reproduced, and how close").first
    title.wait_for(state="visible", timeout=30_000)
    assert page.evaluate("window.scrollY") == 0
    box = title.bounding_box()
    assert box is not None and 0 <= box["y"] and box["y"] + box["height"] <= 1000, f"title at {box}"
    # the page's first line (the workflow description) is inside the window too, not cut off above it
    first = page.get_by_text("neckstrength: reproduction of").first
    fb = first.bounding_box()
    assert fb is not None and fb["y"] >= 0, f"first line at {fb}"
