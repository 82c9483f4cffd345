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
    assert run["directions_dropped"] == [] and len(run["directions_used"]) == 7      # p2m7: the sagittal ones
    est = pd.read_csv(out / "estimate.csv", comment="#")
    assert len(est) == 7 and (est["f_c"] > 0).all()
    assert "iteration 1/2" in cap.err and "iteration 1/2" not in cap.out
    assert (out / "import" / "quality_report.md").exists() and not (out / "fig_fit_radar.png").exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seed"] == 7
    assert not (out / ".checkpoint.npz").exists()        # a finished run leaves no checkpoint (only resumes need it)


def test_directions_without_value_are_dropped_and_listed(tmp_path, config):
    from neckstrength.estimate import _prepare_inputs
    from neckstrength.trials import default_outputs, import_trials, write_import

    res = import_trials(ROOT / "data" / "example_lab" / "trials.csv", _directions(config))
    outputs = default_outputs(tmp_path / "import")
    write_import(res, outputs)
    missing = res.exclusions[(res.exclusions["what"] == "direction") & (res.exclusions["participant"] == "P01")]
    assert len(missing) == 1
    notes = []
    from neckstrength.config import estimate_settings, full_model_from_config, model_from_config

    model = model_from_config(full_model_from_config(config), config, "s3m24")
    prep = _prepare_inputs(estimate_settings(config, "s3m24").bootstrap_direction, model, _directions(config), "P01",
                           outputs["max_force"], None, tmp_path, notes.append)
    assert prep["dropped"] == list(missing["direction"]) and len(prep["used"]) == 24
    assert prep["dropped"][0] in notes[0]
    d = pd.read_csv(prep["directions"], comment="#")
    assert prep["dropped"][0] not in set(d["name"]) and len(d) == 24


def _directions(config):
    from neckstrength.config import build_directions

    return build_directions(config)
