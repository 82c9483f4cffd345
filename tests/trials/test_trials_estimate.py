"""``neckstrength estimate`` from trials: no config to write, progress on stderr, seed recorded."""

import json
from pathlib import Path

import pandas as pd

from neckstrength.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_estimate_from_trials(tmp_path, capsys):
    out = tmp_path / "est"
    rc = main(["estimate", "--trials", str(ROOT / "data" / "example_lab" / "trials.csv"), "--participant", "P01",
               "--model", "p2m7", "--max-iter", "2", "--seed", "7", "--out", str(out), "--no-figures",
               "--config", str(ROOT / "config" / "config.yaml")])
    cap = capsys.readouterr()
    assert rc == 0
    run = json.loads((out / "run.json").read_text())
    assert run["seed"] == 7 and run["method"] == "alg4" and run["iterations"] == 2
    # P01 has no valid 'chinUnder' trial in the example: dropped from the fit and said so
    assert run["directions_dropped"] == ["chinUnder"] and "chinUnder" in cap.out
    est = pd.read_csv(out / "estimate.csv", comment="#")
    assert len(est) == 7 and (est["f_c"] > 0).all()
    assert "iteration 1/2" in cap.err and "iteration 1/2" not in cap.out
    assert (out / "import" / "quality_report.md").exists() and not (out / "fig_fit_radar.png").exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seed"] == 7
