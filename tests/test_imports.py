"""The package's import graph, read from the source (every ``import``/``from ... import`` of a neckstrength module,
at module level or inside a function; not those under ``if TYPE_CHECKING:``, which never run): no cycle among
neckstrength modules, and nothing outside ``pipeline/`` imports ``neckstrength.pipeline`` (the science and the
applications never depend on the Snakemake glue)."""

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "src" / "neckstrength"

# Imports of neckstrength.pipeline from outside pipeline/ that exist today and are to go. The test fails on any
# other, and when one of these is gone (so the list only shrinks).
KNOWN_PIPELINE_IMPORTS: set[tuple[str, str]] = set()


def _modules(root: Path = PKG) -> dict[str, Path]:
    mods = {}
    for p in root.rglob("*.py"):
        parts = list(p.relative_to(root.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = p
    return mods


def _runtime_nodes(tree: ast.AST):
    """Every node of ``tree`` except those under ``if TYPE_CHECKING:`` (imports for annotations only, never run)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        yield node
        if isinstance(node, ast.If) and getattr(node.test, "id", getattr(node.test, "attr", None)) == "TYPE_CHECKING":
            stack.extend(node.orelse)
            continue
        stack.extend(ast.iter_child_nodes(node))


def import_graph(root: Path = PKG) -> dict[str, set[str]]:
    """Module -> the neckstrength modules it imports (``from pkg import sub`` counts as importing ``pkg.sub``)."""
    mods = _modules(root)

    def resolve(name):
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for m, p in mods.items():
        edges = set()
        package = m if p.name == "__init__.py" else m.rpartition(".")[0]
        for node in _runtime_nodes(ast.parse(p.read_text(), str(p))):
            if isinstance(node, ast.Import):
                edges |= {resolve(a.name) for a in node.names if a.name.split(".")[0] == "neckstrength"}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:                                   # relative: from its package, up level - 1
                    up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    base = ".".join(up + ([node.module] if node.module else []))
                if base.split(".")[0] != "neckstrength":
                    continue
                for a in node.names:
                    sub = f"{base}.{a.name}"
                    edges.add(sub if sub in mods else resolve(base))
        graph[m] = edges - {None, m}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle():
    assert cycles(import_graph()) == []


def test_cycle_detector_finds_a_cycle(tmp_path):
    pkg = tmp_path / "neckstrength"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from neckstrength.sub import b\n")
    (pkg / "sub" / "b.py").write_text("def f():\n    from neckstrength.c import x\n")
    (pkg / "c.py").write_text("from . import a\n")
    (pkg / "d.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from neckstrength import a\n")
    assert cycles(import_graph(pkg)) == [["neckstrength.a", "neckstrength.c", "neckstrength.sub.b"]]
    assert import_graph(pkg)["neckstrength.d"] == set()


def test_only_pipeline_imports_pipeline():
    found = {(m, t) for m, ts in import_graph().items() if not m.startswith("neckstrength.pipeline")
             for t in ts if t == "neckstrength.pipeline" or t.startswith("neckstrength.pipeline.")}
    assert found - KNOWN_PIPELINE_IMPORTS == set(), "outside pipeline/, these import neckstrength.pipeline"
    assert KNOWN_PIPELINE_IMPORTS - found == set(), "gone: remove them from KNOWN_PIPELINE_IMPORTS"


def test_errors_sit_at_the_bottom():
    assert import_graph()["neckstrength.errors"] == set()


def test_test_modules_have_unique_basenames():
    # pytest imports test modules by basename (no __init__.py in tests/): two files of one name in different folders
    # stop the whole collection ("import file mismatch"), which only a full run shows
    from collections import Counter
    from pathlib import Path

    names = Counter(p.name for p in Path(__file__).parent.rglob("test_*.py"))
    assert not [n for n, k in names.items() if k > 1]


def test_every_test_of_the_workflow_copy_runs_in_the_workflow_worker(request):
    # test.sh runs two pytest-xdist workers; tests/conftest.py keeps the modules that name the workflow copy's
    # fixtures in one worker (one reduced pipeline run). A test that reaches those fixtures in another way (a fixture
    # of a conftest, say) would get a second copy and run the pipeline again in the other worker.
    import importlib.util

    spec = importlib.util.spec_from_file_location("tests_root_conftest", Path(__file__).parent / "conftest.py")
    root = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(root)          # by path: "conftest" is also the name of the folders' conftests
    WORKFLOW_FIXTURES, workflow_test_files = root.WORKFLOW_FIXTURES, root.workflow_test_files

    files = workflow_test_files()
    assert "tests/pipeline/test_pipeline.py" in files and "tests/test_imports.py" not in files
    users = {item.nodeid.split("::", 1)[0] for item in request.session.items
             if set(WORKFLOW_FIXTURES) & set(getattr(item, "fixturenames", ()))}
    if not users:
        import pytest

        pytest.skip("subset run: no collected test uses the workflow copy (the full suite checks them)")
    assert users <= files, sorted(users - files)
