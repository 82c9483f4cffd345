"""Run-to-run scoring of the stochastic thesis results (issue 36): each printed Chapter 5 / 6 value against the
central 90 % band of our K reruns (:mod:`neckstrength.reruns`).

Verdicts (:data:`RUN_VERDICTS`):

``consistent with our implementation``
    the printed value lies inside our central band, widened by half a unit of its last printed digit (the print
    rounded it). A censored count ('30+') is consistent when some member also stopped at that cap.
``outside our band``
    it does not: the difference is not run-to-run variation of our implementation.

The chance rate of the test (:func:`band_chance_rate`) is computed as the conclusion tests' are: the share of
items whose printed value falls inside the band of another item of the same stratum (same table, quantity and,
for per-group quantities, data set), over seeded permutations of the bands. Beside each item: the members'
spread (half width of the band) and the printed half unit; where the spread is wider, the printed last digit
is not reproducible by any implementation of the estimator, ours included.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np
import pandas as pd

from neckstrength.report.scorecard.tolerances import N_PERMUTATIONS
from neckstrength.seeds import derive_rng

CONSISTENT = "consistent with our implementation"


OUTSIDE = "outside our band"


RUN_VERDICTS = (CONSISTENT, OUTSIDE)


COLUMNS = ["chapter", "source", "item", "thesis", "members", "band_low", "band_high", "median", "verdict",
           "spread", "printed_half_unit", "precision", "scorecard_kind", "scorecard_verdict"]


SUMMARY_COLUMNS = ["chapter", "source", "quantity", "items", "consistent", "share_consistent", "chance_rate",
                   "consistent_by_construction", "not_print_reproducible"]


def _item(r: Mapping) -> str:
    """The scorecard's item label of a band row ('weak: TC-E f_c (N)'), to join the main verdict."""
    g = r["group"] if isinstance(r["group"], str) else ""
    unit = {"f_c": " (N)", "v_c": " (N^2)"}.get(r["quantity"], "")
    return f"{r['dataset']}: {g + ' ' if g else ''}{r['quantity']}{unit}"


def _inside(thesis: np.ndarray, lo: np.ndarray, hi: np.ndarray, half: np.ndarray, censored: np.ndarray) -> np.ndarray:
    plain = (thesis >= lo - half - 1e-12) & (thesis <= hi + half + 1e-12)
    return np.where(censored, hi >= thesis - 1e-12, plain)


def _strata(bands: pd.DataFrame) -> np.ndarray:
    per_group = bands["group"].fillna("").astype(str) != ""
    source = bands["source"] if "source" in bands else bands["table"] + " (" + bands["model"] + ")"
    return (source + "|" + bands["quantity"] + "|"
            + np.where(per_group, bands["dataset"].astype(str), "")).to_numpy()


def band_chance_rate(bands: pd.DataFrame, seed: int, n_permutations: int = N_PERMUTATIONS) -> float:
    """Share of items 'consistent' when each printed value meets the band of a random item of its stratum (mean
    over ``n_permutations`` seeded permutations within strata)."""
    if not len(bands):
        return math.nan
    t = bands["thesis"].to_numpy(float)
    lo, hi = bands["band_low"].to_numpy(float), bands["band_high"].to_numpy(float)
    half = bands["printed_half_unit"].to_numpy(float)
    cens = bands["censored"].to_numpy(bool)
    strata = pd.factorize(_strata(bands))[0]
    groups = [np.flatnonzero(strata == k) for k in np.unique(strata)]
    rng = derive_rng(int(seed), "reruns/band_chance")
    acc = 0.0
    for _ in range(n_permutations):
        perm = np.arange(len(t))
        for idx in groups:
            perm[idx] = rng.permutation(idx)
        acc += float(_inside(t, lo[perm], hi[perm], half, cens).mean())
    return acc / n_permutations


