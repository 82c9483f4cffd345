"""The Snakemake report on the reduced config: builds as HTML and as zip, every chapter's category has entries,
the thesis scorecard is filled with valid verdicts, no report()-registered output of the DAG is missing, and the
front page carries the scorecard summary, run time / memory per rule, software versions and seeds.

Runs in the session-wide temporary copy after the reduced pipeline (tests/conftest.py: run once for this file and
tests/pipeline/test_pipeline.py).
"""

import functools
import json
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pandas as pd
import pytest
import yaml

from neckstrength.report.runinfo import SOFTWARE
from neckstrength.report.scorecard import (CALIBRATED, COLUMNS, CONCLUSION_TESTS, INDEPENDENT, KINDS, MATCHES,
                                           SAME_CONCLUSION, SUMMARY_COLUMNS, VERDICTS)

SNAKEMAKE = [sys.executable, "-m", "snakemake"]
CI = ["--configfile", "config/config.ci.yaml"]
FRONT_PAGE = ("What was reproduced, and how close", "Independent items per chapter",
              "Calibrated items per chapter", "By construction per chapter", "Run time and peak memory",
              "Software versions and seeds")


def run(cmd, cwd, timeout=900):
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def built(ci_report):
    # report.html and report.zip, built once per session with the main dependencies only (tests/conftest.py)
    return ci_report


def _categories(html: str) -> dict:
    """The report's result index: category -> subcategory -> [paths] (the 'var categories' object)."""
    i = html.find("var categories = ")
    assert i >= 0, "no result index ('var categories') in the report"
    obj, _ = json.JSONDecoder().raw_decode(html[i + len("var categories = "):])
    return obj


def _report_calls(workdir: Path):
    """(path regex, category) of every report(...) call in workflow/rules/*.smk."""
    out = []
    for smk in sorted((workdir / "workflow" / "rules").glob("*.smk")):
        text = smk.read_text()
        for m in re.finditer(r"\breport\(", text):
            depth, j = 1, m.end()
            while depth and j < len(text):
                depth += {"(": 1, ")": -1}.get(text[j], 0)
                j += 1
            call = text[m.end():j - 1]
            path = re.match(r'\s*f?"([^"]+)"', call)
            cat = re.search(r'category\s*=\s*"([^"]+)"', call)
            if path:
                rx = re.sub(r"\\\{[^}]*\\\}", "[^/]+", re.escape(path.group(1)))
                out.append((re.compile(rx), cat.group(1) if cat else None, smk.name))
    assert out, "no report() calls found"
    return out


@functools.lru_cache(maxsize=None)
def _dag(workdir: Path):
    """Rules and output files of every job of the reduced DAG (dry run with --forceall)."""
    r = run(SNAKEMAKE + CI + ["-n", "--forceall"], workdir)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    text = r.stdout + r.stderr
    rules = frozenset(re.findall(r"^(?:local)?rule (\w+):", text, re.M))
    outputs = tuple(o.strip() for line in re.findall(r"^\s+output: (.+)$", text, re.M) for o in line.split(", "))
    assert rules and outputs
    return rules, outputs


def test_report_html_and_zip_build(built):
    html = (built / "report.html").read_text()
    assert len(html) > 100_000
    with zipfile.ZipFile(built / "report.zip") as z:
        names = z.namelist()
        assert "report/report.html" in names
        assert any(n.startswith("report/data/") for n in names)


def test_every_chapter_category_has_entries(built):
    expected = {c for _, c, _ in _report_calls(built) if c}
    assert {"Model", "Appendix A", "Chapter 3", "Chapter 4", "Chapter 5", "Scorecard", "Run records"} <= expected
    html_cats = _categories((built / "report.html").read_text())
    with zipfile.ZipFile(built / "report.zip") as z:
        zip_cats = _categories(z.read("report/report.html").decode())
    for cats in (html_cats, zip_cats):
        for c in expected:
            assert c in cats, f"category {c!r} missing from the report"
            assert sum(len(v) for v in cats[c].values()) > 0, f"category {c!r} has no entries"


