"""The registry of scored comparison tables (:data:`SOURCES`): which result files are scored, by which loader,
with which sibling files; :func:`scorecard_inputs` selects the rule's inputs from the pipeline's outputs.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

from neckstrength.report.scorecard.appendix_b import score_b1, score_b_params
from neckstrength.report.scorecard.chapter3 import score_ch3_statistics, score_table_3_2
from neckstrength.report.scorecard.chapter4 import score_ch4_claims
from neckstrength.report.scorecard.chapter5 import score_ch5
from neckstrength.report.scorecard.chapter6 import score_ch6
from neckstrength.report.scorecard.rows import Context


@dataclass(frozen=True)
class Source:
    """One kind of comparison table: ``pattern`` (regex on the path), ``loader`` (-> scorecard rows), and sibling
    files the loader also reads (added to the rule's inputs)."""

    key: str
    chapter: str
    pattern: str
    loader: Callable[[Context], list[dict]]
    companions: tuple[str, ...] = field(default=())
    describes: str = ""

    def matches(self, path: str) -> re.Match | None:
        return re.search(self.pattern, str(path).replace("\\", "/"))


SOURCES: tuple[Source, ...] = (
    Source("b_params", "Appendix B", r"(^|/)results/model/(?P<model>p2m7|p3m12|s3m24)/parameters_vs_thesis\.csv$",
           score_b_params, ("groups.csv",), "Tables B.3/B.5/B.7: reduced-model strengths and moment arms"),
    Source("b1", "Appendix B", r"(^|/)results/model/momentarm_vs_B1\.csv$", score_b1,
           describes="Table B.1: moment arms of the full model (strengths are inputs, not scored)"),
    Source("ch3_statistics", "Chapter 3", r"(^|/)results/chapter3/(?P<dataset>[^/]+)/thesis_vs_ours\.csv$",
           score_ch3_statistics, describes="Sec. 3.4: limits of agreement, ICCs, F tests, pairwise comparisons"),
    Source("ch3_table_3_2", "Chapter 3", r"(^|/)results/chapter3/(?P<dataset>[^/]+)/table_3_2\.csv$",
           score_table_3_2, describes="Table 3.2: MFI mean and SD per group x level x quartile"),
    Source("ch4_claims", "Chapter 4", r"(^|/)results/chapter4/claims\.csv$", score_ch4_claims,
           describes="Sec. 4.3-4.4: qualitative claims as computed checks"),
    Source("ch5_tables", "Chapter 5", r"(^|/)results/chapter5/(?P<model>p2m7|p3m12|s3m24)/table_vs_thesis\.csv$",
           score_ch5, describes="Tables 5.1-5.3: ABC estimates f_c, sigma_c, D(f_c), iterations"),
    # Chapter 6 (Table 6.1, p2m7 sequential estimation): any comparison table under results/chapter6/ whose name
    # says it is beside the thesis, in the long format of Chapter 5 (dataset, quantity, muscle, thesis, ours).
    Source("ch6_table", "Chapter 6", r"(^|/)results/chapter6/(.*/)?[^/]*(vs_thesis|thesis_vs|6_1)[^/]*\.csv$",
           score_ch6, describes="Table 6.1: sequential estimation f_c, v_c, D(f_c)"),
)


def source_for(path: str) -> tuple[Source, re.Match] | None:
    for s in SOURCES:
        m = s.matches(path)
        if m:
            return s, m
    return None


def scorecard_inputs(paths: Iterable[str]) -> list[str]:
    """The files among ``paths`` that the registry scores, plus their sibling files (order kept, no duplicates)."""
    out: list[str] = []
    for p in paths:
        hit = source_for(str(p))
        if not hit:
            continue
        s, _ = hit
        for f in [str(p)] + [str(Path(p).parent / c) for c in s.companions]:
            if f not in out:
                out.append(f)
    return out
