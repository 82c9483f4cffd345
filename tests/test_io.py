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


# --------------------------------------------------------------------------- bounded inputs, short error texts

def test_error_echoes_only_a_short_excerpt_of_a_long_cell(tmp_path):
    big = "x" * 100_000
    p = write(tmp_path, f"direction,S003\nforehead,{big}\n")
    with pytest.raises(DataValidationError) as e:
        read_measurements(p)
    msg = str(e.value)
    assert "row 1" in msg and "'S003'" in msg and "not a number" in msg
    assert "x" * 80 + "..." in msg and "x" * 81 not in msg and len(msg) < 400
    p = write(tmp_path, f"direction,S003\n{big},100\n", "d.csv")        # an unknown direction: the same
    with pytest.raises(DataValidationError, match="unknown test direction") as e:
        read_measurements(p, directions=["forehead"])
    assert "x" * 81 not in str(e.value) and len(str(e.value)) < 400
    p = write(tmp_path, f"direction,{big}\nforehead,100\n", "c.csv")   # a long column name (not an id)
    with pytest.raises(DataValidationError, match="participant column names must look like") as e:
        read_measurements(p)
    assert "x" * 81 not in str(e.value) and len(str(e.value)) < 400


def test_too_many_participant_columns_refused_at_once(tmp_path):
    from neckstrength.io import MAX_TABLE_COLUMNS

    n = MAX_TABLE_COLUMNS + 1
    names = [f"P{i}" for i in range(n)]
    p = write(tmp_path, "direction," + ",".join(names) + "\nforehead," + ",".join(["100"] * n) + "\n")
    with pytest.raises(DataValidationError) as e:
        read_measurements(p)
    msg = str(e.value)
    assert str(p) in msg and f"{n + 1:,} columns" in msg and f"limit of {MAX_TABLE_COLUMNS:,}" in msg
    assert "P5000" not in msg and len(msg) < 400                        # the names are not listed
    with pytest.raises(DataValidationError, match=f"limit of {MAX_TABLE_COLUMNS:,}"):
        read_activations(p)


def test_file_over_the_size_limit_refused_at_once(tmp_path, monkeypatch):
    import neckstrength.io as nio

    p = write(tmp_path, "direction,S003\nforehead,100\nback,120\n")
    monkeypatch.setattr(nio, "MAX_TABLE_BYTES", 20)                    # the check, without writing 50 MB
    with pytest.raises(DataValidationError) as e:
        read_measurements(p)
    msg = str(e.value)
    assert str(p) in msg and f"{p.stat().st_size} bytes" in msg and "limit" in msg and "20 bytes" in msg


def test_size_limit_is_50_mb_and_stated_in_the_docs():
    from neckstrength.io import MAX_TABLE_BYTES, MAX_TABLE_COLUMNS

    assert MAX_TABLE_BYTES == 50_000_000 and MAX_TABLE_COLUMNS == 10_000
    doc = (ROOT / "docs" / "trials.md").read_text()
    assert "50 MB" in doc and "10,000" in doc


@pytest.mark.parametrize("reader", [read_measurements, read_activations])
def test_header_only_table_is_an_error(tmp_path, reader):
    p = write(tmp_path, "# provenance: none\ndirection,S003,S004\n")
    with pytest.raises(DataValidationError, match=r"no data rows \(the table has a header but no rows\)") as e:
        reader(p)
    assert str(p) in str(e.value)


@pytest.mark.parametrize("text", ["direction;S003;S004\nforehead;102,7;28,7\nback;98,1;110,7\n",
                                  "direction;S003\nforehead;102\n"])
def test_semicolon_separated_file_says_so(tmp_path, text):
    p = write(tmp_path, text)
    with pytest.raises(DataValidationError) as e:
        read_measurements(p)
    msg = str(e.value)
    assert str(p) in msg and "line 1" in msg and "missing column" not in msg
    assert ("looks semicolon-separated (decimal commas?): save as comma-separated with '.' as the decimal mark"
            in msg)


def test_duplicated_participant_column_named_with_both_positions(tmp_path):
    p = write(tmp_path, "direction,P01,P02,P01\nforehead,100,110,120\n")
    with pytest.raises(DataValidationError) as e:
        read_measurements(p)
    msg = str(e.value)
    assert "P01.1" not in msg and "field 'P01'" in msg and "line 1" in msg
    assert "duplicate column 'P01' (columns 2 and 4)" in msg


def test_written_files_get_the_usual_mode_not_mkstemps_0600(tmp_path):
    """CSV and text outputs are readable as open() would make them (0666 less the umask; issue 33: they were
    0600, the temporary file's mode)."""
    import os
    import stat

    import pandas as pd

    from neckstrength.io import atomic_write_csv, atomic_write_text

    old = os.umask(0o022)
    os.umask(old)                                             # the process's umask, as at import
    atomic_write_csv(pd.DataFrame({"a": [1]}), tmp_path / "x.csv")
    atomic_write_text("hi", tmp_path / "x.txt")
    for name in ("x.csv", "x.txt"):
        mode = stat.S_IMODE((tmp_path / name).stat().st_mode)
        assert mode == (0o666 & ~old), (name, oct(mode))      # e.g. 0644 under the common umask 022
