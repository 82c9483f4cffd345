"""The README's walk-through cannot go stale: docs/walkthrough.md (written by docs/walkthrough.py) is what the
validate, import and estimate commands print today (re-run here, in-process, on the shipped example lab and
config), and the README's excerpt is the one the script derives from that file. The diagnosis step takes minutes
and is compared by ``python docs/walkthrough.py --check``."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wt():
    spec = importlib.util.spec_from_file_location("walkthrough", ROOT / "docs" / "walkthrough.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def recorded(wt):
    rec = wt.parse_doc((ROOT / "docs" / "walkthrough.md").read_text())
    assert set(rec) == {s[0] for s in wt.STEPS}, f"steps missing from docs/walkthrough.md: {set(rec) ^ set(wt.STEPS)}"
    return rec


def test_fast_steps_print_what_the_walkthrough_shows(wt, recorded):
    now = wt.run_steps(wt.FAST)
    for name in wt.FAST:
        assert now[name] == recorded[name], (f"docs/walkthrough.md is stale at step '{name}' "
                                             f"(run python docs/walkthrough.py --write):\n{now[name]}")


def test_readme_excerpt_is_derived_from_the_walkthrough(wt, recorded):
    readme = (ROOT / "README.md").read_text()
    assert wt.with_readme_block(readme, wt.readme_block(recorded)) == readme, \
        "README's walk-through block differs from docs/walkthrough.md (run python docs/walkthrough.py --write)"
    assert "P01" in wt.readme_block(recorded) and "sigma_c" in recorded["estimate"]


def test_staleness_is_detected(wt, recorded):
    """A changed output makes the comparison fail (the check is not vacuous)."""
    changed = dict(recorded, estimate=recorded["estimate"].replace("converged", "did not converge", 1))
    assert wt.readme_block(changed) != wt.readme_block(recorded)
    doc = wt.render_doc(changed)
    assert wt.parse_doc(doc)["estimate"] != recorded["estimate"]
    assert wt.parse_doc(wt.render_doc(recorded)) == recorded
