"""Constants of the app's tests (a module of its own name: ``conftest`` is ambiguous between test folders)."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CFG = str(ROOT / "config" / "config.ci.yaml")
TOKEN = "test-token-0123456789"
HDR = {"X-Neckstrength-Token": TOKEN}
P2M7 = {"model": "p2m7", "participant": "P01", "n_candidates": 2000, "seed": 7}
