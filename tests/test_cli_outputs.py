"""No command replaces an earlier run's file or its own input without --force; --out that is a file is a clean
error; a failed run removes the folder it created."""

import shutil
from pathlib import Path

import pytest

from neckstrength.cli import main

ROOT = Path(__file__).resolve().parents[1]
CONFIG = str(ROOT / "config" / "config.yaml")
A2 = str(ROOT / "data" / "thesis" / "table_A2_max_force.csv")
EXAMPLE = ROOT / "data" / "example_lab" / "trials.csv"


@pytest.fixture(autouse=True)
def _repo_cwd(monkeypatch):
    monkeypatch.chdir(ROOT)            # the config's data paths are relative to the repository


def test_example_lab_refuses_to_replace_trials_without_force(tmp_path, capsys):
    out = tmp_path / "lab"
    out.mkdir()
    (out / "trials.csv").write_text("my own trials\n")
    assert main(["example-lab", "--out", str(out), "--config", CONFIG]) == 2
    err = capsys.readouterr().err
    assert f"error: {out / 'trials.csv'}: exists; give --force to replace it, or choose another --out" in err
    assert (out / "trials.csv").read_text() == "my own trials\n"
    assert not (out / "true_strengths.csv").exists()
    assert main(["example-lab", "--out", str(out), "--config", CONFIG, "--force"]) == 0
    assert "SYNTHETIC" in (out / "trials.csv").read_text()


def test_import_trials_refuses_existing_outputs_and_never_its_input(tmp_path, capsys):
    out = tmp_path / "imp"
    out.mkdir()
    (out / "max_force.csv").write_text("earlier\n")
    assert main(["import-trials", str(EXAMPLE), "--out", str(out), "--config", CONFIG]) == 2
    assert "max_force.csv: exists; give --force" in capsys.readouterr().err
    assert (out / "max_force.csv").read_text() == "earlier\n"
    # the input itself named as an output: refused even with --force
    own = tmp_path / "own"
    own.mkdir()
    shutil.copy(EXAMPLE, own / "max_force.csv")
    before = (own / "max_force.csv").read_bytes()
    assert main(["import-trials", str(own / "max_force.csv"), "--out", str(own), "--config", CONFIG,
                 "--force"]) == 2
    assert "max_force.csv: is an input of this command and is never overwritten" in capsys.readouterr().err
    assert (own / "max_force.csv").read_bytes() == before


@pytest.mark.parametrize("argv", [
    ["estimate", "--measurements", A2, "--participant", "S003", "--model", "p2m7"],
    ["import-trials", str(EXAMPLE)],
    ["c3d-to-trials", str(EXAMPLE)],
    ["example-lab"],
    ["diagnose", "--dataset", "S003", "--model", "p2m7"],
])
def test_out_naming_a_file_is_a_clean_error(tmp_path, capsys, argv):
    f = tmp_path / "a_file"
    f.write_text("keep\n")
    assert main(argv + ["--out", str(f), "--config", CONFIG]) == 2
    err = capsys.readouterr().err
    assert f"error: {f}: --out names an existing file; give a folder (new or empty)" in err
    assert f.read_text() == "keep\n"


def test_estimate_refuses_a_non_empty_folder(tmp_path, capsys):
    out = tmp_path / "est"
    out.mkdir()
    (out / "fig_estimate_traces.png").write_bytes(b"an earlier participant's figure")
    assert main(["estimate", "--measurements", A2, "--participant", "S003", "--model", "p2m7", "--out", str(out),
                 "--config", CONFIG]) == 2
    assert "--out folder is not empty (1 entries, e.g. fig_estimate_traces.png); give --force" in \
        capsys.readouterr().err


def test_failed_estimate_removes_the_folder_it_created(tmp_path, capsys):
    out = tmp_path / "new" / "est"
    assert main(["estimate", "--measurements", A2, "--participant", "S999", "--model", "p2m7", "--out", str(out),
                 "--config", CONFIG]) == 2
    assert "no column for participant 'S999'" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()
    # a folder that existed before is left as it was
    kept = tmp_path / "kept"
    kept.mkdir()
    assert main(["estimate", "--measurements", A2, "--participant", "S999", "--model", "p2m7", "--out", str(kept),
                 "--config", CONFIG]) == 2
    assert kept.is_dir()


@pytest.mark.parametrize("argv", [["max-wrench", "--model", "p2m7"], ["directions", "--out", "d.csv"],
                                  ["diagnose", "--measurements", "m.csv", "--dataset", "S003"],
                                  ["estimate", "--measurements", "m.csv", "--participant", "S003", "--out", "e"]])
def test_a_missing_config_is_a_clean_error_in_every_verb(tmp_path, monkeypatch, capsys, argv):
    # run outside the repository: the default config/config.yaml is not there
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "config file not found" in err and "Traceback" not in err


def test_max_wrench_prints_only_its_table_on_stdout():
    # HiGHS writes a start-up banner from C to file descriptor 1 on the first solve of a process; the verb's
    # stdout is its table alone (a fresh process, so the banner is not already spent)
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "neckstrength.cli", "max-wrench", "--model", "p2m7", "--direction",
                        "back"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "HiGHS" not in r.stdout
    assert r.stdout.splitlines()[0].startswith("model p2m7") and "back" in r.stdout
