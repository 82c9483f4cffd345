"""Chapter 6 scorer: Table 6.1 (sequential estimation, p2m7).
"""

from __future__ import annotations

from neckstrength.report.scorecard.estimates import _score_estimates
from neckstrength.report.scorecard.rows import Context


def score_ch6(ctx: Context) -> list[dict]:
    return _score_estimates(ctx, "Chapter 6", "Table 6.1 (p2m7)", "p2m7", "table_6_1_p2m7_sequential.csv")
