"""The README's reproduction headline, generated from ``results/report/scorecard_summary.csv``.

The row "How much of the thesis is reproduced?" of the README's *Headline results* table is not typed by hand: this
module writes it from one or more scorecard summaries, each named by the config it came from and the date of its
run, so the README cannot quote counts that no summary backs. ``tests/report/test_headline.py`` regenerates the
row's reduced-config part from the reduced pipeline's summary and its full-config part from :data:`FULL_SUMMARY`, and
fails when the README disagrees.

Usage (from the repository root, after a run)::

    python -m neckstrength.report.headline --config config/config.ci.yaml            # print the row
    python -m neckstrength.report.headline --config config/config.ci.yaml --write    # replace it in README.md
    python -m neckstrength.report.headline --config config/config.ci.yaml --check    # exit 1 if README differs

``--summary`` (default ``results/report/scorecard_summary.csv``), ``--config`` and ``--date`` (default: the date in the
summary's provenance line, else the date the summary was written, UTC) may be repeated, one per run, in the order
the row should list them.

The full config's summary takes about an hour to produce (``bash run.sh``), so a copy of it is kept in the
repository, :data:`FULL_SUMMARY`, with a provenance line (date, commit, command), and the README row is written from
that copy; ``tests/report/test_headline.py`` fails when the README and the copy disagree. After a full run::

    python -m neckstrength.report.headline --config config/config.yaml --keep docs/scorecard_summary_full.csv \
        --command "bash run.sh"                           # copy results/report/ 's summary with its provenance
    python -m neckstrength.report.headline --summary docs/scorecard_summary_full.csv --config config/config.yaml \
        --summary <a reduced run>/results/report/scorecard_summary.csv --config config/config.ci.yaml --write
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

#: the full config's scorecard summary, kept with its provenance (the README's full-config part is written from it)
FULL_SUMMARY = "docs/scorecard_summary_full.csv"

#: the provenance line of a kept summary: '# provenance: run YYYY-MM-DD, commit <hash>, command `<cmd>`, config <file>'
PROVENANCE = re.compile(r"^# provenance: run (?P<date>\d{4}-\d{2}-\d{2}), commit (?P<commit>[0-9a-f]{7,40}), "
                        r"command `(?P<command>[^`]+)`, config (?P<config>\S+)", re.M)

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


def provenance(path: str | Path) -> dict | None:
    """The provenance of a kept summary (date, commit, command, config), or None when it has no provenance line."""
    m = PROVENANCE.search(Path(path).read_text(encoding="utf-8"))
    return m.groupdict() if m else None


def keep_summary(summary: str | Path, dest: str | Path, config: str, command: str, commit: str, date: str) -> None:
    """Copy ``summary`` to ``dest`` with a provenance line first (its own comment lines kept)."""
    text = Path(summary).read_text(encoding="utf-8")
    if PROVENANCE.search(text):
        text = PROVENANCE.sub("", text).lstrip("\n")
    line = f"# provenance: run {date}, commit {commit}, command `{command}`, config {config}\n"
    if not PROVENANCE.match(line):
        raise ValueError(f"provenance line does not parse: {line!r}")
    Path(dest).write_text(line + text, encoding="utf-8")


def _git_commit() -> str:
    import subprocess

    out = subprocess.run(["git", "rev-parse", "--short=10", "HEAD"], capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit("--keep: not in a git checkout; give --commit")
    return out.stdout.strip()


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
    p.add_argument("--config", dest="config_files", action="append", required=True,
                   help="the config file the run used, as in 'snakemake --configfile' (one per --summary)")
    p.add_argument("--date", action="append", help="date of the run, YYYY-MM-DD (one per --summary; default: "
                   "the date the summary was written, UTC)")
    p.add_argument("--readme", default="README.md")
    p.add_argument("--keep", metavar="DEST", help="copy the (one) summary to DEST with a provenance line (run date, "
                   "commit, command, config) instead of printing the row; refuses to overwrite a file that is not a "
                   "kept summary unless --force")
    p.add_argument("--command", default="bash run.sh", help="with --keep: the command that produced the summary")
    p.add_argument("--commit", help="with --keep: the commit the run used (default: git rev-parse HEAD)")
    p.add_argument("--force", action="store_true", help="with --keep: overwrite DEST whatever it holds")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--write", action="store_true", help="replace the row in the README")
    g.add_argument("--check", action="store_true", help="exit 1 when the README's row differs")
    a = p.parse_args(argv)
    summaries = a.summary or ["results/report/scorecard_summary.csv"]
    if len(a.config_files) != len(summaries) or (a.date and len(a.date) != len(summaries)):
        p.error("give one --config (and one --date, if any) per --summary")
    if a.keep:
        if len(summaries) != 1 or a.write or a.check:
            p.error("--keep copies one summary (one --summary, one --config, no --write / --check)")
        dest = Path(a.keep)
        if dest.exists() and provenance(dest) is None and not a.force:
            p.error(f"--keep: {dest} exists and is not a kept summary; give --force to overwrite it")
        date = a.date[0] if a.date else _file_date(Path(summaries[0]))
        keep_summary(summaries[0], dest, a.config_files[0], a.command, a.commit or _git_commit(), date)
        print(f"{dest}: kept {summaries[0]} ({a.config_files[0]}, run {date})")
        return 0
    runs = []
    for k, (s, c) in enumerate(zip(summaries, a.config_files)):
        prov = provenance(s)
        if prov and prov["config"] != c:
            p.error(f"{s} was produced with {prov['config']}, not {c}")
        date = a.date[k] if a.date else (prov["date"] if prov else _file_date(Path(s)))
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
