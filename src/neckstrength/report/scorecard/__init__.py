"""Thesis scorecard: every number the thesis prints that the pipeline reproduces, ours beside it, with a verdict
and a *kind* that says whether the agreement is evidence of reproduction at all.

One row per printed number (or qualitative claim):

    chapter, source, item, kind, thesis, ours, difference, verdict, tolerance, conclusion, test, chance_rate,
    reason, basis, file

Kinds (:data:`KINDS`):

``independent``
    no input of the computation was derived from, fitted or tuned toward the compared thesis number.
``calibrated``
    an input was fitted or drawn to thesis numbers that determine the compared one: strengths recovered from
    Table B.3 (for each B.3 group as many items as unknowns were solved for; the over-determined rest stay
    independent, with their residual in print units in ``basis``), groups of Tables B.5/B.7 that contain recovered
    strengths or were edited by ``grouping_supplements.csv``, and every row computed from the SYNTHETIC Chapter 3
    cohort (drawn to Table 3.2 and the printed limits of agreement). Agreement of a calibrated row shows that the
    calibration worked, not that the thesis was reproduced.

``by construction``
    the agreement follows from how the computation was set up, whatever the implementation does: the Table B.1
    cells that the erratum (``errata_B1.csv``) relocated or inserted because they equal our derived moment arms
    (its evidence cites the derivation); D(f_c) on a noise-free simulated data set where both runs sit at the
    score's ceiling 1 (within the D(f_c) tolerance); sigma_c where both runs sit at the same clip limit of
    ``chapter5.sigma_clip``; an iteration count where both runs stopped at ``max_iter`` without converging (the
    cap is copied from the thesis). These rows are shown with their verdict and the reason in ``basis``, and never
    counted as reproduced. A row where only one side sits at such a value keeps its kind: that difference is
    evidence.

Inputs used as printed (Table B.1 strengths, Tables A.2/A.3, f_a of the simulated data sets) are not rows at all.

Verdict classes (:data:`VERDICTS`), decided per row in this order:

``matches``
    ours agrees with the printed value within the tolerance stated for its source (:data:`TOLERANCES`).
``same conclusion, different number``
    outside that tolerance, but the conclusion the thesis draws from the number also holds for ours, by a
    *conclusion test* (:data:`CONCLUSION_TESTS`) whose agreement by chance is small: each test's chance rate is
    computed on the run's own items by permuting our compared values within the test's strata
    (:func:`chance_rates`, seeded), and a test whose chance rate exceeds ``conclusion_chance_max`` (20 %) is not
    used (its rows can only match or differ; the ``conclusion`` column says so).
``differs``
    neither.

``not evaluated`` (not a verdict of a scored row; counted apart in the summary's ``not_evaluated`` column, each
item with its reason in the summary's header): a claim this configuration cannot check (Chapter 4 variants not
computed), or a scorer error while building an item (the reason names the exception type and message).

Every tolerance and every conclusion threshold lives in :data:`TOLERANCES`, with its reasoning; none was chosen by
looking at how close our numbers come to the thesis (no tuning).  ``report.tolerances`` in the config may override
a value (key = the :data:`TOLERANCES` key); the reasoning then no longer applies and the tolerance column says so.

Which result files are scored, and how, is the registry :data:`SOURCES`: one entry per kind of comparison table
(regular expression on the path, loader, sibling files it also reads).  A chapter that adds a comparison table adds
one entry there (:mod:`.sources`); the Snakemake rule takes its inputs from the pipeline's final outputs filtered by
the registry (:func:`scorecard_inputs`), so nothing else changes.

Not scored, on purpose:

- the inputs above;
- blank cells of Tables B.3/B.5/B.7 (no moment arm about that joint) are scored only where ours is not zero;
- Appendix A (Fig. A.4) prints no numbers, only the radar plot;
- Chapter 4 claims that this configuration cannot evaluate (variants not computed) are counted in the summary as
  ``not_evaluated``, not scored.

Package layout (one concept per module, imports downward only):

- :mod:`.tolerances`  verdicts, kinds, every tolerance with its reasoning, reasons, formatting helpers
- :mod:`.chance`      conclusion tests and their chance rates; the tolerance table
- :mod:`.rows`        a row before its verdict, an item not evaluated, a loader's context
- :mod:`.appendix_b`  Tables B.1, B.3/B.5/B.7
- :mod:`.chapter3`    Sec. 3.4 statistics, Table 3.2
- :mod:`.chapter4`    Sec. 4.3-4.4 claims
- :mod:`.estimates`   ABC estimate tables (shared by Chapters 5 and 6)
- :mod:`.chapter5`    Tables 5.1-5.3 and the Table 5.1 caption claim
- :mod:`.chapter6`    Table 6.1
- :mod:`.sources`     the registry of scored tables (:data:`SOURCES`)
- :mod:`.build`       the scorecard, its summary, headline and header
"""

