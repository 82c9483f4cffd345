"""The reduced config's scorecard counts are pinned, and the README's reproduction row is generated from a summary.

``test_reduced_scorecard_counts_are_pinned`` compares the reduced pipeline's ``scorecard_summary.csv`` (the session
fixture ``ci_pipeline`` in tests/conftest.py) with :data:`CI_COUNTS`, so any change to what is scored, how it is
classified or how it is judged shows up here. ``test_readme_row_agrees_with_the_reduced_summary`` regenerates the
README row's reduced-config part from that summary; ``test_readme_full_config_part_is_generated_from_the_kept_summary``
does the same for the full-config part from the kept copy of the full config's summary (``docs/scorecard_summary_full.csv``,
written by ``python -m neckstrength.report.headline --config config/config.yaml --keep docs/scorecard_summary_full.csv``
after ``bash run.sh``). The other tests are fast (no pipeline).

To update after an intended change: run ``snakemake -c2 --configfile config/config.ci.yaml``, copy the rows of
``results/report/scorecard_summary.csv`` into :data:`CI_COUNTS`, then write the README row from that summary with
``python -m neckstrength.report.headline --config config/config.ci.yaml --write`` (``--date`` defaults to the day the
summary was written).
"""

from pathlib import Path

import pandas as pd
import pytest

from neckstrength.report import headline as hl
from neckstrength.report.scorecard import BY_CONSTRUCTION, CALIBRATED, INDEPENDENT, KINDS, SUMMARY_COLUMNS

ROOT = Path(__file__).resolve().parents[2]
CI_CONFIG = "config/config.ci.yaml"
FULL_CONFIG = "config/config.yaml"

# Reduced config (config/config.ci.yaml, seed 20261123): (chapter, kind) -> items, matches, same conclusion,
# differs, not evaluated. Measured 2026-11-27.
CI_COUNTS = {
    ("Appendix B", INDEPENDENT): (366, 366, 0, 0, 0),
    ("Appendix B", CALIBRATED): (47, 47, 0, 0, 0),
    ("Appendix B", BY_CONSTRUCTION): (12, 12, 0, 0, 0),
    ("Chapter 3", INDEPENDENT): (0, 0, 0, 0, 0),
    ("Chapter 3", CALIBRATED): (171, 154, 0, 17, 0),
    ("Chapter 3", BY_CONSTRUCTION): (0, 0, 0, 0, 0),
    ("Chapter 4", INDEPENDENT): (12, 11, 0, 1, 3),
    ("Chapter 4", CALIBRATED): (0, 0, 0, 0, 0),
    ("Chapter 4", BY_CONSTRUCTION): (0, 0, 0, 0, 0),
    ("Chapter 5", INDEPENDENT): (48, 19, 4, 25, 0),
    ("Chapter 5", CALIBRATED): (0, 0, 0, 0, 0),
    ("Chapter 5", BY_CONSTRUCTION): (1, 1, 0, 0, 0),
    ("Chapter 6", INDEPENDENT): (30, 7, 5, 18, 0),
    ("Chapter 6", CALIBRATED): (0, 0, 0, 0, 0),
    ("Chapter 6", BY_CONSTRUCTION): (0, 0, 0, 0, 0),
    ("all", INDEPENDENT): (456, 403, 9, 44, 3),
    ("all", CALIBRATED): (218, 201, 0, 17, 0),
    ("all", BY_CONSTRUCTION): (13, 13, 0, 0, 0),
}


def _pinned_summary() -> pd.DataFrame:
    return pd.DataFrame([[c, k, *v] for (c, k), v in CI_COUNTS.items()], columns=SUMMARY_COLUMNS)


def _readme_row() -> str:
    return hl.readme_row((ROOT / "README.md").read_text(encoding="utf-8"))


def _ci_date(row: str) -> str:
    dates = [d for c, d in hl.row_sources(row) if c == CI_CONFIG]
    assert len(dates) == 1, f"the README's reproduction row must name {CI_CONFIG} once, with its run date: {row}"
    return dates[0]


# --------------------------------------------------------------------------- fast

def test_pinned_counts_are_consistent():
    """Every chapter x kind once; items = matches + same conclusion + differs; 'all' = the sum of the chapters."""
    s = _pinned_summary()
    assert set(s["kind"]) == set(KINDS)
    assert (s["items"] == s["matches"] + s["same_conclusion"] + s["differs"]).all()
    chapters = s[s["chapter"] != "all"].groupby("kind")[SUMMARY_COLUMNS[2:]].sum()
    total = s[s["chapter"] == "all"].set_index("kind")[SUMMARY_COLUMNS[2:]]
    pd.testing.assert_frame_equal(chapters.sort_index(), total.sort_index(), check_names=False)


def test_readme_row_is_generated_from_the_pinned_summary():
    """The README's reduced-config part is exactly what the generator writes from the pinned counts."""
    row = _readme_row()
    part = hl.answer_part(hl.Run(_pinned_summary(), CI_CONFIG, _ci_date(row)))
    assert part in row, f"README row differs from the reduced summary:\n  README: {row}\n  summary: {part}"
    assert "docs/benchmarks.md#scorecard-ci" in row


