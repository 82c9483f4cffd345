"""Conclusion tests and their chance rates: each test's agreement rule (vectorised over its items), the
agreement by chance when our values are permuted within the test's strata (:func:`chance_rates`), and the
tolerance table that shows every tolerance beside its test.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from neckstrength.report.scorecard.tolerances import N_PERMUTATIONS, TOLERANCES, Tolerance
from neckstrength.seeds import derive_rng


def _ranks(x: np.ndarray, strata: np.ndarray) -> np.ndarray:
    """Rank (1 = largest, ties share the lowest rank) of ``x`` within each stratum; NaN stays NaN."""
    x = np.asarray(x, float)
    same = np.asarray(strata)[:, None] == np.asarray(strata)[None, :]
    r = 1.0 + ((x[None, :] > x[:, None]) & same).sum(axis=1)
    return np.where(np.isnan(x), np.nan, r)


def _agree_rank(t, o, aux, strata):
    rt, ro = _ranks(t, strata), _ranks(o, strata)
    return ~np.isnan(ro) & (rt == ro)


def _sign_arr(x, zero):
    return np.where(np.abs(x) <= zero, 0, np.sign(x))


def _agree_sign(t, o, aux, strata):
    return ~np.isnan(o) & (_sign_arr(t, aux[:, 0]) == _sign_arr(o, aux[:, 0]))


def _agree_equal(t, o, aux, strata):
    return ~np.isnan(o) & (t == o)


def _icc_code(x):
    return np.select([x > 0.9, x > 0.75, x > 0.5], [3, 2, 1], 0).astype(float)


def _agree_icc(t, o, aux, strata):
    return ~np.isnan(o) & (_icc_code(t) == _icc_code(o))


def _recovery_code(x, f_true, rel):
    return np.where(np.abs(x - f_true) <= rel * f_true, 0, np.sign(x - f_true))


def _agree_recovery(t, o, aux, strata):
    return ~np.isnan(o) & (_recovery_code(t, aux[:, 0], aux[:, 1]) == _recovery_code(o, aux[:, 0], aux[:, 1]))


def _agree_identified(t, o, aux, strata):
    return ~np.isnan(t) & ~np.isnan(o) & ((t < aux[:, 0]) == (o < aux[:, 0]))


def _agree_d_band(t, o, aux, strata):
    band, eps = aux[:, 0], aux[:, 1]
    return ~np.isnan(o) & ((np.abs(t - o) <= band) | ((t >= eps) & (o >= eps)))


@dataclass(frozen=True)
class ConclusionTest:
    """A conclusion test: ``agree(thesis, ours, aux, strata)`` -> bool per item (vectorised over the test's items;
    ``aux`` holds per-item parameters, two columns). Its chance rate permutes ``ours`` within ``strata``."""

    key: str
    tolerance: str
    describes: str
    agree: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


CONCLUSION_TESTS: dict[str, ConclusionTest] = {t.key: t for t in (
    ConclusionTest("group_strength_rank", "b_strength_N",
                   "same rank of the group strength among the groups of its table", _agree_rank),
    ConclusionTest("moment_arm_sign", "b_moment_arm_m",
                   "same sign of the moment arm (role about the joint), per table", _agree_sign),
    ConclusionTest("loa_sign", "ci_print_half_unit", "same sign of a limit of agreement", _agree_sign),
    ConclusionTest("icc_class", "ci_print_half_unit", "same reliability class (Koo & Li 2016)", _agree_icc),
    ConclusionTest("f_significance", "f_rel", "same significance of an F test at alpha", _agree_equal),
    ConclusionTest("pairwise_significance", "p_print",
                   "same significance and direction of a pairwise comparison", _agree_equal),
    ConclusionTest("table_3_2_rank", "sampling_z",
                   "same rank of a group among the 3 groups at one level x quartile (mean or SD)", _agree_rank),
    ConclusionTest("recovers_f_a", "estimate_rel",
                   "simulated data set: same recovery class of f_a (within 10 %, above, below)", _agree_recovery),
    ConclusionTest("relative_strength_rank", "estimate_rel",
                   "participant: same rank of f_c / f_base among the data set's groups (f_base: the printed "
                   "baseline group strength of Table B.3/B.5/B.7)", _agree_rank),
    ConclusionTest("identification", "identified_sigma",
                   "same identification class (relative spread below 0.1 or not)", _agree_identified),
    ConclusionTest("D_fc_same_fit", "D_fc_band", "D(f_c) within 0.1, or both converged (>= eps_D)", _agree_d_band),
    ConclusionTest("convergence", "iters_rel", "same convergence (converged within maxIter or not)", _agree_equal),
)}


def _permute_within(o: np.ndarray, groups: Sequence[np.ndarray], rng: np.random.Generator) -> np.ndarray:
    out = o.copy()
    for idx in groups:
        out[idx] = o[rng.permutation(idx)]
    return out


def chance_rates(rows: pd.DataFrame, seed: int = 0, n_permutations: int = N_PERMUTATIONS) -> pd.DataFrame:
    """Per conclusion test: items, observed agreement, and agreement by chance (mean share of agreeing items when our
    compared values are permuted within the test's strata; ``n_permutations`` seeded permutations)."""
    out = []
    for key, test in CONCLUSION_TESTS.items():
        sub = rows[rows["_test"] == key] if "_test" in rows else rows.iloc[:0]
        if not len(sub):
            out.append({"test": key, "items": 0, "agreement": math.nan, "chance_rate": math.nan})
            continue
        t = sub["_tv"].to_numpy(float)
        o = sub["_ov"].to_numpy(float)
        aux = sub[["_aux0", "_aux1"]].to_numpy(float)
        strata = pd.factorize(sub["_stratum"].astype(str))[0]
        groups = [np.flatnonzero(strata == k) for k in np.unique(strata)]
        observed = float(test.agree(t, o, aux, strata).mean())
        rng = derive_rng(int(seed), key)  # key: the test's name (registered as '{test}')
        acc = 0.0
        for _ in range(n_permutations):
            acc += float(test.agree(t, _permute_within(o, groups, rng), aux, strata).mean())
        out.append({"test": key, "items": len(sub), "agreement": observed, "chance_rate": acc / n_permutations})
    return pd.DataFrame(out)


def tolerance_table(tols: Mapping[str, Tolerance] | None = None, chance: pd.DataFrame | None = None) -> pd.DataFrame:
    """Every tolerance with its reasoning, then every conclusion test beside its tolerance with its chance rate
    (``chance``: :func:`chance_rates` of the run; blank without it)."""
    tols = tols or TOLERANCES
    rows = [{"key": k, "kind": t.kind, "value": t.value, "unit": t.unit, "overridden": t.overridden,
             "beside": "", "items": math.nan, "chance_rate": math.nan, "used": "", "why": t.why}
            for k, t in tols.items()]
    cmax = tols["conclusion_chance_max"].value
    ch = chance.set_index("test") if chance is not None and len(chance) else None
    for key, test in CONCLUSION_TESTS.items():
        n = int(ch.loc[key, "items"]) if ch is not None and key in ch.index else 0
        c = float(ch.loc[key, "chance_rate"]) if n else math.nan
        used = ("not scored in this run" if not n else
                ("yes" if c <= cmax else f"no: chance rate above {cmax:g}"))
        rows.append({"key": key, "kind": "conclusion test", "value": math.nan, "unit": "", "overridden": False,
                     "beside": test.tolerance, "items": n, "chance_rate": round(c, 3) if n else math.nan,
                     "used": used, "why": test.describes})
    return pd.DataFrame(rows)
