"""Data loading and validation.

Every table the package reads goes through :func:`read_table`, which checks the
columns, the declared units, the types and the ranges of each field, and raises
:class:`DataValidationError` naming the file, the row (and its line in the file)
and the field.  Nothing is written by these functions, so a bad input stops a
run before any output exists.

CSV conventions used throughout ``data/``:

- lines starting with ``#`` are comments (provenance);
- an optional comment line ``# units: col=unit; col=unit`` declares units; when
  present, each declared unit must equal the unit the schema expects (so a file
  in millimetres or kN is rejected instead of silently misread);
- one header row, then data; an empty field is a missing value.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import pandas as pd

from neckstrength.errors import EXCERPT_CHARS, DataValidationError, excerpt  # noqa: F401  (re-exported)


#: Largest table file the readers accept (bytes; 50 MB). A bigger measurement, activation or trial table is not a
#: lab's table (25 directions x a few hundred participants, a few thousand trials are a few MB); it is refused
#: before it is read. EMG signal files (one row per sample) have their own limit, :data:`MAX_SIGNALS_BYTES`.
MAX_TABLE_BYTES = 50_000_000

#: Largest EMG signals file (bytes; 2 GB): a long-format file with one row per sample.
MAX_SIGNALS_BYTES = 2_000_000_000

#: Most columns a table may have (10,000): a table with more participant columns is refused at its header,
#: before its rows are read, and the column names are not listed.
MAX_TABLE_COLUMNS = 10_000

@dataclass(frozen=True)
class Column:
    """Expected column: name, kind ('float', 'int', 'str', 'bool'), unit, range."""

    name: str
    kind: str = "float"
    unit: str | None = None
    min: float | None = None
    max: float | None = None
    required: bool = True          # column must be present
    allow_missing: bool = False    # individual cells may be empty
    choices: tuple[str, ...] | None = None
    min_exclusive: bool = False


@dataclass(frozen=True)
class Schema:
    name: str
    columns: tuple[Column, ...]
    unique: tuple[str, ...] = ()
    allow_extra_columns: bool = True
    # regex for extra columns that must obey a column template (e.g. participants)
    pattern_columns: tuple[tuple[str, Column], ...] = field(default_factory=tuple)

    def column(self, name: str) -> Column | None:
        for c in self.columns:
            if c.name == name:
                return c
        for pat, tmpl in self.pattern_columns:
            if re.fullmatch(pat, name):
                return Column(name, tmpl.kind, tmpl.unit, tmpl.min, tmpl.max, False,
                              tmpl.allow_missing, tmpl.choices, tmpl.min_exclusive)
        return None


_UNIT_ALIASES = {"n": "N", "newton": "N", "newtons": "N", "m": "m", "metre": "m", "meter": "m",
                 "metres": "m", "meters": "m", "1": "1", "-": "1", "fraction": "1",
                 "unitless": "1", "dimensionless": "1", "nm": "N*m", "n*m": "N*m", "n m": "N*m"}


def _norm_unit(u: str) -> str:
    u = u.strip()
    return _UNIT_ALIASES.get(u.lower(), u)


def _read_comments(path: Path) -> tuple[list[str], int]:
    comments: list[str] = []
    n = 0
    with open(path, encoding="utf-8-sig") as fh:
        for line in fh:
            if line.startswith("#"):
                comments.append(line.rstrip("\n"))
                n += 1
            else:
                break
    return comments, n


def declared_units(comments: Iterable[str]) -> dict[str, str]:
    """Parse ``# units: a=N; b=m`` comment lines into a dict."""
    units: dict[str, str] = {}
    for c in comments:
        m = re.match(r"#\s*units\s*:\s*(.*)$", c, flags=re.IGNORECASE)
        if not m:
            continue
        for part in re.split(r"[;,]", m.group(1)):
            if "=" in part:
                k, v = part.split("=", 1)
                units[k.strip()] = v.strip()
    return units


def _header_fields(path: Path, n_comment: int) -> tuple[str, list[str], int]:
    """The header line after the comments (its text, its fields, its line number); blank lines are skipped.
    Reads only up to the header."""
    line_no = n_comment
    with open(path, encoding="utf-8-sig", newline="") as fh:
        for _ in range(n_comment):
            fh.readline()
        for text in fh:
            line_no += 1
            text = text.rstrip("\r\n")
            if text.strip():
                try:
                    fields = next(csv.reader([text]))
                except csv.Error:
                    fields = text.split(",")
                return text, fields, line_no
    return "", [], line_no