def test_generated_row_names_config_date_and_every_kind():
    s = _pinned_summary()
    r = hl.row([hl.Run(s, CI_CONFIG, "2026-01-02")])
    assert r.startswith(f"| {hl.QUESTION} | reduced config (`{CI_CONFIG}`, run 2026-01-02): 456 independent items, "
                        "403 match, 9 same conclusion, 44 differ (366 of the matches are Appendix B")
    assert "218 calibrated items (201 match)" in r and "13 by construction" in r and "3 not evaluated" in r
    assert hl.row_sources(r) == [(CI_CONFIG, "2026-01-02")]
    # a different count changes the row
    s2 = s.copy()
    s2.loc[(s2["chapter"] == "all") & (s2["kind"] == INDEPENDENT), "matches"] -= 1
    assert hl.row([hl.Run(s2, CI_CONFIG, "2026-01-02")]) != r


def test_cli_check_fails_when_readme_and_summary_disagree(tmp_path, capsys):
    summary = tmp_path / "scorecard_summary.csv"
    _pinned_summary().to_csv(summary, index=False)
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n| question | answer today | where |\n|---|---|---|\n| {hl.QUESTION} | old | x |\n")
    args = ["--summary", str(summary), "--config", CI_CONFIG, "--date", "2026-01-02", "--readme", str(readme)]
    assert hl.main(args + ["--check"]) == 1
    assert hl.main(args + ["--write"]) == 0
    assert hl.main(args + ["--check"]) == 0
    text = readme.read_text()
    assert text.startswith("# x\n") and "| old |" not in text and "456 independent items" in text
    with pytest.raises(SystemExit):
        hl.main(["--summary", str(summary), "--config", CI_CONFIG, "--date", "27.11.2026"])


def test_readme_full_config_part_is_generated_from_the_kept_summary():
    """The README's full-config part is exactly what the generator writes from the kept copy of the full config's
    summary (docs/scorecard_summary_full.csv, with its provenance); without a kept copy the README may not quote the
    full config at all."""
    row = _readme_row()
    full = [d for c, d in hl.row_sources(row) if c == FULL_CONFIG]
    kept = ROOT / hl.FULL_SUMMARY
    if not kept.exists():
        assert not full, f"the README quotes {FULL_CONFIG} but {hl.FULL_SUMMARY} (its kept summary) is missing"
        return
    prov = hl.provenance(kept)
    assert prov and prov["config"] == FULL_CONFIG, f"{hl.FULL_SUMMARY}: no provenance line for {FULL_CONFIG}"
    part = hl.answer_part(hl.Run(hl.read_summary(kept), FULL_CONFIG, prov["date"]))
    assert full == [prov["date"]] and part in row, (
        f"README row differs from {hl.FULL_SUMMARY}:\n  README: {row}\n  summary: {part}")


def test_keep_writes_provenance_and_the_row_takes_its_date(tmp_path):
    """--keep copies a summary with its provenance; the row then dates the part by it; a kept copy of another config
    is refused, and --keep does not overwrite a file it did not make without --force."""
    summary = tmp_path / "scorecard_summary.csv"
    _pinned_summary().to_csv(summary, index=False)
    kept = tmp_path / "kept.csv"
    assert hl.main(["--summary", str(summary), "--config", CI_CONFIG, "--keep", str(kept), "--date", "2026-01-02",
                    "--commit", "abc1234", "--command", "snakemake -c2 --configfile config/config.ci.yaml"]) == 0
    prov = hl.provenance(kept)
    assert prov == {"date": "2026-01-02", "commit": "abc1234", "config": CI_CONFIG,
                    "command": "snakemake -c2 --configfile config/config.ci.yaml"}
    pd.testing.assert_frame_equal(hl.read_summary(kept), _pinned_summary())
    readme = tmp_path / "README.md"
    readme.write_text(f"| {hl.QUESTION} | old | x |\n")
    assert hl.main(["--summary", str(kept), "--config", CI_CONFIG, "--readme", str(readme), "--write"]) == 0
    assert hl.row_sources(hl.readme_row(readme.read_text())) == [(CI_CONFIG, "2026-01-02")]
    with pytest.raises(SystemExit):                      # the kept copy names its config
        hl.main(["--summary", str(kept), "--config", "config/config.yaml"])
    other = tmp_path / "notes.csv"
    other.write_text("mine\n")
    with pytest.raises(SystemExit):                      # not a kept summary: refused without --force
        hl.main(["--summary", str(summary), "--config", CI_CONFIG, "--keep", str(other), "--commit", "abc1234"])
    assert other.read_text() == "mine\n"


# --------------------------------------------------------------------------- the reduced pipeline

@pytest.fixture(scope="module")
def ci_summary(repo_copy, ci_pipeline):
    assert ci_pipeline.returncode == 0, ci_pipeline.stdout[-3000:] + ci_pipeline.stderr[-3000:]
    return hl.read_summary(repo_copy / "results/report/scorecard_summary.csv")


def test_reduced_scorecard_counts_are_pinned(ci_summary):
    got = {(r["chapter"], r["kind"]): tuple(int(r[c]) for c in SUMMARY_COLUMNS[2:])
           for r in ci_summary.to_dict("records")}
    assert got == CI_COUNTS, ("reduced scorecard counts changed; if intended, update CI_COUNTS and the README row "
                              "(see this module's docstring):\n"
                              + "\n".join(f"{k}: pinned {CI_COUNTS.get(k)}, now {got.get(k)}"
                                          for k in sorted(set(got) | set(CI_COUNTS), key=str)
                                          if got.get(k) != CI_COUNTS.get(k)))


def test_readme_row_agrees_with_the_reduced_summary(ci_summary):
    row = _readme_row()
    part = hl.answer_part(hl.Run(ci_summary, CI_CONFIG, _ci_date(row)))
    assert part in row, f"README row differs from the reduced summary:\n  README: {row}\n  summary: {part}"
