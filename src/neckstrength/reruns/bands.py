"""Per printed item: the central band of our members, their spread, and the precision the thesis printed."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

#: quantities of the members matched to printed cells (Tables 5.1-5.3: f_c, sigma_c, D_fc, iters; Table 6.1: f_c,
#: v_c, D_fc)
QUANTITIES = ("f_c", "sigma_c", "v_c", "D_fc", "iters")


def printed_half_unit(text: str) -> float:
    """Half a unit of the last printed digit: '68' -> 0.5, '0.23' -> 0.005, '30+' -> 0.5, '1.5e2' -> 5."""
    t = str(text).strip().rstrip("+")
    if not t:
        return math.nan
    mant, _, exp = t.lower().partition("e")
    decimals = len(mant.split(".")[1]) if "." in mant else 0
    return 0.5 * 10.0 ** (-decimals + (int(exp) if exp else 0))


def central_band(values: np.ndarray, level: float = 0.9) -> tuple[float, float]:
    """The central ``level`` interval of the members (linear quantiles; NaN members ignored)."""
    v = np.asarray(values, float)
    v = v[~np.isnan(v)]
    if not len(v):
        return math.nan, math.nan
    lo, hi = np.quantile(v, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


def band_table(members: pd.DataFrame, thesis: pd.DataFrame, level: float = 0.9) -> pd.DataFrame:
    """One row per printed cell that has members: the members' central ``level`` band, median, sd, and the
    printed half unit.

    ``members``: columns ``model, dataset, member, quantity, parameter, value`` (one chapter);
    ``thesis``: the thesis table of that model (:func:`neckstrength.estimation.datasets.thesis_result_table`, with
    the printed text in ``value``), its ``group`` matched to a parameter by name, else to its right side
    ``<group>-R`` (the thesis prints one value per group), as the comparison tables do.
    ``spread`` is the half width of the band; ``print_reproducible`` is False where it exceeds the printed half
    unit (then the printed last digit differs from run to run of any implementation of the same estimator).
    """
    rows = []
    for (model, ds), mem in members.groupby(["model", "dataset"], sort=False):
        t = thesis[(thesis["model"] == model) & (thesis["dataset"] == ds)]
        params = set(mem["parameter"])
        for r in t.to_dict("records"):
            q = r["quantity"]
            if q not in QUANTITIES:
                continue
            g = r["group"] if isinstance(r["group"], str) else ""
            p = g if (g in params or not g) else f"{g}-R"
            vals = mem[(mem["quantity"] == q) & (mem["parameter"] == p)].sort_values("member")
            if not len(vals):
                continue
            v = vals["value"].to_numpy(float)
            lo, hi = central_band(v, level)
            half = printed_half_unit(r["value"])
            row = {"model": model, "dataset": ds, "quantity": q, "group": g, "parameter": p,
                   "thesis_text": str(r["value"]), "thesis": float(r["value_numeric"]),
                   "censored": bool(str(r.get("censored", "")).lower() == "true"), "members": len(v),
                   "band_low": lo, "band_high": hi, "median": float(np.nanmedian(v)),
                   "sd": float(np.nanstd(v, ddof=1)) if len(v) > 1 else math.nan,
                   "min": float(np.nanmin(v)), "max": float(np.nanmax(v)), "spread": (hi - lo) / 2,
                   "printed_half_unit": half, "print_reproducible": bool((hi - lo) / 2 <= half)}
            if q == "iters":
                conv = mem[(mem["quantity"] == "converged")].sort_values("member")["value"].to_numpy(float)
                row["share_converged"] = float(conv.mean()) if len(conv) else math.nan
            rows.append(row)
    return pd.DataFrame(rows)
