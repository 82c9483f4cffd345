"""The documentation site: ``mkdocs build --strict`` of mkdocs.yml succeeds (every page in the nav, every relative
link and anchor resolves, the API reference renders from the docstrings), and the same settings fail a build whose
page has a broken link or anchor, so a green build means something."""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
MKDOCS = [sys.executable, "-m", "mkdocs", "build", "--strict"]
SRC = ROOT / "src" / "neckstrength"


def _build(config: Path, site: Path):
    return subprocess.run(MKDOCS + ["-f", str(config), "-d", str(site)], capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    out = tmp_path_factory.mktemp("site")
    r = _build(ROOT / "mkdocs.yml", out)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-4000:]
    return out


def test_site_builds_with_every_page(site):
    assert (site / "index.html").is_file()                                     # README.md is the front page
    for md in [*(ROOT / "docs").glob("*.md"), ROOT / "CHANGELOG.md", ROOT / "config" / "README.md"]:
        rel = md.relative_to(ROOT).with_suffix("")
        rel = rel.parent if rel.name == "README" else rel                       # a folder's README is its index
        assert (site / rel / "index.html").is_file(), f"{md.relative_to(ROOT)} is not in the site"
    assert "docs/benchmarks/#ci" in (site / "index.html").read_text()       # GitHub links rewritten for the site


def test_api_reference_covers_every_public_module(site):
    """One API page per subpackage and top-level module (the pipeline glue excepted), rendered from docstrings."""
    public = {p.parent.name for p in SRC.glob("*/__init__.py")} | {p.stem for p in SRC.glob("*.py")}
    public -= {"pipeline", "__init__", "__main__"}
    assert {"wrench", "gap", "config", "cli"} <= public
    missing = [m for m in public if not (site / "docs" / "api" / m / "index.html").is_file()]
    assert not missing, f"modules without an API page: {sorted(missing)}"
    html = (site / "docs" / "api" / "wrench" / "index.html").read_text()
    assert "doc-heading" in html and "max_wrench" in html                       # mkdocstrings rendered the module
    assert 'href="wrench/"' in (site / "docs" / "api" / "index.html").read_text()


def _mini_site(tmp_path: Path, readme: str) -> Path:
    """A two-page site with the repository's hook, validation and Markdown settings."""
    cfg = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "hooks.py").write_text((ROOT / "docs" / "hooks.py").read_text())
    (tmp_path / "docs" / "a.md").write_text('# Page a\n\n<a id="row"></a>\n\n## A heading\n')
    (tmp_path / "README.md").write_text(readme)
    mini = {k: cfg[k] for k in ("docs_dir", "exclude_docs", "hooks", "validation", "markdown_extensions", "theme")}
    mini |= {"site_name": "mini", "nav": [{"Home": "README.md"}, {"a": "docs/a.md"}]}   # no src/: no API pages
    (tmp_path / "mkdocs.yml").write_text(yaml.safe_dump(mini))
    return tmp_path / "mkdocs.yml"


@pytest.mark.parametrize("link, ok", [("docs/a.md#row", True), ("docs/a.md#a-heading", True),
                                      ("docs/b.md", False), ("docs/a.md#no-such-anchor", False)])
def test_strict_build_fails_on_a_broken_link(tmp_path, link, ok):
    r = _build(_mini_site(tmp_path, f"# Mini\n\nSee [there]({link}).\n"), tmp_path / "site")
    assert (r.returncode == 0) == ok, r.stdout[-2000:] + r.stderr[-2000:]
    if not ok:
        assert link.split("/")[-1].split("#")[-1] in r.stderr
