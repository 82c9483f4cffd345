"""Truncated raw inputs are errors: a row with fewer (or more) fields than the header, and a file that ends inside
a row, name the file, row and field counts instead of importing blank values."""

from pathlib import Path

import pytest

from neckstrength.io import DataValidationError, read_measurements
from neckstrength.trials import import_trials

EXAMPLE = Path(__file__).resolve().parents[2] / "data" / "example_lab" / "trials.csv"


def _lines():
    return EXAMPLE.read_text().splitlines()


def _header_index(lines):
    return next(i for i, line in enumerate(lines) if not line.startswith("#"))


def test_row_cut_to_11_fields_is_an_error(tmp_path, directions):
    lines = _lines()
    h = _header_index(lines)
    n_fields = len(lines[h].split(","))
    k = h + 3                                       # the third trial row
    lines[k] = ",".join(lines[k].split(",")[:11])
    p = tmp_path / "trials.csv"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataValidationError) as exc:
        import_trials(p, directions)
    assert str(exc.value) == (f"{p}, row 3 (line {k + 1}): 11 fields, the header has {n_fields} (fewer than the "
                              "header)")


def test_file_ending_inside_a_row_is_truncation(tmp_path, directions):
    lines = _lines()
    cut = lines[:-1] + [",".join(lines[-1].split(",")[:9])]        # cut after a wrench column, no newline
    p = tmp_path / "trials.csv"
    p.write_text("\n".join(cut))
    msg = (r"row \d+ \(line 231\): 9 fields, the header has \d+ \(fewer than the header; the file ends in this row "
           r"without a newline: truncated\?\)")
    with pytest.raises(DataValidationError, match=msg):
        import_trials(p, directions)


def test_complete_last_line_without_newline_is_fine(tmp_path, directions):
    p = tmp_path / "trials.csv"
    p.write_text(EXAMPLE.read_text().rstrip("\n"))
    assert import_trials(p, directions).summary["trials"] == import_trials(EXAMPLE, directions).summary["trials"]


def test_measurement_row_with_an_extra_field(tmp_path):
    p = tmp_path / "A2.csv"
    p.write_text("direction,S003,S005\nforehead,102.7,99.1\nback,120.0,110.0,5\n")
    with pytest.raises(DataValidationError, match=r"row 2 \(line 3\): 4 fields, the header has 3 \(more than"):
        read_measurements(p)
