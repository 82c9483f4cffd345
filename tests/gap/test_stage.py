"""The diagnosis stage (issue 33 item 3): ``neckstrength diagnose`` and the pipeline rule ``gap_diagnose`` build
the same settings and inputs (config.diagnose_stage) and call the same run_diagnose / write_diagnose."""

from pathlib import Path

import numpy as np
import pytest

import neckstrength.gap.stage as stage
import neckstrength.pipeline.gap as pgap
from neckstrength.cli import main
from neckstrength.config import build_directions, load_config

ROOT = Path(__file__).resolve().parents[2]
CONFIG = str(ROOT / "config" / "config.ci.yaml")


class _Stop(Exception):
    pass


def test_cli_and_pipeline_run_the_same_stage(tmp_path, monkeypatch):
    seen = {}

    def fake_run(name):
        def run(settings, inputs, resume_dir=None, progress=None):
            seen[name] = (settings, inputs, Path(resume_dir))
            raise _Stop
        return run

    monkeypatch.setattr(stage, "run_diagnose", fake_run("cli"))
    with pytest.raises(_Stop):
        main(["diagnose", "--dataset", "S003", "--model", "p2m7", "--config", CONFIG, "--out", str(tmp_path / "c")])
    assert not (tmp_path / "c").exists()   # the folder it created is removed on failure
    monkeypatch.setattr(pgap, "run_diagnose", fake_run("pipeline"))
    cfg = load_config(CONFIG)
    with pytest.raises(_Stop):
        pgap.gap_diagnose(cfg, "p2m7", "S003", build_directions(cfg), {"summary": tmp_path / "p" / "summary.json"})
    (s_cli, i_cli, r_cli), (s_pipe, i_pipe, r_pipe) = seen["cli"], seen["pipeline"]
    assert s_cli.diagnosis == s_pipe.diagnosis and s_cli.discriminate == s_pipe.discriminate
    assert s_cli.diagnosis.seed == cfg["seed"] and s_cli.diagnosis.calibration is not None
    assert i_cli.data.name == i_pipe.data.name == "S003"
    assert np.array_equal(i_cli.data.forces, i_pipe.data.forces)
    assert i_cli.settings_text == i_pipe.settings_text and i_cli.model_name == i_pipe.model_name == "p2m7"
    assert i_cli.head == i_pipe.head and i_cli.plane_bands == i_pipe.plane_bands
    assert (i_cli.a3 is None) == (i_pipe.a3 is None) and (i_cli.a3 is None or np.allclose(i_cli.a3, i_pipe.a3))
    assert i_cli.directions.equals(i_pipe.directions)
    assert (r_cli.name, r_pipe.name) == ("resume", "resume")


def test_effects_option_replaces_the_candidates(tmp_path, monkeypatch):
    seen = {}

    def run(settings, inputs, resume_dir=None, progress=None):
        seen["s"] = settings
        raise _Stop

    monkeypatch.setattr(stage, "run_diagnose", run)
    with pytest.raises(_Stop):
        main(["diagnose", "--dataset", "S003", "--model", "p2m7", "--config", CONFIG, "--out", str(tmp_path / "c"),
              "--effects", "kinematic, origin_offset"])
    assert seen["s"].diagnosis.effects == ("kinematic", "origin_offset")


def test_answer_lines():
    class R:
        seconds = 12.3
        summary = {"decision": "no effect detectable (best kinematic, p = 0.4 > 0.05)", "gap_before": 0.1234,
                   "gap_after": 0.1,
                   "protocol_advice": ["to tell `kinematic` from noise, add 3 trials per direction"]}

    assert stage.answer_lines(R()) == [
        "done in 12 s: no effect detectable (best kinematic, p = 0.4 > 0.05), held-out gap 0.123 -> 0.100",
        "  to tell `kinematic` from noise, add 3 trials per direction"]


def test_diagnose_gives_the_evidence_reading_with_its_choices(tmp_path, capsys):
    """``neckstrength diagnose`` (CI config, S003): summary.json's ``evidence`` (gap.evidence) states its choices, the
    noise it used and its trials per force (1: the noise is the prior's, no repeats), names an effect only under the
    stated rule, decides (the shipped configs), and report.md carries the line; ``enabled: false`` gives none."""
    import json

    from neckstrength.config import evidence_settings

    out = tmp_path / "d"
    rc = main(["diagnose", "--dataset", "S003", "--model", "p2m7", "--config", CONFIG, "--out", str(out)])
    assert rc in (0, None)
    s = json.loads((out / "summary.json").read_text())
    e = s["evidence"]
    assert (e["strength_sd"], e["prior_no_effect"], e["threshold"], e["fit_alpha"]) == (0.3, 0.5, 0.05, 0.001)
    assert e["trials_per_force"] == 1 and e["noise_sigma"] == pytest.approx(s["noise_sigma"])
    assert abs(sum(v for _, v in e["top3"])) <= 1 + 1e-9 and e["top3"][0][0] == e["most_probable"]
    if e["named"] != "none":
        assert e["p_no_effect"] < e["threshold"] and e["fit_p_best_effect"] >= e["fit_alpha"]
    # the shipped configs let the evidence decide: the summary's named effect is its, the calibrated test's beside it
    assert s["decided_by"] == "evidence" and s["named"] == e["named"] and "named_calibrated" in s
    printed = capsys.readouterr().out
    assert f"which {s['named']} (Bayes evidence; calibrated test: {s['named_calibrated']})" in printed
    text = (out / "report.md").read_text()
    assert "- **Bayes evidence** (the decision" in text and "- **Calibrated test**" in text
    cfg = load_config(CONFIG)
    cfg["gap"]["evidence"] = {**cfg["gap"]["evidence"], "enabled": False}
    assert evidence_settings(cfg) is None
