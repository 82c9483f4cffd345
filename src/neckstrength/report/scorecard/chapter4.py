"""Chapter 4 scorer: the qualitative claims of Sec. 4.3-4.4 as computed checks.
"""

from __future__ import annotations

import math

from neckstrength.report.scorecard.rows import Context, _not_evaluated, _read, _row
from neckstrength.report.scorecard.tolerances import _tol_text


def score_ch4_claims(ctx: Context) -> list[dict]:
    df = _read(ctx.path)
    t = ctx.tols["claim"]
    rows = []
    for r in df.to_dict("records"):
        verdict = str(r["verdict"])
        if verdict not in ("holds", "does not hold"):
            rows.append(_not_evaluated("Chapter 4", f"Sec. {r['section']}", r["claim"], str(r["numbers"]), ctx.rel,
                                       f"not evaluated in this configuration: {r['numbers']}"))
            continue
        rows.append(_row("Chapter 4", f"Sec. {r['section']}", f"{r['claim']} [{r['variants']}]", "holds", verdict,
                         math.nan, verdict == "holds",
                         _tol_text(t, f"claim check (relative tolerance {ctx.settings.claim_tolerance_rel}, anterior "
                                      f"|azimuth| < {ctx.settings.anterior_max_azimuth_deg} deg)"),
                         str(r["numbers"]), ("geometry", "grouping") if "sagittal" in str(r["variants"])
                         else ("geometry",), ctx.rel,
                         basis="computed on the model's strength surfaces; nothing fitted to the claim"))
    return rows
