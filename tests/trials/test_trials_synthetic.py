"""The shipped example lab is SYNTHETIC, labelled with its generator and seed, and regenerates from them."""

from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.trials.synthetic import generate_example

ROOT = Path(__file__).resolve().parents[2]


def test_shipped_example_regenerates(config):
    path = ROOT / "data" / "example_lab" / "trials.csv"
    head = path.read_text().splitlines()[:2]
    assert "SYNTHETIC" in head[0] and "seed 20261123" in head[0] and "generate_example" in head[0]
    shipped = pd.read_csv(path, comment="#")
    trials, truth = generate_example(config, seed=20261123)
    assert list(shipped.columns) == list(trials.columns) and len(shipped) == len(trials)
    assert (shipped["direction"] == trials["direction"]).all() and (shipped["trial"] == trials["trial"]).all()
    for c in ("Mx", "My", "Mz", "Fx", "Fy", "Fz"):
        assert np.allclose(shipped[c], trials[c], atol=0.011)
    other, _ = generate_example(config, seed=1)
    assert len(other) != len(trials) or not np.allclose(other["Fx"], trials["Fx"], atol=0.011)
    t = pd.read_csv(ROOT / "data" / "example_lab" / "true_strengths.csv", comment="#")
    assert np.allclose(t["strength_N"], truth["strength_N"], rtol=1e-3)
