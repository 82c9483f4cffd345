"""Every bad-input class of the trial import and of ``validate`` is an error naming file, row and field."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from neckstrength.cli import main
from neckstrength.io import DataValidationError
from neckstrength.trials import import_to_folder, import_trials, read_trials

ROOT = Path(__file__).resolve().parents[2]
CONFIG = str(ROOT / "config" / "config.yaml")
HEADER = "participant,direction,block,trial,frame,Mx,My,Mz,Fx,Fy,Fz"
GOOD = ["P01,forehead,main,1,skull,0,0,-4.8,91.7,39.5,0", "P01,forehead,main,2,skull,0,0,-5.0,95.0,40.0,0"]


def write(tmp_path, lines, name="t.csv", header=HEADER):
    p = tmp_path / name
    p.write_text("\n".join([header] + lines) + "\n", encoding="utf-8")
    return p


def names(directions):
    return list(directions["name"])


def test_good_table_reads(tmp_path, directions):
    df = read_trials(write(tmp_path, GOOD), names(directions))
    assert len(df) == 2 and list(df["row"]) == [1, 2] and list(df["line"]) == [2, 3]


def test_unknown_direction_names_row_and_field(tmp_path, directions):
    p = write(tmp_path, GOOD + ["P01,templeAboveX,main,1,skull,0,0,-4.8,91.7,39.5,0"])
    with pytest.raises(DataValidationError) as e:
        read_trials(p, names(directions))
    assert e.value.row == 3 and e.value.field == "direction" and str(p) in str(e.value)
    assert "templeAboveX" in str(e.value)


def test_validate_measurements_rejects_unknown_direction(tmp_path, capsys):
    p = tmp_path / "m.csv"
    p.write_text("direction,S003\nforehead,100\ntempleAboveX,120\n")
    assert main(["validate", "measurements", str(p), "--config", CONFIG]) == 2
    err = capsys.readouterr().err
    assert "row 2" in err and "'direction'" in err and "templeAboveX" in err and str(p) in err


BINARY = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256))


def test_binary_file_is_an_error_not_a_traceback(tmp_path):
    p = tmp_path / "data.csv"
    p.write_bytes(BINARY)
    r = subprocess.run([sys.executable, "-m", "neckstrength.cli", "validate", "measurements", str(p), "--config",
                        CONFIG], capture_output=True, text=True, env={**os.environ}, cwd=ROOT)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and "binary file" in r.stderr and str(p) in r.stderr


@pytest.mark.parametrize("kind", ["activations", "trials", "points"])
def test_binary_file_rejected_by_every_reader(tmp_path, capsys, kind):
    p = tmp_path / "data.csv"
    p.write_bytes(BINARY)
    assert main(["validate", kind, str(p), "--config", CONFIG]) == 2
    err = capsys.readouterr().err
    assert "binary file" in err and str(p) in err


def test_non_utf8_file_names_line(tmp_path, directions):
    p = tmp_path / "latin1.csv"
    p.write_bytes((HEADER + "\n" + GOOD[0] + "\nP01,forehead,main,2,skull,0,0,-5,95,40,0 # caf\xe9\n")
                  .encode("latin-1"))
    with pytest.raises(DataValidationError, match=r"line 3.*not UTF-8"):
        read_trials(p, names(directions))


def test_duplicated_trial(tmp_path, directions):
    p = write(tmp_path, GOOD + [GOOD[1]])
    with pytest.raises(DataValidationError) as e:
        read_trials(p, names(directions))
    assert e.value.row == 3 and e.value.field == "trial" and "already at row 2" in str(e.value)


def test_missing_frame_cell_and_column(tmp_path, directions):
    p = write(tmp_path, [GOOD[0], "P01,forehead,main,2,,0,0,-5,95,40,0"])
    with pytest.raises(DataValidationError) as e:
        read_trials(p, names(directions))
    assert e.value.row == 2 and e.value.field == "frame" and "missing value" in str(e.value)
    p = write(tmp_path, ["P01,forehead,main,1,0,0,-5,95,40,0"], header=HEADER.replace("frame,", ""))
    with pytest.raises(DataValidationError, match="missing column") as e:
        read_trials(p, names(directions))
    assert e.value.field == "frame"


def test_unknown_frame(tmp_path, directions):
    p = write(tmp_path, ["P01,forehead,main,1,loadcell,0,0,-5,95,40,0"])
    with pytest.raises(DataValidationError, match="not one of skull, pad") as e:
        read_trials(p, names(directions))
    assert e.value.field == "frame"


@pytest.mark.parametrize("field,line", [("Fx", "P01,forehead,main,1,skull,0,0,-5,95000,40,0"),
                                        ("Mz", "P01,forehead,main,1,skull,0,0,-4800,95,40,0")])
def test_wrench_component_out_of_range(tmp_path, directions, field, line):
    with pytest.raises(DataValidationError, match="out of range") as e:
        read_trials(write(tmp_path, [line]), names(directions))
    assert e.value.row == 1 and e.value.field == field


def test_wrong_declared_unit(tmp_path, directions):
    p = tmp_path / "t.csv"
    p.write_text("# units: Fx=kN\n" + HEADER + "\n" + GOOD[0] + "\n")
    with pytest.raises(DataValidationError, match="declared unit 'kN'") as e:
        read_trials(p, names(directions))
    assert e.value.field == "Fx"


def test_emg_above_one_after_normalisation(tmp_path, directions):
    h = HEADER + ",emg_SCM_R,emgmax_SCM_R"
    p = write(tmp_path, [GOOD[0] + ",0.20,0.25", GOOD[1] + ",0.40,0.30"], header=h)
    with pytest.raises(DataValidationError, match=r"outside \[0, 1\]") as e:
        import_trials(p, directions)
    assert e.value.row == 2 and e.value.field == "emg_SCM_R" and str(p) in str(e.value)


def test_negative_emg_rejected(tmp_path, directions):
    p = write(tmp_path, [GOOD[0] + ",-0.2"], header=HEADER + ",emg_SCM_R")
    with pytest.raises(DataValidationError, match="out of range") as e:
        read_trials(p, names(directions))
    assert e.value.field == "emg_SCM_R"


def test_cardinal_direction_needs_start_or_end(tmp_path, directions):
    p = write(tmp_path, ["P01,extension,main,1,skull,0,0,30,0,0,0"])
    with pytest.raises(DataValidationError, match="start' or 'end'") as e:
        read_trials(p, names(directions))
    assert e.value.field == "block"


def test_bad_input_leaves_existing_outputs_untouched(tmp_path, directions):
    good = write(tmp_path, GOOD, "good.csv")
    _, outputs = import_to_folder(good, directions, tmp_path / "out")
    before = {k: Path(v).read_bytes() for k, v in outputs.items()}
    bad = write(tmp_path, GOOD + [GOOD[1]], "bad.csv")
    with pytest.raises(DataValidationError):
        import_to_folder(bad, directions, tmp_path / "out")
    assert {k: Path(v).read_bytes() for k, v in outputs.items()} == before
    assert not [f for f in os.listdir(tmp_path / "out") if f.endswith(".tmp")]
    mf = before["max_force"].decode()
    assert "forehead," in mf and np.isclose(float(mf.split("forehead,")[1].split("\n")[0]),
                                            float(np.dot([0, 0, -5.0, 95.0, 40.0, 0],
                                                         directions.loc[0, [f"u_{c}" for c in
                                                                            ("Mx", "My", "Mz", "Fx", "Fy", "Fz")]]
                                                         .to_numpy(float)) / directions.loc[0, "force_scale"]),
                                            atol=0.01)


def test_participant_id_must_fit_the_max_force_table(tmp_path, directions):
    p = write(tmp_path, ["lab 3,forehead,main,1,skull,0,0,-4.8,91.7,39.5,0"])
    with pytest.raises(DataValidationError, match="must look like S003 or P01") as e:
        read_trials(p, names(directions))
    assert e.value.row == 1 and e.value.field == "participant"


def test_validate_header_only_measurements_is_an_error_not_ok(tmp_path, capsys):
    p = tmp_path / "m.csv"
    p.write_text("direction,S003,S004\n")
    assert main(["validate", "measurements", str(p), "--config", CONFIG]) == 2
    cap = capsys.readouterr()
    assert "OK" not in cap.out and str(p) in cap.err and "no data rows" in cap.err


def test_long_cell_in_a_trial_row_is_echoed_as_a_short_excerpt(tmp_path, directions):
    big = "templeAbove" + "X" * 100_000
    p = write(tmp_path, GOOD + [f"P01,{big},main,1,skull,0,0,-4.8,91.7,39.5,0"])
    with pytest.raises(DataValidationError) as e:
        read_trials(p, names(directions))
    msg = str(e.value)
    assert e.value.row == 3 and e.value.field == "direction" and "unknown test direction" in msg
    assert "X" * 69 + "..." in msg and "X" * 70 not in msg and len(msg) < 1000


def test_semicolon_trial_table_says_so(tmp_path, directions):
    p = write(tmp_path, ["P01;forehead;main;1;skull;0;0;-4,8;91,7;39,5;0"], header=HEADER.replace(",", ";"))
    with pytest.raises(DataValidationError, match="looks semicolon-separated \\(decimal commas\\?\\)") as e:
        read_trials(p, names(directions))
    assert e.value.line == 1 and str(p) in str(e.value)
