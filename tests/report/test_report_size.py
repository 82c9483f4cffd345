"""The report's size (issue 33 item 5: the full-config report under about 20 MB).

CI builds only the reduced report, so the full one is estimated from it: every embedded result's size per rule and
job of the reduced report (Snakemake embeds each report() output once, base64), times the full config's number of
jobs of that rule (``snakemake -n`` of config/config.yaml), plus the report's own page (scripts, rule graph). The
estimate is linear in the jobs: it assumes a full-config job's outputs are as large as a reduced one's of the same
rule (the reduced Chapter 5 runs p2m7 only; docs/benchmarks.md#report-size says how far off s3m24 could be).
A growth of either report fails here: the reduced report, its largest item, or the estimate.
"""

import json
import re
import subprocess
import sys
from collections import defaultdict

import pytest

SNAKEMAKE = [sys.executable, "-m", "snakemake"]
REDUCED_MAX_MB = 11.0      # 8.19 MB on 2026-11-28
ITEM_MAX_MB = 0.8          # largest embedded item 0.50 MB (results/report/scorecard.csv)
FULL_MAX_MB = 15.5         # 13.0 MB on 2026-11-28; +4.2 MB if Chapter 5's p3m12 / s3m24 figures are 2x / 3x p2m7's
                           # and the full scorecard 1.8x: still under 20 MB (docs/benchmarks.md#report-size)


def _results(html: str) -> dict:
    m = re.search(r'<script id="results">\s*var results = ', html)
    assert m, "no results script ('var results') in the report"
    obj, _ = json.JSONDecoder().raw_decode(html[m.end():])
    return obj


def _job_counts(cwd, *args) -> dict:
    r = subprocess.run(SNAKEMAKE + ["-n", "--forceall", "--quiet", "rules", *args], cwd=cwd, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    counts = dict(re.findall(r"^(\w+)\s+(\d+)\s*$", r.stdout + r.stderr, re.M))
    assert "all" in counts, (r.stdout + r.stderr)[-2000:]
    return {k: int(v) for k, v in counts.items()}


def report_size_estimate(html: str, full_jobs: dict) -> dict:
    """Bytes of the reduced report's page, of its items per rule and job, and the full report's estimate."""
    res = _results(html)
    per_rule, jobs = defaultdict(int), defaultdict(set)
    for e in res.values():
        rule = e["job_properties"]["rule"]
        per_rule[rule] += len(e["data_uri"])
        jobs[rule].add(json.dumps(e["job_properties"]["wildcards"], sort_keys=True))
    page = len(html) - sum(per_rule.values())
    full = page + sum(per_rule[r] / len(jobs[r]) * full_jobs.get(r, 0) for r in per_rule)
    return {"page": page, "per_rule": dict(per_rule), "jobs": {r: len(j) for r, j in jobs.items()},
            "full": full}


@pytest.fixture(scope="module")
def html(ci_report):
    return (ci_report / "report.html").read_text()


def test_reduced_report_and_its_items_stay_small(html):
    mb = len(html.encode()) / 1e6
    assert mb < REDUCED_MAX_MB, f"reduced report.html is {mb:.1f} MB (limit {REDUCED_MAX_MB} MB)"
    big = {p: len(e["data_uri"]) / 1e6 for p, e in _results(html).items() if len(e["data_uri"]) / 1e6 > ITEM_MAX_MB}
    assert not big, f"report items over {ITEM_MAX_MB} MB (embedded, base64): {big}"


def test_full_report_estimate_under_the_limit(html, ci_report):
    full_jobs = _job_counts(ci_report)          # the repository's config/config.yaml, default target
    est = report_size_estimate(html, full_jobs)
    rules_with_items = [r for r in full_jobs if r in est["per_rule"]]
    assert len(rules_with_items) >= 15, sorted(full_jobs)   # the estimate sees the full DAG's reported rules
    top = sorted(((v / est["jobs"][r] * full_jobs.get(r, 0) / 1e6, r) for r, v in est["per_rule"].items()),
                 reverse=True)[:5]
    assert est["full"] / 1e6 < FULL_MAX_MB, (f"estimated full-config report {est['full'] / 1e6:.1f} MB (limit "
                                              f"{FULL_MAX_MB} MB); largest rules (MB): {top}")


def test_estimate_grows_with_the_jobs():
    """The estimate is not vacuous: twice the jobs of a rule adds that rule's share once more."""
    html = ('<script id="results">var results = {"a.png": {"data_uri": "' + "x" * 1000 + '", "job_properties": '
            '{"rule": "r", "wildcards": {"d": "1"}}}};</script>')
    one, two = (report_size_estimate(html, {"r": n, "all": 1})["full"] for n in (1, 2))
    assert two - one == 1000
