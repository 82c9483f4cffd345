"""Pipeline stages of ``workflow/rules/report.smk``: scorecard, run time, environment."""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Mapping, Sequence

import pandas as pd

from neckstrength.config import scorecard_settings
from neckstrength.report.runinfo import environment_table, runtime_by_rule, runtime_table
from neckstrength.report.scorecard import (
    build_scorecard,
    header_lines,
    headline,
    summarize,
    tolerance_table,
    tolerances,
)


def report_runtime(metadata_dir: str | Path, out_jobs, out_by_rule, exclude_rules: Iterable[str] = ()) -> pd.DataFrame:
    """The run-time rule: per job and per rule tables."""
    from neckstrength.io import atomic_write_csv

    jobs = runtime_table(metadata_dir, exclude_rules=exclude_rules)
    atomic_write_csv(jobs, out_jobs,
                     ["run time and peak memory per job of the latest execution of each output",
                      "seconds: Snakemake metadata (endtime - starttime; .snakemake/metadata); peak_rss_mb: peak "
                      "resident memory of the rule script process (VmHWM; job record appended to the job's log)"],
                     float_format="%.6g")
    by_rule = runtime_by_rule(jobs)
    atomic_write_csv(by_rule, out_by_rule,
                     ["run time and peak memory per rule (sum / max over its jobs; results/report/runtime.csv)"],
                     float_format="%.6g")
    print(by_rule.to_string(index=False))
    return jobs


def report_environment(config: Mapping, out_csv) -> pd.DataFrame:
    """The environment rule: software versions, platform and seeds."""
    from neckstrength.io import atomic_write_csv

    c5 = config.get("chapter5", {})
    env = environment_table(config.get("seed"), not config.get("chapter3", {}).get("data"),
                            [(m, d) for m in c5.get("models", []) for d in c5.get("datasets", [])])
    atomic_write_csv(env, out_csv, ["software versions seen by the report job, platform, and every seed the "
                                    "pipeline derives from config 'seed'"])
    print(env.to_string(index=False))
    return env


def report_scorecard(config: Mapping, inputs: Sequence[str], out_table, out_summary, out_tolerances,
                    overrides: Mapping[str, float] | None = None) -> pd.DataFrame:
    """The scorecard rule: scorecard, summary per chapter and the tolerance table."""
    from neckstrength.io import atomic_write_csv

    tols = tolerances(overrides)
    settings = scorecard_settings(config)
    scored, skipped = build_scorecard(list(inputs), settings, overrides)
    atomic_write_csv(scored, out_table, header_lines(settings, tols), float_format="%.5g")
    summary = summarize(scored, skipped)
    atomic_write_csv(summary, out_summary,
                     ["thesis scorecard summary: items per chapter, kind and verdict (results/report/scorecard.csv)",
                      headline(summary),
                      "not_evaluated: printed items this run could not score (claims this configuration cannot "
                      "check, scorer errors), each with its reason: "
                      + ("; ".join(f"{i} [{r}]" for i, r in zip(skipped["item"], skipped["reason"]))
                         if len(skipped) else "none")])
    atomic_write_csv(tolerance_table(tols, scored.attrs.get("chance")), out_tolerances,
                     ["scorecard tolerances and conclusion thresholds (neckstrength.report.scorecard.TOLERANCES), each with "
                      "its reasoning; overridden = set in config report.tolerances; conclusion tests beside their "
                      "tolerance with their chance rate in this run (used only if <= conclusion_chance_max)"])
    print(summary.to_string(index=False))
    return summary