def score_distribution(bands: pd.DataFrame, scorecard: pd.DataFrame | None, seed: int,
                       n_permutations: int = N_PERMUTATIONS) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per printed item its run-to-run verdict (beside the main scorecard's kind and verdict), and the summary per
    table and quantity with the chance rate of the test on that table's items; ``consistent_by_construction``
    counts the consistent items that the main scorecard marks "by construction" (a clip limit, the noise-free
    ceiling, a censored count: shown, not evidence)."""
    b = bands.copy()
    b["group"] = b["group"].fillna("").astype(str)
    b["source"] = b["table"] + " (" + b["model"] + ")"
    inside = _inside(b["thesis"].to_numpy(float), b["band_low"].to_numpy(float), b["band_high"].to_numpy(float),
                     b["printed_half_unit"].to_numpy(float), b["censored"].to_numpy(bool))
    b["verdict"] = np.where(inside, CONSISTENT, OUTSIDE)
    b["item"] = [_item(r) for r in b.to_dict("records")]
    b["precision"] = np.where(
        b["print_reproducible"].astype(bool), "",
        [f"spread {s:.3g} > printed half unit {h:g}: the printed value is not reproducible by any implementation, "
         "ours included" for s, h in zip(b["spread"], b["printed_half_unit"])])
    main = {}
    if scorecard is not None and len(scorecard):
        main = {(r["source"], r["item"]): (r["kind"], r["verdict"]) for r in scorecard.to_dict("records")}
    b["scorecard_kind"] = [main.get((s, i), ("", ""))[0] for s, i in zip(b["source"], b["item"])]
    b["scorecard_verdict"] = [main.get((s, i), ("", ""))[1] for s, i in zip(b["source"], b["item"])]
    rows = []
    for (ch, src), sub in b.groupby(["chapter", "source"], sort=False):
        chance = band_chance_rate(sub, seed, n_permutations)
        for q, s in [("all", sub)] + list(sub.groupby("quantity", sort=False)):
            n = len(s)
            k = int((s["verdict"] == CONSISTENT).sum())
            rows.append({"chapter": ch, "source": src, "quantity": q, "items": n, "consistent": k,
                         "share_consistent": k / n if n else math.nan,
                         "chance_rate": chance if q == "all" else band_chance_rate(s, seed, n_permutations),
                         "consistent_by_construction": int(((s["verdict"] == CONSISTENT)
                                                            & (s["scorecard_kind"] == "by construction")).sum()),
                         "not_print_reproducible": int((~s["print_reproducible"].astype(bool)).sum())})
    out = b.assign(thesis=b["thesis_text"])[COLUMNS].reset_index(drop=True)
    return out, pd.DataFrame(rows, columns=SUMMARY_COLUMNS)


def group_spread(bands: pd.DataFrame) -> pd.DataFrame:
    """The members' seed-to-seed spread of f_c per muscle group and table: median over the data sets of the band's
    half width relative to the median (and the largest), beside the printed half unit relative to the value."""
    f = bands[bands["quantity"] == "f_c"].copy()
    if not len(f):
        return pd.DataFrame(columns=["source", "group", "datasets", "median_rel_spread", "max_rel_spread",
                                     "median_rel_print_half_unit"])
    f["source"] = f["table"] + " (" + f["model"] + ")"
    f["rel"] = f["spread"] / f["median"].abs()
    f["rel_print"] = f["printed_half_unit"] / f["thesis"].abs()
    return (f.groupby(["source", "group"], sort=False)
            .agg(datasets=("dataset", "nunique"), median_rel_spread=("rel", "median"), max_rel_spread=("rel", "max"),
                 median_rel_print_half_unit=("rel_print", "median")).reset_index())


def within_tolerance(quantity: str, thesis: float, ours: float, censored: bool = False,
                     tols: Mapping | None = None) -> bool:
    """The scorecard's 'matches' test of one Chapter 5 / 6 value (:data:`TOLERANCES`: f_c max(0.5 N, 10 %), sigma_c
    0.05, v_c max(0.5 N^2, 21 %) (the f_c tolerance squared), D(f_c) 0.01, iterations max(1, 20 %); a censored
    count matches a run that reached the cap)."""
    from neckstrength.report.scorecard.tolerances import TOLERANCES

    t = tols or TOLERANCES
    d = abs(ours - thesis)
    if math.isnan(d):
        return False
    if quantity == "f_c":
        return d <= max(0.5, t["estimate_rel"].value * abs(thesis))
    if quantity == "sigma_c":
        return d <= t["sigma_c_abs"].value
    if quantity == "v_c":
        return d <= max(0.5, ((1 + t["estimate_rel"].value) ** 2 - 1) * abs(thesis))
    if quantity == "D_fc":
        return d <= t["D_fc_abs"].value
    if quantity == "iters":
        return ours >= thesis if censored else d <= max(1.0, t["iters_rel"].value * abs(thesis))
    return d <= t["estimate_rel"].value * abs(thesis)


ATTRIBUTION_COLUMNS = ["variant", "changes", "items", "members", "on_print", "inside_band", "within_tolerance",
                       "moved_onto", "moved_off", "median_abs_rel_diff_f_c", "moved_onto_items", "note"]


def attribution_summary(runs: pd.DataFrame, changes: Mapping[str, str], baseline: str = "baseline"
                        ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per variant (a band table per variant with a ``variant`` column, as :func:`neckstrength.reruns.bands.band_table`
    writes it; one member each for Algorithm 4, K for Table 6.1): how many printed items our value (the members'
    median) meets on the print (within half a printed unit), inside our central band widened by half a printed unit
    (the run-to-run verdict "consistent with our implementation") and within the scorecard's tolerance, and which
    items the change moved onto the thesis's value (within tolerance now, not at ``baseline``) or off it. Returns
    (per item, per variant)."""
    r = runs.copy()
    r["ours"] = r["median"]
    r["on_print"] = (r["ours"] - r["thesis"]).abs() <= r["printed_half_unit"] + 1e-12
    r["inside_band"] = _inside(r["thesis"].to_numpy(float), r["band_low"].to_numpy(float),
                               r["band_high"].to_numpy(float), r["printed_half_unit"].to_numpy(float),
                               r["censored"].to_numpy(bool))
    r["within_tolerance"] = [within_tolerance(q, t, o, c) for q, t, o, c in
                             zip(r["quantity"], r["thesis"], r["ours"], r["censored"])]
    r["item"] = [f"{m} " + _item(x) for m, x in zip(r["model"], r.to_dict("records"))]
    base = r[r["variant"] == baseline].set_index("item")["within_tolerance"]
    rows = []
    for v, sub in r.groupby("variant", sort=False):
        w = sub.set_index("item")["within_tolerance"]
        b = base.reindex(w.index).fillna(False).astype(bool)
        onto = [i for i in w.index if w[i] and not b[i]]
        off = [i for i in w.index if b[i] and not w[i]]
        f = sub[sub["quantity"] == "f_c"]
        rel = ((f["ours"] - f["thesis"]).abs() / f["thesis"].abs()).median() if len(f) else math.nan
        rows.append({"variant": v, "changes": changes.get(v, ""), "items": len(sub),
                     "members": int(sub["members"].max()), "on_print": int(sub["on_print"].sum()),
                     "inside_band": int(sub["inside_band"].sum()),
                     "within_tolerance": int(sub["within_tolerance"].sum()), "moved_onto": len(onto),
                     "moved_off": len(off), "median_abs_rel_diff_f_c": rel, "moved_onto_items": "; ".join(onto),
                     "note": ""})
    cols = ["variant", "item", "model", "dataset", "quantity", "group", "thesis_text", "ours", "band_low", "band_high",
            "members", "on_print", "inside_band", "within_tolerance"]
    return r[cols].reset_index(drop=True), pd.DataFrame(rows, columns=ATTRIBUTION_COLUMNS)
