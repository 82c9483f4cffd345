"""Chapter 5 scorer: Tables 5.1-5.3 (Algorithm 4 estimates) and the Table 5.1 caption claim.
"""

from __future__ import annotations

import math

from neckstrength.report.scorecard.estimates import _baseline, _score_estimates
from neckstrength.report.scorecard.rows import Context, _error_text, _not_evaluated, _read, _row
from neckstrength.report.scorecard.tolerances import _num, _tol_text


CH5_TABLES = {"p2m7": "Table 5.1", "p3m12": "Table 5.2", "s3m24": "Table 5.3"}


# Claims printed in a table caption: model -> (data set, group). Table 5.1: "The algorithm was able to identify
# weakness of the deep extensor muscle group (TC-E) in the 'weak' data set, with high confidence."
CH5_CAPTION_CLAIMS = {"p2m7": ("weak", "TC-E")}


def _weakness_claim(ctx: Context, source: str, model: str) -> list[dict]:
    """'weakness of <group> identified in <data set> with high confidence': f_c closer to the weakened f_a than to
    the unweakened f_a ('norm'), and sigma_c below the identification threshold."""
    if model not in CH5_CAPTION_CLAIMS:
        return []
    ds, g = CH5_CAPTION_CLAIMS[model]
    df = _read(ctx.path)
    df["muscle"] = df["muscle"].astype(object).fillna("")
    cell = {(r["dataset"], r["quantity"], r["muscle"]): (_num(r["thesis"]), _num(r["ours"]))
            for r in df.to_dict("records")}
    need = [(ds, "f_c", g), (ds, "sigma_c", g), (ds, "f_a", g)]
    if not all(k in cell for k in need):
        return []
    item = f"{ds}: weakness of {g} identified with high confidence"
    csource = source.replace(" (", " caption (", 1)
    concl = ("f_c closer to the weakened f_a than to the unweakened f_a ('norm') and sigma_c < "
             f"{ctx.tols['identified_sigma'].value:g}")
    try:
        base = float(_baseline(df, ctx, model, None)[g])
        if math.isnan(base):
            raise ValueError(f"the unweakened f_a of {g} is not a number")
    except Exception as e:  # noqa: BLE001 - any failure: the claim is not evaluated, with the error as its reason
        return [_not_evaluated("Chapter 5", csource, item, concl, ctx.rel,
                               _error_text(e) + " (building the unweakened baseline f_a)")]
    f_a = cell[(ds, "f_a", g)][0]
    thr = ctx.tols["identified_sigma"].value

    def holds(side):
        f, s = cell[(ds, "f_c", g)][side], cell[(ds, "sigma_c", g)][side]
        return bool(abs(f - f_a) < abs(f - base) and s < thr), f, s

    h_t, f_t, s_t = holds(0)
    h_o, f_o, s_o = holds(1)
    return [_row("Chapter 5", csource, item, "holds",
                 "holds" if h_o else "does not hold", math.nan, h_o,
                 _tol_text(ctx.tols["identified_sigma"], f"f_c closer to f_a = {f_a:g} N than to the unweakened "
                                                        f"f_a = {base:g} N ('norm') and sigma_c < {thr:g}"),
                 f"thesis f_c {f_t:g} N, sigma_c {s_t:g} ({'holds' if h_t else 'does not hold'} on the printed "
                 f"numbers); ours f_c {f_o:.4g} N, sigma_c {s_o:.3g}", ("random", "q"), ctx.rel,
                 basis="estimate from data simulated with the printed f_a (an input, not scored)")]


def score_ch5(ctx: Context) -> list[dict]:
    model = ctx.match["model"]
    source = f"{CH5_TABLES.get(model, 'Table 5.x')} ({model})"
    return _score_estimates(ctx, "Chapter 5", source, model, None) + _weakness_claim(ctx, source, model)