def check_header(path: str | Path, n_comment: int = 0) -> None:
    """Raise :class:`DataValidationError` for a header that cannot be a comma-separated table of a sane size:
    more than :data:`MAX_TABLE_COLUMNS` columns (refused before any row is read), a semicolon-separated file
    (a spreadsheet export with decimal commas), or a column name given twice (named with both positions)."""
    path = Path(path)
    text, fields, line = _header_fields(path, n_comment)
    if len(fields) > MAX_TABLE_COLUMNS:
        raise DataValidationError(path, f"{len(fields):,} columns, more than the limit of {MAX_TABLE_COLUMNS:,} "
                                  "(neckstrength.io.MAX_TABLE_COLUMNS); is this the right file?", line=line)
    if ";" in text and ("," not in text or len(fields) == 1):
        raise DataValidationError(path, "looks semicolon-separated (decimal commas?): save as comma-separated "
                                  "with '.' as the decimal mark", line=line)
    seen: dict[str, int] = {}
    for k, name in enumerate(fields, start=1):
        name = name.strip()
        if name in seen:
            raise DataValidationError(path, f"duplicate column '{excerpt(name)}' (columns {seen[name]} and {k})",
                                      line=line, field_name=name)
        seen[name] = k


def check_size(path: str | Path, max_bytes: int | None = None) -> None:
    """Raise :class:`DataValidationError` for a file larger than ``max_bytes`` (default
    :data:`MAX_TABLE_BYTES`), before it is read."""
    path = Path(path)
    limit = MAX_TABLE_BYTES if max_bytes is None else max_bytes
    size = path.stat().st_size
    if size > limit:
        raise DataValidationError(path, f"{size} bytes ({size / 1e6:.1f} MB), larger than the limit of {limit} "
                                  f"bytes ({limit / 1e6:g} MB) for this kind of table; is this the right file?")


def check_field_counts(path: str | Path, n_comment: int = 0) -> None:
    """Raise :class:`DataValidationError` for a row with more or fewer fields than the header (a truncated or
    shifted row would otherwise import with blank or misplaced values), naming row, line and both counts. A last
    line that is short and has no newline is reported as a truncated file."""
    path = Path(path)
    text = path.read_text(encoding="utf-8-sig")
    body = text.split("\n", n_comment)[-1] if n_comment else text
    reader = csv.reader(io.StringIO(body, newline=""))
    header = None
    row = 0
    while True:
        try:
            rec = next(reader)
        except StopIteration:
            break
        except csv.Error as exc:                      # e.g. a cell longer than the csv module's field limit
            raise DataValidationError(path, f"cannot parse CSV ({excerpt(exc, 200)})",
                                      line=n_comment + reader.line_num) from None
        line = n_comment + reader.line_num
        if header is None:
            header = rec
            continue
        if not rec or (len(rec) == 1 and not rec[0].strip()):
            continue                                  # blank line (skipped by the reader)
        row += 1
        if len(rec) != len(header):
            at_end = not body.endswith(("\n", "\r")) and reader.line_num == body.count("\n") + 1
            what = "fewer" if len(rec) < len(header) else "more"
            problem = (f"{len(rec)} fields, the header has {len(header)} ({what} than the header"
                       + ("; the file ends in this row without a newline: truncated?)" if at_end
                          and len(rec) < len(header) else ")"))
            raise DataValidationError(path, problem, row, line)


def check_text_file(path: str | Path) -> None:
    """Raise :class:`DataValidationError` unless ``path`` is UTF-8 text (no NUL byte), naming the line."""
    path = Path(path)
    if path.is_dir():
        raise DataValidationError(path, "is a folder, not a CSV file")
    data = path.read_bytes()
    nul = data.find(b"\x00")
    if nul >= 0:
        raise DataValidationError(path, f"binary file (NUL byte at offset {nul}); expected a UTF-8 CSV text file",
                                  line=data.count(b"\n", 0, nul) + 1)
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DataValidationError(path, f"not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); "
                                  "save the file as UTF-8 CSV", line=data.count(b"\n", 0, exc.start) + 1) from None