from neckstrength.report.scorecard.tolerances import (  # noqa: F401
    BY_CONSTRUCTION,
    CALIBRATED,
    CHAPTER_ORDER,
    COLUMNS,
    DIFFERS,
    INDEPENDENT,
    KINDS,
    MATCHES,
    N_PERMUTATIONS,
    NOT_EVALUATED,
    PRINT_UNIT,
    REASONS,
    SAME_CONCLUSION,
    TOLERANCES,
    VERDICTS,
    Tolerance,
    _fmt,
    _num,
    _tol_text,
    tolerances,
)
from neckstrength.report.scorecard.chance import (  # noqa: F401
    CONCLUSION_TESTS,
    ConclusionTest,
    _agree_d_band,
    _agree_equal,
    _agree_icc,
    _agree_identified,
    _agree_rank,
    _agree_recovery,
    _agree_sign,
    _icc_code,
    _permute_within,
    _ranks,
    _recovery_code,
    _sign_arr,
    chance_rates,
    tolerance_table,
)
from neckstrength.report.scorecard.rows import (  # noqa: F401
    B_FILES,
    B_TABLES,
    GROUPING_FILES,
    Context,
    _error_text,
    _key,
    _not_evaluated,
    _read,
    _reason,
    _row,
    _sign,
)
from neckstrength.report.scorecard.appendix_b import (  # noqa: F401
    _group_calibration,
    b1_errata_from_derivation,
    recovered_strengths,
    score_b1,
    score_b_params,
    supplemented_groups,
)
from neckstrength.report.scorecard.chapter3 import (  # noqa: F401
    ICC_CLASSES,
    PAIRWISE_DIRECTION,
    _ch3_caveats,
    _ch3_kind,
    _icc_class,
    _parse_p,
    score_ch3_statistics,
    score_table_3_2,
)
from neckstrength.report.scorecard.chapter4 import (  # noqa: F401
    score_ch4_claims,
)
from neckstrength.report.scorecard.estimates import (  # noqa: F401
    SIGMA_CLIP,
    _at_clip_limit,
    _baseline,
    _printed_group_strengths,
    _score_estimates,
    _spearman_perm,
)
from neckstrength.report.scorecard.chapter5 import (  # noqa: F401
    CH5_CAPTION_CLAIMS,
    CH5_TABLES,
    _weakness_claim,
    score_ch5,
)
from neckstrength.report.scorecard.chapter6 import (  # noqa: F401
    score_ch6,
)
from neckstrength.report.scorecard.sources import (  # noqa: F401
    SOURCES,
    Source,
    scorecard_inputs,
    source_for,
)
from neckstrength.report.scorecard.settings import ScorecardSettings  # noqa: F401
from neckstrength.report.scorecard.build import (  # noqa: F401
    SUMMARY_COLUMNS,
    _agreement,
    _finalize,
    _source_family,
    build_scorecard,
    header_lines,
    headline,
    score_rows,
    summarize,
)

__all__ = [
    "B_FILES",
    "B_TABLES",
    "BY_CONSTRUCTION",
    "CALIBRATED",
    "CH5_CAPTION_CLAIMS",
    "CH5_TABLES",
    "CHAPTER_ORDER",
    "COLUMNS",
    "CONCLUSION_TESTS",
    "DIFFERS",
    "GROUPING_FILES",
    "ICC_CLASSES",
    "INDEPENDENT",
    "KINDS",
    "MATCHES",
    "N_PERMUTATIONS",
    "NOT_EVALUATED",
    "PAIRWISE_DIRECTION",
    "PRINT_UNIT",
    "REASONS",
    "SAME_CONCLUSION",
    "SIGMA_CLIP",
    "SOURCES",
    "SUMMARY_COLUMNS",
    "ScorecardSettings",
    "TOLERANCES",
    "VERDICTS",
    "ConclusionTest",
    "Context",
    "Source",
    "Tolerance",
    "b1_errata_from_derivation",
    "build_scorecard",
    "chance_rates",
    "header_lines",
    "headline",
    "recovered_strengths",
    "score_b1",
    "score_b_params",
    "score_ch3_statistics",
    "score_ch4_claims",
    "score_ch5",
    "score_ch6",
    "score_rows",
    "score_table_3_2",
    "scorecard_inputs",
    "source_for",
    "summarize",
    "supplemented_groups",
    "tolerance_table",
    "tolerances",
]
