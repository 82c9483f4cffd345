"""Bad input gets a clear error naming file, row and field; good input loads."""

from pathlib import Path

import pytest

from neckstrength.io import DataValidationError, read_activations, read_measurements
from neckstrength.model.geometry import read_test_points

ROOT = Path(__file__).resolve().parents[1]
A2 = ROOT / "data" / "thesis" / "table_A2_max_force.csv"
A3 = ROOT / "data" / "thesis" / "table_A3_activation.csv"


def write(tmp_path, text, name="m.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_shipped_tables_load():
    m = read_measurements(A2)
    assert m.shape == (25, 5) and m.loc["back", "S003"] == 262.6
    a = read_activations(A3)
    assert a.shape == (25, 5) and a.loc["forehead", "S005"] == 0.81


def test_non_numeric_force_names_row_and_field(tmp_path):
    p = write(tmp_path, "# units: S003=N\ndirection,S003,S004\nforehead,102.7,28.7\nback,abc,110.7\n")
    with pytest.raises(DataValidationError) as e:
        read_measurements(p)
    msg = str(e.value)
    assert str(p) in msg and "row 2" in msg and "line 4" in msg and "'S003'" in msg and "not a number" in msg


def test_negative_and_zero_force_rejected(tmp_path):
    for bad in ("-3", "0"):
        p = write(tmp_path, f"direction,S003\nforehead,{bad}\n")
        with pytest.raises(DataValidationError, match=r"row 1.*'S003'.*out of range"):
            read_measurements(p)


def test_implausible_force_rejected(tmp_path):
    p = write(tmp_path, "direction,S003\nforehead,102700\n")
    with pytest.raises(DataValidationError, match="out of range"):
        read_measurements(p)


def test_wrong_declared_unit_rejected(tmp_path):
    p = write(tmp_path, "# units: S003=kN\ndirection,S003\nforehead,0.1027\n")
    with pytest.raises(DataValidationError, match=r"field 'S003'.*declared unit 'kN'"):
        read_measurements(p)


def test_missing_column_and_unknown_direction(tmp_path):
    p = write(tmp_path, "dir,S003\nforehead,1\n")
    with pytest.raises(DataValidationError, match=r"field 'direction'.*missing column"):
        read_measurements(p)
    p = write(tmp_path, "direction,S003\nforehead,1\nbackk,2\n")
    with pytest.raises(DataValidationError, match=r"row 2.*unknown test direction 'backk'"):
        read_measurements(p, directions=["forehead", "back"])


def test_duplicate_direction_rejected(tmp_path):
    p = write(tmp_path, "direction,S003\nback,1\nback,2\n")
    with pytest.raises(DataValidationError, match=r"row 2.*duplicate value 'back' \(first at row 1\)"):
        read_measurements(p)


def test_activation_outside_unit_interval(tmp_path):
    p = write(tmp_path, "direction,S003\nforehead,1.3\n")
    with pytest.raises(DataValidationError, match=r"row 1.*'S003'.*<= 1"):
        read_activations(p)


def test_missing_file_named():
    with pytest.raises(DataValidationError, match="nope.csv: file not found"):
        read_measurements("nope.csv")


def test_points_normal_must_be_unit(tmp_path):
    p = write(tmp_path, "name,px,py,pz,nx,ny,nz\nforehead,0.1,0.08,0,0.5,0,0\n")
    with pytest.raises(DataValidationError, match=r"row 1.*unit vector"):
        read_test_points(p)
