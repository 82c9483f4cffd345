"""Config typos and out-of-domain values are errors at start-up, not settings that silently have no effect."""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from neckstrength.cli import main
from neckstrength.config import load_config

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]


def base() -> dict:
    return yaml.safe_load((ROOT / "config" / "config.yaml").read_text())


def write(tmp_path, cfg, name="config.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(cfg))
    return p


def set_key(cfg, dotted, value):
    node = cfg
    *parents, leaf = dotted.split(".")
    for k in parents:
        node = node.setdefault(k, {})
    node[leaf] = value
    return cfg


@pytest.mark.parametrize("path", ["config/config.yaml", "config/config.ci.yaml"])
def test_shipped_configs_load(path):
    cfg = load_config(ROOT / path)
    assert cfg["seed"] >= 0 and cfg["chapter5"]["epsilon"] > 0


@pytest.mark.parametrize("dotted, suggestion", [
    ("chapter5.epsilonn", "chapter5.epsilonn`: unknown setting; did you mean `epsilon`?"),
    ("gap.bootstrapp", "gap.bootstrapp`: unknown setting; did you mean `bootstrap`?"),
    ("chapter6.n_candidate", "chapter6.n_candidate`: unknown setting; did you mean `n_candidates`?"),
    ("modle.x", "modle`: unknown setting; did you mean `model`?"),
    # a map (chapter5.settings: model -> settings): its keys are free, its values are checked
    ("chapter5.settings.p2m7.sigma_0", "chapter5.settings.p2m7.sigma_0`: unknown setting; did you mean `sigma0`?"),
    ("clinician.session.s3m24.criterio", "clinician.session.s3m24.criterio`: unknown setting; did you mean "
                                         "`criterion`?"),
])
def test_unknown_setting_is_an_error_with_the_closest_key(tmp_path, dotted, suggestion):
    p = write(tmp_path, set_key(base(), dotted, 3.0))
    with pytest.raises(ValueError) as exc:
        load_config(p)
    assert f"config.yaml: `{suggestion}" in str(exc.value)


def test_map_keys_are_free(tmp_path):
    cfg = set_key(base(), "chapter5.settings.mymodel", {"sigma0": 0.25})
    assert load_config(write(tmp_path, cfg))["chapter5"]["settings"]["mymodel"] == {"sigma0": 0.25}


def test_no_close_key_lists_the_known_ones(tmp_path):
    p = write(tmp_path, set_key(base(), "chapter4.zzzz", 1))
    with pytest.raises(ValueError, match=r"`chapter4.zzzz`: unknown setting; known: reference_variant, "):
        load_config(p)


def test_negative_seed_is_an_error(tmp_path):
    p = write(tmp_path, set_key(base(), "seed", -1))
    with pytest.raises(ValueError, match=r"config.yaml: `seed`: -1 is less than the minimum of 0"):
        load_config(p)


def test_cli_reports_a_typo_without_traceback(tmp_path, capsys):
    p = write(tmp_path, set_key(base(), "chapter5.epsilonn", 3.0))
    assert main(["directions", "--config", str(p), "--out", str(tmp_path / "d.csv")]) == 2
    err = capsys.readouterr().err
    assert "`chapter5.epsilonn`: unknown setting; did you mean `epsilon`?" in err and "Traceback" not in err
    assert not (tmp_path / "d.csv").exists()


def test_unknown_dataset_names_the_known_ones(monkeypatch):
    from neckstrength.config import check_config_datasets

    monkeypatch.chdir(ROOT)
    cfg = load_config(ROOT / "config" / "config.yaml")
    check_config_datasets(cfg)                      # the shipped names exist
    cfg["gap"]["datasets"] = ["S003", "S999"]
    cfg["chapter6"]["model_datasets"] = {"s3m24": ["weak", "S998"]}
    with pytest.raises(ValueError) as exc:
        check_config_datasets(cfg, "config.yaml")
    msg = str(exc.value)
    assert ("config.yaml: `gap.datasets`: data set 'S999' is not in the data (known: norm, weak, S003, S004, S005, "
            "S006, S007)") in msg
    assert "`chapter6.model_datasets.s3m24`: data set 'S998' is not in the data (known: norm, weak, Sim, S003" in msg


@pytest.mark.parametrize("dotted, value, expected", [
    ("chapter5.epsilonn", 3.0, "`chapter5.epsilonn`: unknown setting; did you mean `epsilon`?"),
    ("seed", -1, "`seed`: -1 is less than the minimum of 0"),
    ("gap.datasets", ["S003", "S999"], "`gap.datasets`: data set 'S999' is not in the data (known: norm, weak, S003"),
])
def test_workflow_refuses_at_start_up(repo_copy, dotted, value, expected):
    cfg = yaml.safe_load((repo_copy / "config" / "config.ci.yaml").read_text())
    path = repo_copy / "config" / "strict_test.yaml"
    path.write_text(yaml.safe_dump(set_key(cfg, dotted, value)))
    r = subprocess.run(SNAKEMAKE + ["results/appendix_a/table_A4.csv", "-n", "-c1", "--configfile",
                                    "config/strict_test.yaml"], cwd=repo_copy, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode != 0
    assert expected in r.stdout + r.stderr
