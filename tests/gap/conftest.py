"""Fixtures shared by the gap tests: the full config with absolute data paths, its directions, gap contexts."""

from pathlib import Path

import pytest

from neckstrength.config import build_directions, gap_context, load_config

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def cfg():
    c = load_config(ROOT / "config" / "config.yaml")
    c["data"] = {k: str(ROOT / v) for k, v in c["data"].items()}
    c["geometry"]["test_point_spec"] = str(ROOT / c["geometry"]["test_point_spec"])
    return c


@pytest.fixture(scope="module")
def directions(cfg):
    return build_directions(cfg)


@pytest.fixture(scope="module")
def ctx_s3(cfg, directions):
    return gap_context(cfg, "s3m24", directions)


@pytest.fixture(scope="module")
def ctx_p2(cfg, directions):
    return gap_context(cfg, "p2m7", directions)
