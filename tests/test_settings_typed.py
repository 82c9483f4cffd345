"""Settings as types (issue 33 item 2): only ``config.py`` and ``pipeline/`` read the config dict; everything else
receives frozen dataclasses that ``config.py`` builds. The schema's defaults equal the dataclasses' defaults, so a
setting left out of a config means the same thing wherever it is read."""

import ast
from dataclasses import MISSING, fields
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "src" / "neckstrength"
SCHEMA = ROOT / "workflow" / "schemas" / "config.schema.yaml"

#: names a config dict (or a section of it) goes by
CONFIG_NAMES = {"cfg", "config", "conf", "configuration"}

# Files that still index the config dict, to go (the test fails on any other, and when one of these no longer does,
# so the list only shrinks).
KNOWN = {"estimation/datasets.py",              # build_dataset: callers to pass DatasetSettings (load_dataset)
         "report/scorecard/appendix_b.py", "report/scorecard/build.py", "report/scorecard/chapter3.py",
         "report/scorecard/chapter4.py", "report/scorecard/estimates.py"}


def _config_name(node: ast.AST) -> str | None:
    if isinstance(node, ast.Name) and node.id in CONFIG_NAMES:
        return node.id
    if isinstance(node, ast.Attribute) and node.attr in CONFIG_NAMES:
        return node.attr
    return None


def config_reads(source: str, filename: str = "<source>") -> list[str]:
    """``line: text`` of every ``cfg[...]``, ``config.get(...)``, ``x.config[...]`` ... in ``source``."""
    out = []
    for node in ast.walk(ast.parse(source, filename)):
        name = None
        if isinstance(node, ast.Subscript):
            name = _config_name(node.value)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in (
                "get", "setdefault", "pop", "items", "keys", "values", "update"):
            name = _config_name(node.func.value)
        if name:
            out.append(f"{node.lineno}: {ast.get_source_segment(source, node)}")
    return out


def _offenders() -> dict[str, list[str]]:
    found = {}
    for p in sorted(PKG.rglob("*.py")):
        rel = p.relative_to(PKG).as_posix()
        if rel == "config.py" or rel.startswith("pipeline/"):
            continue
        reads = config_reads(p.read_text(), str(p))
        if reads:
            found[rel] = reads
    return found


def test_only_config_and_pipeline_read_the_config_dict():
    found = _offenders()
    new = {k: v for k, v in found.items() if k not in KNOWN}
    assert new == {}, "outside config.py and pipeline/, these read the config dict: build typed settings in config.py"
    assert KNOWN - set(found) == set(), "no longer read the config dict: remove them from KNOWN"


def test_the_detector_finds_config_reads():
    src = ("def f(cfg, ctx, config, other):\n"
           "    a = cfg['seed']\n"
           "    b = config.get('chapter5', {}).get('eps_D')\n"
           "    c = ctx.config['data']['thesis_dir']\n"
           "    d = other['seed'] + other.get('x', 1)\n"
           "    return config_path(cfg)\n")
    got = config_reads(src)
    assert sorted(g.split(":")[0] for g in got) == ["2", "3", "4"]
    assert config_reads("x = settings.seed\n") == []
