"""The front door: the README stays short, every relative link in the docs points to a file (and anchor) that
exists, and everything the README's commands import is a declared main dependency (not only something the test
extras happen to pull in, as pygments was for ``snakemake --report``)."""

import ast
import re
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
from packaging.markers import default_environment
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
DOCS = [ROOT / "README.md", ROOT / "CHANGELOG.md", ROOT / "config" / "README.md", *sorted((ROOT / "docs").glob("*.md")),
        *sorted((ROOT / "data").glob("*/README.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
# Imported lazily by a README command, not by our code: snakemake's HTML report needs pygments but snakemake does
# not declare it.
REPORT_IMPORTS = ("pygments",)


def _name(req: str) -> str:
    return re.sub(r"[-_.]+", "-", Requirement(req).name).lower()


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    s = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return s.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    text = path.read_text()
    ids = set(re.findall(r"""<a\s+(?:id|name)=["']([^"']+)["']""", text))
    ids |= {_slug(h) for h in re.findall(r"^#+\s+(.*)$", text, re.M)}
    return ids


def _links(path: Path):
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)     # code blocks are not links
    for m in LINK.finditer(text):
        target = m.group(1)
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):             # http:, https:, mailto:
            continue
        yield text.count("\n", 0, m.start()) + 1, target


def test_docs_found():
    assert (ROOT / "README.md").is_file() and len(DOCS) >= 10


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(doc):
    broken = []
    for line, target in _links(doc):
        path, _, anchor = target.partition("#")
        dest = (doc.parent / path).resolve() if path else doc
        if not dest.exists():
            broken.append(f"{doc.relative_to(ROOT)}:{line}: {target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            broken.append(f"{doc.relative_to(ROOT)}:{line}: {target} (no anchor #{anchor} in {path or doc.name})")
    assert not broken, "broken links:\n" + "\n".join(broken)


def test_link_checker_catches_a_broken_link(tmp_path):
    doc = tmp_path / "x.md"
    (tmp_path / "y.md").write_text("# A heading\n<a id=\"row\"></a>\n")
    doc.write_text("[ok](y.md#row) [ok2](y.md#a-heading) [bad](z.md) ```\n[in code](nope.md)\n``` [web](https://e.org)")
    assert [t for _, t in _links(doc)] == ["y.md#row", "y.md#a-heading", "z.md"]
    assert {"row", "a-heading"} <= _anchors(tmp_path / "y.md")


def test_readme_is_short():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 210, f"README.md has {len(lines)} lines; measured figures belong in docs/benchmarks.md"


def test_readme_headline_rows_link_to_benchmarks():
    text = (ROOT / "README.md").read_text()
    table = text.split("## Headline results", 1)[1].split("\n## ", 1)[0]
    rows = [r for r in table.splitlines() if r.startswith("| ") and not r.startswith("| question")]
    assert len(rows) >= 5
    for r in rows:
        assert "docs/benchmarks.md#" in r or "](docs/" in r, f"headline row without a link to where it is measured: {r}"


def _closure(requirements: list[str]) -> set[str]:
    """Distributions installed by these requirements (without extras), following installed metadata."""
    env = default_environment() | {"extra": ""}
    seen, todo = set(), list(requirements)
    while todo:
        req = Requirement(todo.pop())
        if req.marker is not None and not req.marker.evaluate(env):
            continue
        name = _name(str(req))
        if name in seen:
            continue
        seen.add(name)
        try:
            todo.extend(metadata.requires(name) or [])
        except metadata.PackageNotFoundError:
            pass
    return seen


def _third_party_imports(files) -> dict[str, str]:
    """Top-level module -> first file importing it, for modules that are neither stdlib nor ours."""
    out = {}
    for f in files:
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                mods = [node.module]
            else:
                continue
            for m in mods:
                top = m.split(".")[0]
                if top not in sys.stdlib_module_names and top != "neckstrength":
                    out.setdefault(top, str(f.relative_to(ROOT)))
    return out


def test_report_imports_are_main_dependencies():
    """``snakemake --report`` after ``bash run.sh`` (main dependencies only) needs pygments."""
    main = _closure(PYPROJECT["project"]["dependencies"])
    declared = {_name(r) for r in PYPROJECT["project"]["dependencies"]}
    for mod in REPORT_IMPORTS:
        assert mod in declared, f"{mod} (needed by snakemake --report) is not a main dependency in pyproject.toml"
        assert mod in main


def test_every_import_of_the_package_is_declared():
    """Every third-party module imported by src/ or a rule's script comes with the main dependencies, or belongs
    to an optional extra other than `test` (imported lazily by the command that needs that extra)."""
    main = _closure(PYPROJECT["project"]["dependencies"])
    extras = {k: v for k, v in PYPROJECT["project"]["optional-dependencies"].items() if k != "test"}
    optional = {_name(r) for reqs in extras.values() for r in reqs}
    dists = metadata.packages_distributions()
    files = [*(ROOT / "src").rglob("*.py"), *(ROOT / "workflow" / "scripts").glob("*.py")]
    imports = _third_party_imports(files)
    assert {"numpy", "pandas", "highspy"} <= set(imports)
    missing = []
    for mod, where in sorted(imports.items()):
        names = {_name(d) for d in dists.get(mod, [])} or {_name(mod)}
        if not names & (main | optional):
            missing.append(f"{mod} (imported in {where}; distribution {sorted(names)})")
    assert not missing, "imports that no main dependency provides:\n" + "\n".join(missing)


def test_dependency_closure_follows_requirements():
    """The closure used above is not vacuous: snakemake brings its own requirements, the test extras are left out."""
    main = _closure(PYPROJECT["project"]["dependencies"])
    assert {"snakemake", "numpy", "jinja2"} <= main
    assert "pytest" not in main and "hypothesis" not in main


def test_every_benchmarks_row_has_its_own_anchor():
    # a figure lives once: two rows with one id would make every link to it ambiguous
    import collections

    ids = re.findall(r'<a id="([^"]+)"></a>', (ROOT / "docs" / "benchmarks.md").read_text())
    dup = [k for k, n in collections.Counter(ids).items() if n > 1]
    assert ids and not dup, f"docs/benchmarks.md: anchors used by more than one row: {dup}"
