"""The shared exception types, at the bottom of the import graph
==============================================================

Every error type that more than one subpackage raises or catches lives here, so that a module can name it without
importing the module that first raised it (which closed the import cycle ``config -> gap.discriminate -> session
-> config``). This module imports nothing from the package. The old homes re-export them, so
``from neckstrength.io import DataValidationError`` and the like keep working.

- :class:`DataValidationError`   a data file failed validation (names file, row, field); raised by ``io`` and the
  readers built on it.
- :class:`ConfigError`           the config has an unknown setting or a value outside its domain (``config``).
- :class:`UndeclaredSettingError` a pipeline rule read a setting its ``params`` do not declare (``config``).
- :class:`InputError`            a rejected clinician entry (a prompt line, a CSV row); the message is shown as is
  (``session``, ``gap.discriminate``).
- :class:`SessionLockedError`    another process holds a session folder's lock (``session.log``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

#: Characters of a cell or a column name an error message echoes; a longer one is cut and ends in "...".
EXCERPT_CHARS = 80


def excerpt(value: object, n: int = EXCERPT_CHARS) -> str:
    """``value`` as text, cut to ``n`` characters plus "..." when longer (for error messages)."""
    text = str(value)
    return text if len(text) <= n else text[:n] + "..."


class DataValidationError(ValueError):
    """A data file failed validation; the message names file, row and field."""

    def __init__(self, path: str | Path, problem: str, row: int | None = None,
                 line: int | None = None, field_name: str | None = None):
        self.path = str(path)
        self.row = row
        self.line = line
        self.field = field_name
        self.problem = problem
        where = [self.path]
        if row is not None:
            where.append(f"row {row}" + (f" (line {line})" if line is not None else ""))
        elif line is not None:
            where.append(f"line {line}")
        if field_name is not None:
            where.append(f"field '{excerpt(field_name)}'")
        super().__init__(", ".join(where) + ": " + problem)


class ConfigError(DataValidationError):
    """The config has an unknown setting, a value outside its domain, or names a data set the data lack."""

    def __init__(self, source: str | Path, problems: Sequence[str]):
        self.problems = list(problems)
        super().__init__(source, self.problems[0])
        self.args = ("\n".join(f"{source}: {p}" for p in self.problems),)

    def __str__(self) -> str:
        return self.args[0]


class UndeclaredSettingError(RuntimeError):
    """A rule read a config setting that its ``params`` do not declare (so a change to it would not rerun it)."""


class InputError(ValueError):
    """A rejected clinician entry (a line at the prompt, a row of a replayed CSV); ``str(exc)`` is the message shown
    before the re-prompt."""


class SessionLockedError(ValueError):
    """Another process holds the session folder's lock (a second ``session resume`` of the same session)."""


__all__ = ["EXCERPT_CHARS", "excerpt", "DataValidationError", "ConfigError", "UndeclaredSettingError", "InputError",
           "SessionLockedError"]