def read_table(path: str | Path, schema: Schema, max_bytes: int | None = None) -> pd.DataFrame:
    """Read a CSV and validate it against ``schema``.

    Returns a DataFrame with typed columns. Raises :class:`DataValidationError`
    for a missing file, a file larger than ``max_bytes`` (default :data:`MAX_TABLE_BYTES`), more than
    :data:`MAX_TABLE_COLUMNS` columns, a semicolon-separated file, a duplicated or missing column, a wrong
    declared unit, a non-numeric or out-of-range value, a missing required value or a duplicate key. Messages
    echo at most :data:`EXCERPT_CHARS` characters of a cell.
    """
    path = Path(path)
    if not path.exists():
        raise DataValidationError(path, "file not found")
    if path.is_dir():
        raise DataValidationError(path, "is a folder, not a CSV file")
    check_size(path, max_bytes)
    check_text_file(path)
    comments, n_comment = _read_comments(path)
    check_header(path, n_comment)
    check_field_counts(path, n_comment)
    try:
        raw = pd.read_csv(path, comment=None, skiprows=n_comment, dtype=str,
                          keep_default_na=False, skip_blank_lines=True)
    except Exception as exc:  # pandas parser errors carry a line number in text
        raise DataValidationError(path, f"cannot parse CSV ({excerpt(exc, 200)})") from exc
    raw.columns = [str(c).strip() for c in raw.columns]
    header_line = n_comment + 1

    for col in schema.columns:
        if col.required and col.name not in raw.columns:
            raise DataValidationError(path, f"missing column (expected columns: "
                                      f"{', '.join(c.name for c in schema.columns if c.required)}; "
                                      f"found: {_column_list(raw.columns)})",
                                      line=header_line, field_name=col.name)
    if len(set(raw.columns)) != len(raw.columns):
        dup = [c for c in raw.columns if list(raw.columns).count(c) > 1][0]
        raise DataValidationError(path, "duplicate column", line=header_line, field_name=dup)
    if not schema.allow_extra_columns:
        for c in raw.columns:
            if schema.column(c) is None:
                raise DataValidationError(path, "unexpected column", line=header_line, field_name=c)

    units = declared_units(comments)
    for cname, unit in units.items():
        col = schema.column(cname)
        if col is None or col.unit is None:
            continue
        if _norm_unit(unit) != _norm_unit(col.unit):
            raise DataValidationError(path, f"declared unit '{unit}' but '{col.unit}' is required "
                                      f"(convert the values to {col.unit})", field_name=cname)

    out = {}
    for cname in raw.columns:
        col = schema.column(cname)
        values = raw[cname].tolist()
        if col is None:
            out[cname] = values
            continue
        parsed = []
        for i, v in enumerate(values):
            row = i + 1
            line = header_line + 1 + i
            v = v.strip()
            if v == "":
                if not col.allow_missing:
                    raise DataValidationError(path, "missing value", row, line, cname)
                parsed.append(None)
                continue
            if col.kind in ("float", "int"):
                try:
                    x = float(v)
                except ValueError:
                    raise DataValidationError(path, f"'{excerpt(v)}' is not a number", row, line, cname) from None
                if not math.isfinite(x):
                    raise DataValidationError(path, f"'{excerpt(v)}' is not a finite number", row, line, cname)
                if col.kind == "int" and x != int(x):
                    raise DataValidationError(path, f"'{excerpt(v)}' is not an integer", row, line, cname)
                unit = f" {col.unit}" if col.unit and col.unit != "1" else ""
                if col.min is not None and (x < col.min or (col.min_exclusive and x == col.min)):
                    op = ">" if col.min_exclusive else ">="
                    raise DataValidationError(path, f"value {excerpt(v)}{unit} out of range "
                                              f"(must be {op} {col.min}{unit})",
                                              row, line, cname)
                if col.max is not None and x > col.max:
                    raise DataValidationError(path, f"value {excerpt(v)}{unit} out of range "
                                              f"(must be <= {col.max}{unit})",
                                              row, line, cname)
                parsed.append(int(x) if col.kind == "int" else x)
            elif col.kind == "bool":
                lv = v.lower()
                if lv not in ("true", "false", "1", "0"):
                    raise DataValidationError(path, f"'{excerpt(v)}' is not true/false", row, line, cname)
                parsed.append(lv in ("true", "1"))
            else:
                if col.choices is not None and v not in col.choices:
                    raise DataValidationError(path, f"'{excerpt(v)}' is not one of {', '.join(col.choices)}",
                                              row, line, cname)
                parsed.append(v)
        if col.kind == "float":
            out[cname] = np.array([np.nan if p is None else p for p in parsed], dtype=float)
        elif col.kind == "int" and all(p is not None for p in parsed):
            out[cname] = np.array(parsed, dtype=int)
        else:
            arr = np.empty(len(parsed), dtype=object)
            arr[:] = parsed
            out[cname] = pd.Series(arr, dtype=object)
    df = pd.DataFrame(out, columns=list(raw.columns))
    for key in schema.unique:
        if key in df.columns:
            seen: dict = {}
            for i, v in enumerate(df[key].tolist()):
                if v in seen:
                    raise DataValidationError(path, f"duplicate value '{excerpt(v)}' (first at row {seen[v]})",
                                              i + 1, header_line + 1 + i, key)
                seen[v] = i + 1
    df.attrs["source"] = str(path)
    df.attrs["comments"] = comments
    return df


#: Upper plausibility bound for a maximum isometric neck force, N. The largest
#: value in Table A.2 is 329 N; published maximal neck strengths of strong adults
#: stay below about 1 kN at the head, so 2000 N catches unit errors (kN vs N x1000,
#: or N*m entered as N) without rejecting any plausible measurement.
MAX_PLAUSIBLE_FORCE_N = 2000.0


