"""Shared fixtures of the trial-import tests: the default config, its direction table, the shipped example."""

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "data" / "example_lab" / "trials.csv"

HEADER = "participant,direction,block,trial,frame,Mx,My,Mz,Fx,Fy,Fz"


@pytest.fixture(scope="session")
def config():
    from neckstrength.config import load_config

    return load_config(ROOT / "config" / "config.yaml")


@pytest.fixture(scope="session")
def directions(config):
    from neckstrength.config import build_directions

    return build_directions(config)


@pytest.fixture(scope="session")
def example_import(directions):
    from neckstrength.trials import import_trials

    return import_trials(EXAMPLE, directions)