def test_no_registered_output_missing(built):
    calls = _report_calls(built)
    _, outputs = _dag(built)
    registered = sorted({o for o in outputs if any(rx.fullmatch(o) for rx, _, _ in calls)})
    assert len(registered) >= 30
    cats = _categories((built / "report.html").read_text())
    in_report = {p for sub in cats.values() for paths in sub.values() for p in paths}
    with zipfile.ZipFile(built / "report.zip") as z:
        zip_files = {n.rsplit("/", 1)[-1] for n in z.namelist() if n.startswith("report/data/")}
    missing_files = [o for o in registered if not (built / o).is_file()]
    assert not missing_files, f"registered outputs not produced: {missing_files}"
    not_in_report = [o for o in registered if o not in in_report]
    assert not not_in_report, f"registered outputs missing from the HTML report: {not_in_report}"
    not_in_zip = [o for o in registered if Path(o).name not in zip_files]
    assert not not_in_zip, f"registered outputs missing from the zip report: {not_in_zip}"
    # and nothing in the report that does not exist
    assert all((built / p).is_file() for p in in_report)


def test_scorecard_rows_and_verdicts(built):
    sc = pd.read_csv(built / "results/report/scorecard.csv", comment="#")
    assert list(sc.columns) == COLUMNS
    assert len(sc) > 100
    assert set(sc["verdict"]) <= set(VERDICTS), set(sc["verdict"]) - set(VERDICTS)
    chapters = {"Appendix B", "Chapter 3", "Chapter 4", "Chapter 5"}
    if list((built / "results" / "chapter6").glob("*/table_6_1_vs_thesis.csv")):
        chapters.add("Chapter 6")
    assert chapters <= set(sc["chapter"]), chapters - set(sc["chapter"])
    for c in chapters:
        assert (sc["chapter"] == c).sum() > 0
    assert sc["item"].notna().all() and sc["thesis"].notna().all() and sc["tolerance"].notna().all()
    # every difference has a reason
    assert sc.loc[sc["verdict"] != MATCHES, "reason"].fillna("").str.len().gt(0).all()
    assert set(sc["kind"]) <= set(KINDS) and sc["basis"].fillna("").str.len().gt(0).all()
    # Appendix B parameters are deterministic: they all match within print rounding (reduced config)
    assert (sc.loc[sc["chapter"] == "Appendix B", "verdict"] == MATCHES).all()
    # degrees of freedom of the recovered strengths: Table B.3 has calibrated AND independent (over-determined) rows
    b3 = sc[sc["source"].str.startswith("Table B.3")]
    assert (b3["kind"] == CALIBRATED).sum() > 0 and (b3["kind"] == INDEPENDENT).sum() > 0
    assert b3.loc[b3["kind"] == INDEPENDENT, "basis"].str.contains("print units").all()
    # the SYNTHETIC Chapter 3 cohort is calibrated to the printed numbers: none of its rows is independent
    assert (sc.loc[sc["chapter"] == "Chapter 3", "kind"] == CALIBRATED).all()
    # 'same conclusion' only from a conclusion test whose chance rate is at most 0.2
    same = sc[sc["verdict"] == SAME_CONCLUSION]
    assert (same["chance_rate"] <= 0.2).all() and same["test"].isin(list(CONCLUSION_TESTS)).all()
    summ = pd.read_csv(built / "results/report/scorecard_summary.csv", comment="#")
    assert list(summ.columns) == SUMMARY_COLUMNS
    assert len(summ.columns) <= 7  # narrow: the front page shows it
    tot = summ[summ["chapter"] == "all"].set_index("kind")
    assert int(tot["items"].sum()) == len(sc)
    for kind in KINDS:
        assert int(tot.loc[kind, "items"]) == (sc["kind"] == kind).sum()
    for c in chapters:
        s = summ[summ["chapter"] == c]
        assert int(s["items"].sum()) == (sc["chapter"] == c).sum()
        assert (s["matches"] + s["same_conclusion"] + s["differs"] == s["items"]).all()
    # every conclusion test applied in this run has its chance rate in the tolerance table
    tol = pd.read_csv(built / "results/report/scorecard_tolerances.csv", comment="#")
    tests = tol[tol["kind"] == "conclusion test"].set_index("key")
    assert set(tests.index) == set(CONCLUSION_TESTS)
    for key in set(sc["test"].dropna()) - {""}:
        assert 0 <= tests.loc[key, "chance_rate"] <= 1 and tests.loc[key, "items"] == (sc["test"] == key).sum()
        assert tests.loc[key, "used"] == ("yes" if tests.loc[key, "chance_rate"] <= 0.2 else
                                          "no: chance rate above 0.2")
    # the summary header quotes independent counts first
    head = [ln for ln in (built / "results/report/scorecard_summary.csv").read_text().splitlines()
            if ln.startswith("#")]
    assert any(re.match(r"# \d+ independent items: .*; \d+ calibrated items", ln) for ln in head), head


