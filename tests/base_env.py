"""Run Python as if only the main dependencies were installed: the environment ``bash run.sh`` makes.

``python tests/base_env.py -m snakemake --report report.html`` (or ``-c CODE``) runs with an import hook that
refuses every third-party top-level module whose distribution is not in the closure of pyproject.toml's
``[project] dependencies`` (the test extras, docs, playwright, ...), exactly as if it were not installed: a
``try: import x / except ImportError`` sees it missing, a hard import fails with ``ModuleNotFoundError``. This is
how CI checks that a README command works after ``bash run.sh`` without building a second virtual environment.
``--drop NAME`` removes a distribution from the allowed set (the tests use it to show the hook bites).
"""

from __future__ import annotations

import importlib.abc
import pkgutil
import re
import runpy
import sys
import tomllib
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _name(req: str) -> str:
    from packaging.requirements import Requirement

    return re.sub(r"[-_.]+", "-", Requirement(req).name).lower()


def main_closure(drop: tuple[str, ...] = ()) -> set[str]:
    """Normalised names of the distributions the main dependencies install (no extras), from installed metadata."""
    from packaging.markers import default_environment
    from packaging.requirements import Requirement

    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    env = default_environment() | {"extra": ""}
    seen, todo = {"neckstrength"}, [d for d in deps if _name(d) not in drop]
    while todo:
        req = Requirement(todo.pop())
        if req.marker is not None and not req.marker.evaluate(env):
            continue
        name = _name(str(req))
        if name in seen or name in drop:
            continue
        seen.add(name)
        try:
            todo.extend(metadata.requires(name) or [])
        except metadata.PackageNotFoundError:
            pass
    return seen


class MainDependenciesOnly(importlib.abc.MetaPathFinder):
    """Refuses top-level modules that only distributions outside ``allowed`` provide."""

    def __init__(self, allowed: set[str]):
        self.allowed = allowed
        self.provides = {m: {re.sub(r"[-_.]+", "-", d).lower() for d in ds}
                         for m, ds in metadata.packages_distributions().items()}

    def find_spec(self, name, path=None, target=None):
        if path is not None or name in sys.stdlib_module_names or name in sys.builtin_module_names:
            return None                                   # submodules follow their top-level package
        dists = self.provides.get(name)
        if not dists or dists & self.allowed:
            return None                                   # ours, the workflow's own, or a main dependency
        raise ModuleNotFoundError(f"No module named {name!r} (base environment: {sorted(dists)} is not a main "
                                  "dependency in pyproject.toml)", name=name)


def main(argv: list[str]) -> None:
    drop = []
    while argv[:1] == ["--drop"]:
        drop.append(argv[1])
        argv = argv[2:]
    if len(argv) < 2 or argv[0] not in ("-m", "-c"):
        sys.exit("usage: python tests/base_env.py [--drop DIST] (-m MODULE | -c CODE) [ARGS...]")
    allowed = main_closure(tuple(drop))
    finder = MainDependenciesOnly(allowed)
    for mod in [m for m in list(sys.modules) if "." not in m]:   # nothing imported so far may leak through
        dists = finder.provides.get(mod)
        if dists and not dists & allowed:
            del sys.modules[mod]
    sys.meta_path.insert(0, finder)
    iter_modules = pkgutil.iter_modules

    def visible_modules(path=None, prefix=""):          # plugin discovery (snakemake's registries) lists these
        for info in iter_modules(path, prefix):
            dists = finder.provides.get(info.name)
            if path is not None or not dists or dists & allowed:
                yield info

    pkgutil.iter_modules = visible_modules
    if argv[0] == "-c":
        sys.argv = ["-c", *argv[2:]]
        exec(compile(argv[1], "<string>", "exec"), {"__name__": "__main__"})
    else:
        sys.argv = [argv[1], *argv[2:]]
        runpy.run_module(argv[1], run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main(sys.argv[1:])