#: A participant id: letter first, then up to 63 letters, digits, '_' or '-' (a wildcard and a folder name).
PARTICIPANT_ID = r"[A-Za-z][A-Za-z0-9_-]{0,63}"

MEASUREMENT_SCHEMA = Schema(
    name="max-force measurements (Table A.2 layout)",
    columns=(Column("direction", "str"),),
    unique=("direction",),
    # summary columns first; then any safe participant id (a letter, then letters, digits, '_' or '-': it becomes a
    # Snakemake wildcard and a folder name), e.g. S003, P01, subject1, lab-B_2
    pattern_columns=((r"avg|sd", Column("", "float", "N", 0.0, MAX_PLAUSIBLE_FORCE_N, allow_missing=True)),
                     (PARTICIPANT_ID, Column("", "float", "N", 0.0, MAX_PLAUSIBLE_FORCE_N,
                                             allow_missing=True, min_exclusive=True))),
)


ACTIVATION_SCHEMA = Schema(
    name="normalised activation at max force (Table A.3 layout)",
    columns=(Column("direction", "str"),),
    unique=("direction",),
    pattern_columns=((PARTICIPANT_ID, Column("", "float", "1", 0.0, 1.0, allow_missing=True)),),
)


def _column_list(names: Sequence[str], n: int = 20) -> str:
    """The first ``n`` column names (each cut to an excerpt), and how many more."""
    names = [excerpt(c) for c in names]
    more = f", ... ({len(names) - n:,} more)" if len(names) > n else ""
    return ", ".join(names[:n]) + more


def _check_rows(path: str | Path, df: pd.DataFrame) -> None:
    if len(df) == 0:
        raise DataValidationError(path, "no data rows (the table has a header but no rows)")


def _participant_columns(df: pd.DataFrame) -> list[str]:
    return [c for c in df.columns if c not in ("direction", "avg", "sd")]


def read_measurements(path: str | Path, directions: Sequence[str] | None = None) -> pd.DataFrame:
    """Read a max-force table (directions x participants, N) and validate it.

    ``directions``: the known test-direction names; an unknown name is an error
    naming its row. Returns a DataFrame indexed by direction, one column per
    participant (avg/sd columns dropped).
    """
    df = read_table(path, MEASUREMENT_SCHEMA)
    _check_rows(path, df)
    cols = _participant_columns(df)
    if not cols:
        raise DataValidationError(path, "no participant columns (expected e.g. S003, S004, ...)")
    for c in cols:
        if MEASUREMENT_SCHEMA.column(c) is None:
            raise DataValidationError(path, "participant column names must look like S003, P01, sim or "
                                      "norm/weak (a letter, then up to 63 letters, digits, '_' or '-')",
                                      field_name=c)
    if directions is not None:
        known = set(directions)
        for i, d in enumerate(df["direction"]):
            if d not in known:
                raise DataValidationError(path, f"unknown test direction '{excerpt(d)}' "
                                          f"(known: {', '.join(directions)})",
                                          i + 1, None, "direction")
    return df.set_index("direction")[cols]


def read_activations(path: str | Path, directions: Sequence[str] | None = None) -> pd.DataFrame:
    """Read a normalised-activation table (directions x participants, in [0, 1])."""
    df = read_table(path, ACTIVATION_SCHEMA)
    _check_rows(path, df)
    cols = _participant_columns(df)
    if directions is not None:
        known = set(directions)
        for i, d in enumerate(df["direction"]):
            if d not in known:
                raise DataValidationError(path, f"unknown test direction '{excerpt(d)}'", i + 1, None, "direction")
    return df.set_index("direction")[cols]


def read_directions(path: str | Path) -> pd.DataFrame:
    """A test-direction table this package wrote (``neckstrength directions``, ``config.build_directions``; ``#``
    comment lines first), as written: one row per direction."""
    return pd.read_csv(path, comment="#")


def _umask() -> int:
    m = os.umask(0o022)
    os.umask(m)
    return m


#: the mode of a file the package writes: what open() would give (0666 less the umask), not mkstemp's 0600
FILE_MODE = 0o666 & ~_umask()


def atomic_write_csv(df: pd.DataFrame, path: str | Path, header_lines: list[str] | None = None,
                     float_format: str | None = None) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            for h in header_lines or []:
                fh.write(f"# {h}\n")
            df.to_csv(fh, index=False, float_format=float_format, lineterminator="\n")
        os.chmod(tmp, FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_text(text: str, path: str | Path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        fh.write(text)
    os.chmod(tmp, FILE_MODE)
    os.replace(tmp, path)
