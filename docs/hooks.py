"""MkDocs hook: the site is built from the repository's Markdown as it reads on GitHub, plus an API reference.

The pages keep their repository paths (``README.md`` is the front page, ``docs/x.md``, ``config/README.md``,
``data/*/README.md``, ``CHANGELOG.md``), so the relative links written for GitHub resolve unchanged, and every
repository file a page links to (a CSV, a YAML config, a script) is copied into the site, so that with
``mkdocs build --strict`` a link to a file that does not exist fails the build.

The API reference is one generated page per public module of ``src/neckstrength`` (each subpackage and top-level
module; the pipeline glue, which only the Snakemake rules call, is left out), rendered by mkdocstrings from the
docstrings, and appended to the navigation. A new module gets its page without editing anything.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "neckstrength"
PAGES = ("README.md", "CHANGELOG.md", "config/README.md", "data/*/README.md", "docs/*.md", "docs/figures/*")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
NOT_API = {"pipeline", "__init__", "__main__"}


def public_modules() -> dict[str, str]:
    """Public module name -> first line of its docstring: every subpackage and top-level module but the glue."""
    files = {p.parent.name: p for p in SRC.glob("*/__init__.py")} | {p.stem: p for p in SRC.glob("*.py")}
    out = {}
    for name in sorted(set(files) - NOT_API):
        doc = ast.get_docstring(ast.parse(files[name].read_text())) or ""
        out[name] = doc.strip().splitlines()[0].rstrip(".") if doc.strip() else ""
    return out


def _api_pages() -> dict[str, str]:
    mods = public_modules()
    rows = "".join(f"| [{m}]({m}.md) | {d.replace('|', '/')} |\n" for m, d in mods.items())
    pages = {"docs/api/index.md": (
        "# API reference\n\nGenerated from the docstrings by mkdocstrings: one page per subpackage and top-level "
        "module of `neckstrength`. Each subpackage is one concept of the thesis and imports downward only; the "
        "pipeline glue (`neckstrength.pipeline`, called only by the Snakemake rules) is left out.\n\n"
        f"| module | what it holds |\n|---|---|\n{rows}")}
    for m in mods:
        pages[f"docs/api/{m}.md"] = f"# neckstrength.{m}\n\n::: neckstrength.{m}\n"
    return pages


def on_config(config):
    api = [{"Overview": "docs/api/index.md"}, *({m: f"docs/api/{m}.md"} for m in public_modules())]
    config["nav"] = [*(config["nav"] or []), {"API reference": api}] if SRC.is_dir() else config["nav"]
    return config


def _linked(page: Path) -> set[str]:
    """Repository paths of the existing non-Markdown files a page links to (relative links only)."""
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    out = set()
    for m in LINK.finditer(text):
        target = m.group(1).partition("#")[0]
        if not target or re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.endswith(".md"):
            continue
        dest = (page.parent / target).resolve()
        if dest.is_file() and ROOT in dest.parents:
            out.add(str(dest.relative_to(ROOT)))
    return out


def on_files(files: Files, config) -> Files:
    site, udu = config["site_dir"], config["use_directory_urls"]
    paths = sorted({str(p.relative_to(ROOT)) for pattern in PAGES for p in ROOT.glob(pattern) if p.is_file()})
    linked = set().union(*(_linked(ROOT / p) for p in paths if p.endswith(".md")))
    out = Files([File(p, str(ROOT), site, udu) for p in sorted(set(paths) | linked)])
    if SRC.is_dir():
        for path, text in _api_pages().items():
            out.append(File.generated(config, path, content=text))
    docs = Path(config["docs_dir"]).resolve()
    for f in files:   # theme assets and anything a plugin added; the docs folder is laid out above
        if f.abs_src_path and Path(f.abs_src_path).resolve().is_relative_to(docs):
            continue
        if out.get_file_from_path(f.src_uri) is None:
            out.append(f)
    return out