def test_front_page_summary_runtime_environment(built):
    html = (built / "report.html").read_text()
    for text in FRONT_PAGE:
        assert text in html, f"front page lacks {text!r}"
    rules, _ = _dag(built)
    rt = pd.read_csv(built / "results/report/runtime.csv", comment="#")
    assert rules - {"all", "report_runtime"} <= set(rt["rule"]), rules - set(rt["rule"])
    assert (rt["seconds"] > 0).all()
    assert (rt["peak_rss_mb"] > 10).all() and (rt["peak_rss_mb"] < 24_000).all()
    assert (rt["time_source"] == "snakemake metadata").all()
    by_rule = pd.read_csv(built / "results/report/runtime_by_rule.csv", comment="#")
    assert set(by_rule["rule"]) == set(rt["rule"])
    env = pd.read_csv(built / "results/report/environment.csv", comment="#", dtype=str)
    sw = env[env["kind"] == "software"].set_index("name")["value"]
    for p in SOFTWARE:
        assert p in sw.index and sw[p] != "not installed", p
    seed = yaml.safe_load((built / "config/config.ci.yaml").read_text())["seed"]
    assert env.loc[(env["kind"] == "seed") & (env["name"] == "seed"), "value"].tolist() == [str(seed)]


# --------------------------------------------------------------------------- fast checks (no pipeline)

def test_registry_selects_comparison_tables_and_siblings():
    from neckstrength.report.scorecard import scorecard_inputs, source_for

    paths = ["results/model/s3m24/parameters_vs_thesis.csv", "results/model/s3m24/parameters.csv",
             "results/chapter3/SYNTHETIC/thesis_vs_ours.csv", "results/chapter3/SYNTHETIC/table_3_2.csv",
             "results/chapter4/claims.csv", "results/chapter5/p2m7/table_vs_thesis.csv",
             "results/chapter6/p2m7/table_6_1_vs_thesis.csv", "results/chapter6/p2m7/S005/estimate.csv",
             "results/appendix_a/table_A4.csv"]
    sel = scorecard_inputs(paths)
    assert "results/model/s3m24/groups.csv" in sel
    assert "results/model/s3m24/parameters.csv" not in sel
    assert "results/appendix_a/table_A4.csv" not in sel  # Fig. A.4 prints no numbers
    assert source_for("results/chapter6/p2m7/table_6_1_vs_thesis.csv")[0].chapter == "Chapter 6"
    assert source_for("results/chapter6/p2m7/S005/estimate.csv") is None


def test_tolerance_overrides_are_flagged_and_checked():
    from neckstrength.report.scorecard import TOLERANCES, tolerances

    t = tolerances({"estimate_rel": 0.2})
    assert t["estimate_rel"].value == 0.2 and t["estimate_rel"].overridden
    assert not TOLERANCES["estimate_rel"].overridden and TOLERANCES["estimate_rel"].value == 0.10
    assert all(tol.why for tol in TOLERANCES.values())
    with pytest.raises(ValueError, match="unknown key"):
        tolerances({"no_such_tolerance": 1.0})
