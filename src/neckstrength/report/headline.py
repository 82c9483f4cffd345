"""The README's reproduction headline, generated from ``results/report/scorecard_summary.csv``.

The row "How much of the thesis is reproduced?" of the README's *Headline results* table is not typed by hand: this
module writes it from one or more scorecard summaries, each named by the config it came from and the date of its
run, so the README cannot quote counts that no summary backs. ``tests/report/test_report.py`` regenerates the row
from the reduced pipeline's summary and fails when the README disagrees.

Usage (from the repository root, after a run)::

    python -m neckstrength.report.headline --config config/config.ci.yaml            # print the row
    python -m neckstrength.report.headline --config config/config.ci.yaml --write    # replace it in README.md
    python -m neckstrength.report.headline --config config/config.ci.yaml --check    # exit 1 if README differs

``--summary`` (default ``results/report/scorecard_summary.csv``), ``--config`` and ``--date`` (default: the date the
summary was written, UTC) may be repeated, one per run, in the order the row should list them.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import pandas as pd

from neckstrength.report.scorecard import BY_CONSTRUCTION, CALIBRATED, INDEPENDENT

QUESTION = "How much of the thesis is reproduced?"

# config file -> (name in the row, anchor of its row in docs/benchmarks.md)
CONFIGS = {"config/config.ci.yaml": ("reduced config", "scorecard-ci"),
           "config/config.yaml": ("full config", "scorecard-full")}

# one part of the answer: "<name> (`<config>`, run <date>): ..."
PART = re.compile(r"(?P<name>[^;:|]+?) \(`(?P<config>[^`]+)`, run (?P<date>\d{4}-\d{2}-\d{2})\): ")


@dataclass(frozen=True)
class Run:
    """One scorecard summary and where it came from."""

    summary: pd.DataFrame
    config: str
    date: str


def read_summary(path: str | Path) -> pd.DataFrame:
    return pd.read_csv(path, comment="#")


def _counts(summary: pd.DataFrame, chapter: str, kind: str) -> dict[str, int]:
    r = summary[(summary["chapter"] == chapter) & (summary["kind"] == kind)]
    cols = ("items", "matches", "same_conclusion", "differs", "not_evaluated")
    return {c: int(r[c].sum()) for c in cols}


def answer_part(run: Run) -> str:
    """'reduced config (`config/config.ci.yaml`, run 2026-11-27): N independent items, ...' for one summary."""
    s = run.summary
    name = CONFIGS.get(run.config, (run.config, ""))[0]
    ind, cal, bc = (_counts(s, "all", k) for k in (INDEPENDENT, CALIBRATED, BY_CONSTRUCTION))
    app_b = _counts(s, "Appendix B", INDEPENDENT)["matches"]
    n_ne = int(s.loc[s["chapter"] == "all", "not_evaluated"].sum())
    return (f"{name} (`{run.config}`, run {run.date}): {ind['items']} independent items, {ind['matches']} match, "
            f"{ind['same_conclusion']} same conclusion, {ind['differs']} differ ({app_b} of the matches are "
            f"Appendix B model parameters); {cal['items']} calibrated items ({cal['matches']} match); "
            f"{bc['items']} by construction (shown, never counted as reproduced); {n_ne} not evaluated")


def row(runs: Sequence[Run]) -> str:
    """The README table row: question, answer (one part per run), links to where each is measured."""
    links = []
    for r in runs:
        anchor = CONFIGS.get(r.config, ("", ""))[1]
        links.append(f"[{anchor}](docs/benchmarks.md#{anchor})" if anchor else "[scorecard](docs/scorecard.md)")
    where = ", ".join(dict.fromkeys(links))
    return f"| {QUESTION} | {'; '.join(answer_part(r) for r in runs)} | {where} |"


def readme_row(text: str) -> str:
    """The README's current reproduction row (exactly one)."""
    rows = [ln for ln in text.splitlines() if ln.startswith(f"| {QUESTION} |")]
    if len(rows) != 1:
        raise ValueError(f"README: expected one row '{QUESTION}', found {len(rows)}")
    return rows[0]


def row_sources(row_text: str) -> list[tuple[str, str]]:
    """(config, date) of every part of a reproduction row, in order."""
    return [(m["config"], m["date"]) for m in PART.finditer(row_text)]


def replace_row(text: str, new_row: str) -> str:
    old = readme_row(text)
    return text.replace(old, new_row, 1)


def _file_date(path: Path) -> str:
    return _dt.datetime.fromtimestamp(path.stat().st_mtime, _dt.timezone.utc).date().isoformat()


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m neckstrength.report.headline",
                                description="The README's reproduction row, from scorecard_summary.csv.")
    p.add_argument("--summary", action="append", help="scorecard_summary.csv of a run (repeatable; default "
                   "results/report/scorecard_summary.csv)")
    p.add_argument("--config", action="append", required=True,
                   help="the config file the run used, as in 'snakemake --configfile' (one per --summary)")
    p.add_argument("--date", action="append", help="date of the run, YYYY-MM-DD (one per --summary; default: "
                   "the date the summary was written, UTC)")
    p.add_argument("--readme", default="README.md")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--write", action="store_true", help="replace the row in the README")
    g.add_argument("--check", action="store_true", help="exit 1 when the README's row differs")
    a = p.parse_args(argv)
    summaries = a.summary or ["results/report/scorecard_summary.csv"]
    if len(a.config) != len(summaries) or (a.date and len(a.date) != len(summaries)):
        p.error("give one --config (and one --date, if any) per --summary")
    runs = []
    for k, (s, c) in enumerate(zip(summaries, a.config)):
        date = a.date[k] if a.date else _file_date(Path(s))
        if not re.fullmatch(r"\d{4}-\d{2}-\d{2}", date):
            p.error(f"--date {date!r}: expected YYYY-MM-DD")
        runs.append(Run(read_summary(s), c, date))
    new = row(runs)
    if not (a.write or a.check):
        print(new)
        return 0
    readme = Path(a.readme)
    text = readme.read_text(encoding="utf-8")
    if a.check:
        old = readme_row(text)
        if old != new:
            print(f"{readme}: the reproduction row differs from the summary\n  README:  {old}\n  summary: {new}",
                  file=sys.stderr)
            return 1
        print(f"{readme}: the reproduction row agrees with the summary")
        return 0
    readme.write_text(replace_row(text, new), encoding="utf-8")
    print(f"{readme}: wrote {new}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
