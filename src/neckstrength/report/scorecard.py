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
one entry here; the Snakemake rule takes its inputs from the pipeline's final outputs filtered by the registry
(:func:`scorecard_inputs`), so nothing else changes.

Not scored, on purpose:

- the inputs above;
- blank cells of Tables B.3/B.5/B.7 (no moment arm about that joint) are scored only where ours is not zero;
- Appendix A (Fig. A.4) prints no numbers, only the radar plot;
- Chapter 4 claims that this configuration cannot evaluate (variants not computed) are counted in the summary as
  ``not_evaluated``, not scored.
"""

from __future__ import annotations

import math
import re
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np
import pandas as pd

MATCHES = "matches"


SAME_CONCLUSION = "same conclusion, different number"


DIFFERS = "differs"


VERDICTS = (MATCHES, SAME_CONCLUSION, DIFFERS)


NOT_EVALUATED = "not evaluated"


INDEPENDENT = "independent"


CALIBRATED = "calibrated"


BY_CONSTRUCTION = "by construction"


KINDS = (INDEPENDENT, CALIBRATED, BY_CONSTRUCTION)


COLUMNS = ["chapter", "source", "item", "kind", "thesis", "ours", "difference", "verdict", "tolerance", "conclusion",
           "test", "chance_rate", "reason", "basis", "file"]


# print units (one unit of the last printed digit) of the Appendix B tables, for residuals in print units
PRINT_UNIT = {"strength_N": 0.1, "moment_arm_m": 1e-4}


# permutations per conclusion test for its chance rate (seeded from config 'seed')
N_PERMUTATIONS = 2000


CHAPTER_ORDER = ["Appendix B", "Chapter 3", "Chapter 4", "Chapter 5", "Chapter 6"]


@dataclass(frozen=True)
class Tolerance:
    """A tolerance or conclusion threshold: ``kind`` says how ``value`` is used, ``why`` gives the reasoning."""

    value: float
    kind: str      # abs | rel | print | ci | sampling | statement | threshold
    unit: str
    why: str
    overridden: bool = False


TOLERANCES: dict[str, Tolerance] = {
    # ---- Appendix B: model parameters (deterministic; only rounding separates ours from the print)
    "b1_moment_arm_m": Tolerance(
        5e-5, "print", "m",
        "Table B.1 prints moment arms in m to 4 decimals. Ours are derived from the same public OpenSim model "
        "(docs/model_derivation.md), so only print rounding separates them: half a unit of the last printed digit."),
    "b_strength_N": Tolerance(
        0.05, "print", "N",
        "Tables B.3/B.5/B.7 print group strengths to 0.1 N. Our inputs are printed values too (Table B.1 strengths "
        "to 0.1 N; the 32 unprinted rows recovered from B.3), and a group strength is the 2-norm of its n members, "
        "so input rounding contributes up to 0.05*sqrt(n) N and the print another 0.05 N: "
        "tolerance 0.05*(1 + sqrt(n)) N."),
    "b_moment_arm_m": Tolerance(
        5e-5, "print", "m",
        "Group moment arms are printed to 0.1 mm. A group arm is sum(R_i F_i)/F_g over its n members, and our "
        "member arms agree with the thesis's only to print precision (Table B.1: 5e-5 m), so the members "
        "contribute up to 5e-5*sqrt(n) m and the print another 5e-5 m: tolerance 5e-5*(1 + sqrt(n)) m."),
    # ---- Chapters 5 and 6: stochastic estimates
    "estimate_rel": Tolerance(
        0.10, "rel", "",
        "ABC estimates are random (Algorithm 4 draws candidates; our random stream is not the thesis's) and depend "
        "on the rejection percentile q, which the thesis does not state. 10 % is our convention for 'the same "
        "estimate' (a third of the largest sampling spread sigma_max = 0.3 of Sec. 5.2.2.7), with a floor of the "
        "print rounding (0.5 N). Variances (Table 6.1 v_c) get (1 + 0.10)^2 - 1 = 21 %."),
    "sigma_c_abs": Tolerance(
        0.05, "abs", "",
        "sigma_c (relative spread, printed to 0.01, clipped to [0.01, 0.3]) of a random run: 0.05 absolute, a sixth "
        "of the clip range."),
    "D_fc_abs": Tolerance(
        0.01, "abs", "",
        "D(f_c) is printed to 2 decimals; one unit of the last printed digit."),
    "D_fc_band": Tolerance(
        0.10, "threshold", "",
        "Conclusion threshold for D(f_c): the same fit quality when |d| <= 0.1 (a tenth of the score's range), or "
        "both at or above the convergence threshold eps_D (both converged). 'Same side of eps_D' alone is not a "
        "conclusion (0.23 and 0.69 are on the same side)."),
    "iters_rel": Tolerance(
        0.20, "rel", "",
        "Iteration counts of a random run: 20 % of the printed count (at least 1 iteration) when both runs "
        "converged. A censored count ('30+': stopped at maxIter without converging) is compared as censored: it "
        "matches only a run of ours that also stopped at that cap without converging; a converged run never "
        "matches a censored one."),
    "identified_sigma": Tolerance(
        0.10, "threshold", "",
        "Conclusion threshold: a group counts as 'identified' when its relative spread sigma_c (or sqrt(v_c)/f_c) "
        "is below 0.1, a third of sigma_max; otherwise 'uncertain' (the thesis reads sigma_c as high / low "
        "confidence, e.g. the Table 5.1 caption)."),
    # ---- Chapter 3: statistics of one cohort (SYNTHETIC unless real data are configured)
    "ci_print_half_unit": Tolerance(
        0.005, "ci", "",
        "Limits of agreement: matches when the printed limit lies inside our 95 % CI of that limit (Bland & "
        "Altman 1986). ICC(2,1): matches when ours lies inside the printed 95 % CI. Either interval is widened by "
        "half a unit of the printed digit (0.005)."),
    "f_rel": Tolerance(
        0.20, "rel", "",
        "F statistics of one cohort of 15 participants: 20 % of the printed F. There is no sampling distribution "
        "to derive this from (F values across synthetic seeds spread over an order of magnitude, "
        "docs/chapter3.md), so 20 % is a strict bar for 'the same number'."),
    "p_print": Tolerance(
        0.0, "statement", "",
        "Pairwise comparisons print only p (and df): matches when ours satisfies the printed statement "
        "('p < x', 'p = x' within half a unit of its last digit, 'no significant difference' = p > alpha) with "
        "the printed direction."),
    "sampling_z": Tolerance(
        2.0, "sampling", "",
        "Table 3.2 cells (mean and SD over n = 5 participants per group): matches within 2 standard errors of "
        "the printed value, SE = SD/sqrt(n) for a mean and SD/sqrt(2(n-1)) for an SD (the printed SD is used)."),
    # ---- conclusion tests
    "conclusion_chance_max": Tolerance(
        0.20, "threshold", "",
        "A conclusion test is used only if its agreement by chance is at most 20 %: the share of items on which "
        "it agrees when our compared values are permuted at random within the test's strata (mean over "
        f"{N_PERMUTATIONS} seeded permutations). A test that agrees by chance more often than one time in five "
        "cannot tell a reproduced conclusion from a coin flip; its rows can then only match or differ."),
    # ---- Chapter 4: qualitative claims
    "claim": Tolerance(
        0.0, "statement", "",
        "A claim matches when our computed check holds (neckstrength.surfaces.evaluate_claims with the "
        "config chapter4 thresholds) and differs when it does not hold."),
}


# Why a number may differ from the print (joined into the 'reason' column of rows that do not match).
REASONS = {
    "print": "print rounding",
    "inputs": "inputs recovered from printed values (Table B.1 rounding, B.3-implied strengths)",
    "synthetic": "synthetic data: SYNTHETIC cohort (the thesis's per-participant MFI was never published)",
    "calibrated": "synthetic data calibrated to this printed number: agreement shows the calibration, "
                  "not a replication",
    "satterthwaite": "different method: Wald chi-square/z tests without Satterthwaite df (statsmodels; the thesis "
                     "used SPSS)",
    "geometry": "reconstructed geometry: test-point coordinates are not printed (docs/geometry.md)",
    "random": "random estimator: different random stream from the thesis",
    "q": "unspecified parameter: rejection percentile q (90) not stated in the thesis",
    "grouping": "reconstructed grouping: the sagittal groupings are described only in words (docs/model.md)",
    "construction": "agreement by construction (basis says why): shown, never counted as reproduced",
}


def tolerances(overrides: Mapping[str, float] | None = None) -> dict[str, Tolerance]:
    """:data:`TOLERANCES` with config overrides (``report.tolerances``) applied and marked."""
    out = dict(TOLERANCES)
    for k, v in (overrides or {}).items():
        if k not in out:
            raise ValueError(f"report.tolerances: unknown key {k!r} (known: {', '.join(sorted(out))})")
        out[k] = replace(out[k], value=float(v), overridden=True)
    return out


def _num(x) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return math.nan
    return v


def _fmt(x, sig: int = 5) -> str:
    v = _num(x)
    if math.isnan(v):
        return "" if x is None or (isinstance(x, float) and math.isnan(x)) else str(x)
    return f"{v:.{sig}g}"


def _tol_text(t: Tolerance, text: str) -> str:
    return text + (" (config override)" if t.overridden else "")


# --------------------------------------------------------------------------- conclusion tests

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
        rng = np.random.default_rng([int(seed), zlib.crc32(key.encode())])
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


def _row(chapter, source, item, thesis, ours, difference, within, tolerance, conclusion, reason_codes, file, *,
         kind=INDEPENDENT, basis="", test="", tv=math.nan, ov=math.nan, aux=(math.nan, math.nan), stratum="",
         always=()) -> dict:
    """A scorecard row before its verdict: ``within`` the tolerance or not, and its conclusion test (``test`` key,
    thesis-side ``tv`` and our ``ov`` values, per-item ``aux`` parameters, permutation ``stratum``)."""
    if test and test not in CONCLUSION_TESTS:
        raise KeyError(f"unknown conclusion test {test!r}")
    return {"chapter": chapter, "source": source, "item": item, "kind": kind, "thesis": thesis, "ours": ours,
            "difference": difference, "verdict": "", "tolerance": tolerance, "conclusion": conclusion, "test": test,
            "chance_rate": math.nan, "reason": "", "basis": basis, "file": str(file),
            "_within": bool(within), "_codes": tuple(reason_codes), "_always": tuple(always), "_test": test,
            "_tv": _num(tv), "_ov": _num(ov), "_aux0": _num(aux[0]), "_aux1": _num(aux[1]),
            "_stratum": f"{file}|{stratum}"}


def _not_evaluated(chapter, source, item, conclusion, file, reason: str, thesis: str = "holds") -> dict:
    """An item this run does not score, with ``reason`` (why: not computed here, or the scorer's error)."""
    r = _row(chapter, source, item, thesis, NOT_EVALUATED, math.nan, False, "", conclusion, (), file)
    r["verdict"], r["reason"] = NOT_EVALUATED, reason
    return r


def _error_text(e: BaseException) -> str:
    """'scorer error: KeyError: 'x'' -- the reason of an item whose scorer raised."""
    return f"scorer error: {type(e).__name__}: {e}"


def _reason(verdict: str, codes: Sequence[str], always: Sequence[str] = ()) -> str:
    """Reasons for a difference (rows that do not match); ``always`` codes are caveats shown on every row."""
    keys = list(always) + ([c for c in codes if c not in always] if verdict != MATCHES else [])
    return "; ".join(REASONS[c] for c in keys)


def _sign(x: float, zero: float) -> int:
    return 0 if abs(x) <= zero else (1 if x > 0 else -1)


def _read(path) -> pd.DataFrame:
    return pd.read_csv(path, comment="#")


@dataclass
class Context:
    config: Mapping
    tols: Mapping[str, Tolerance]
    match: re.Match
    path: Path
    rel: str  # path as given (relative to the working directory)


B_TABLES = {"s3m24": "Table B.3", "p3m12": "Table B.5", "p2m7": "Table B.7"}
B_FILES = {"s3m24": "table_B3_params_s3m24.csv", "p3m12": "table_B5_params_p3m12.csv",
           "p2m7": "table_B7_params_p2m7.csv"}
GROUPING_FILES = {"s3m24": "table_B2_groups_s3m24.csv", "p3m12": "table_B4_groups_p3m12.csv",
                  "p2m7": "table_B6_groups_p2m7.csv"}


def _key(name: str) -> str:
    return re.sub(r"\s+", " ", str(name).strip().lower())


def recovered_strengths(config: Mapping) -> dict[str, dict]:
    """Muscles whose strength was recovered from Table B.3 in this configuration (name -> record of
    ``b3_implied_strengths.csv``); empty with ``model.unprinted_strengths: osim``."""
    m = config.get("model", {})
    if m.get("unprinted_strengths", "b3_implied") != "b3_implied":
        return {}
    path = Path(config.get("data", {}).get("model_dir", "data/model")) / "b3_implied_strengths.csv"
    if not path.exists():
        return {}
    df = _read(path)
    return {_key(r["name"]): r for r in df.to_dict("records")}


def supplemented_groups(config: Mapping, model: str) -> dict[str, str]:
    """Groups of ``model`` whose membership an applied supplement with basis 'fit' changes (a row of
    ``grouping_supplements.csv`` that exists only to reproduce a printed value; applied with
    ``model.grouping_supplements: all``): group (as named in the printed grouping table) -> the supplements.
    Supplements justified by the printed tables or by anatomy (basis 'printed' / 'anatomy') calibrate nothing."""
    from neckstrength.model.reduction import supplement_level

    level = supplement_level(config.get("model", {}).get("grouping_supplements", True))
    if level != "all":
        return {}
    thesis_dir = Path(config.get("data", {}).get("thesis_dir", "data/thesis"))
    path = thesis_dir / "grouping_supplements.csv"
    if not path.exists():
        return {}
    sup = _read(path)
    sup = sup[(sup["model"] == model) & (sup["basis"] == "fit")] if "basis" in sup else sup.iloc[:0]
    printed = {}
    if (thesis_dir / GROUPING_FILES.get(model, "-")).exists():
        g = _read(thesis_dir / GROUPING_FILES[model])
        printed = {_key(r["muscle"]): str(r["group"]) for r in g.to_dict("records")}
    out: dict[str, list[str]] = {}
    for r in sup.to_dict("records"):
        grp = r["group"] if r["action"] == "add" and isinstance(r["group"], str) else printed.get(_key(r["muscle"]))
        if grp:
            out.setdefault(grp, []).append(f"{r['action']} {r['muscle']}")
    return {g: ", ".join(v) for g, v in out.items()}


def _group_calibration(ctx: Context, model: str, groups: pd.DataFrame | None) -> dict[str, tuple[int, str]]:
    """Per group of a named model: (number of its items that are calibrated, why); -1 = all of them."""
    rec = recovered_strengths(ctx.config)
    sup = supplemented_groups(ctx.config, model)
    out = {}
    if groups is None:
        if rec or sup:
            raise FileNotFoundError(f"{ctx.rel}: groups.csv beside it is needed to tell calibrated from independent "
                                    "items (recovered strengths / supplements are in use)")
        return out
    for r in groups.to_dict("records"):
        g = str(r["group"])
        members = [m.strip() for m in str(r.get("members", "")).split(";") if m.strip()]
        recm = [m for m in members if _key(m) in rec]
        base = re.sub(r"-[RL]$", "", g)
        why = []
        if recm:
            why.append(f"{len(recm)} of its {len(members)} member strengths recovered from Table B.3 "
                       f"({', '.join(recm)})")
        if base in sup or g in sup:
            why.append(f"membership edited by grouping_supplements.csv only to reproduce the printed table "
                       f"(basis 'fit': {sup.get(base, sup.get(g))})")
        if not why:
            continue
        if model == "s3m24" and recm and not (base in sup or g in sup):
            # Table B.3 is what the strengths were solved from: as many items as unknowns are calibrated
            out[g] = (len(recm), "; ".join(why))
        else:
            out[g] = (-1, "; ".join(why) + (
                "; Table B.3 fixes the recovered strengths, so this table's numbers follow from the same printed "
                "values" if recm else ""))
    return out


def score_b_params(ctx: Context) -> list[dict]:
    model = ctx.match["model"]
    src = f"{B_TABLES.get(model, 'Table B.x')} ({model})"
    df = _read(ctx.path)
    groups_csv = ctx.path.parent / "groups.csv"
    n_members = {}
    groups = None
    if groups_csv.exists():
        groups = _read(groups_csv)
        n_members = dict(zip(groups["group"], groups["n_members"]))
    calib = _group_calibration(ctx, model, groups)
    ts, ta = ctx.tols["b_strength_N"], ctx.tols["b_moment_arm_m"]
    st = df[df["quantity"] == "strength_N"]
    reasons = ("print", "inputs")
    rows = []
    for r in df.to_dict("records"):
        g, q = r["group"], r["quantity"]
        t, o = _num(r["thesis"]), _num(r["ours"])
        n = int(n_members.get(g, 1))
        blank = isinstance(r.get("note"), str) and "blank" in r["note"]
        d = o - t
        if q == "strength_N":
            tol = ts.value * (1 + math.sqrt(n))
            tol_txt = _tol_text(ts, f"|d| <= {ts.value:g}*(1+sqrt({n})) = {tol:.3g} N (print + input rounding)")
            concl = f"same rank among the {len(st)} group strengths"
            item = f"{g} strength (N)"
            test, aux, unit = "group_strength_rank", (math.nan, math.nan), PRINT_UNIT["strength_N"]
        else:
            tol = ta.value * (1 + math.sqrt(n))
            if blank and abs(o) <= tol:
                continue  # blank printed cell (no arm about this joint) and ours zero: nothing printed to score
            tol_txt = _tol_text(ta, f"|d| <= {ta.value:g}*(1+sqrt({n})) = {tol:.2g} m (print + input rounding)")
            concl = f"same sign of the moment arm: thesis {_sign(t, tol):+d}, ours " + (
                "-" if math.isnan(o) else f"{_sign(o, tol):+d}")
            item = f"{g} {q.replace(' (m)', '').replace('_', ' ')} moment arm (m)"
            test, aux, unit = "moment_arm_sign", (tol, math.nan), PRINT_UNIT["moment_arm_m"]
        within = not math.isnan(d) and abs(d) <= tol * (1 + 1e-9)
        resid = abs(d) / unit if not math.isnan(d) else math.nan
        row = _row("Appendix B", src, item + (" [blank in thesis]" if blank else ""), "" if blank else _fmt(t),
                   _fmt(o), d, within, tol_txt, concl, reasons, ctx.rel, test=test, tv=0.0 if blank else t, ov=o,
                   aux=aux, stratum="", basis=f"group strengths from Table B.1 as printed; moment arms derived "
                                             f"from the public OpenSim model; residual {resid:.2f} print units")
        row["_group"], row["_resid"], row["_q"] = g, resid, q
        rows.append(row)
    # degrees of freedom: per calibrated group, its strength and the (k - 1) best-fitting moment arms are calibrated
    for g, (k, why) in calib.items():
        mine = [r for r in rows if r["_group"] == g]
        if k < 0:
            chosen = mine
        else:
            st_rows = [r for r in mine if r["_q"] == "strength_N"]
            arms = sorted([r for r in mine if r["_q"] != "strength_N"], key=lambda r: r["_resid"])
            chosen = (st_rows + arms)[:k]
        for r in mine:
            if r in chosen:
                r["kind"] = CALIBRATED
                r["basis"] = (why + (f"; one of the {k} items counted for the {k} strengths solved from this group "
                                     f"(residual {r['_resid']:.2f} print units)" if k > 0 else
                                     f"; residual {r['_resid']:.2f} print units"))
            else:
                r["basis"] = (why + f"; over-determined: {len(mine) - k} printed numbers beyond the {k} solved "
                                    f"for; residual {r['_resid']:.2f} print units")
    for r in rows:
        for k in ("_group", "_resid", "_q"):
            r.pop(k, None)
    return rows


def b1_errata_from_derivation(config: Mapping) -> dict[tuple[int, str], str]:
    """Table B.1 cells that the erratum (``errata_B1.csv``, applied with ``model.apply_b1_errata``) relocated or
    inserted because they equal our derived moment arms: (row index, 'joint_axis') -> the erratum's evidence.

    An erratum row counts when it sets a value (``corrected`` not empty) and its evidence cites the derivation
    (the word 'derived'); a relocation justified by another printed table (rows 33/34 from Table B.3) does not.
    Empty without the erratum applied."""
    if not config.get("model", {}).get("apply_b1_errata", True):
        return {}
    path = Path(config.get("data", {}).get("thesis_dir", "data/thesis")) / "errata_B1.csv"
    if not path.exists():
        return {}
    err = _read(path)
    out = {}
    for r in err.to_dict("records"):
        ev = str(r.get("evidence", ""))
        if not math.isnan(_num(r.get("corrected"))) and re.search(r"derived", ev, re.I):
            out[(int(r["index"]), str(r["field"]))] = ev
    return out


def score_b1(ctx: Context) -> list[dict]:
    df = _read(ctx.path)
    df = df[df["joint"] != "strength"]  # B.1 strengths are inputs (used as printed), not reproduced
    t = ctx.tols["b1_moment_arm_m"]
    errata = b1_errata_from_derivation(ctx.config)
    rows = []
    for r in df.to_dict("records"):
        th, o = _num(r["thesis_B1"]), _num(r["derived"])
        d = o - th
        within = abs(d) <= t.value * (1 + 1e-6)
        st_, so = _sign(th, t.value), _sign(o, t.value)
        ev = errata.get((int(r["index"]), f"{r['joint']}_{r['axis']}"))
        kind, basis = INDEPENDENT, "derived from the public OpenSim model geometry; nothing fitted to Table B.1"
        if ev is not None:
            kind, basis = BY_CONSTRUCTION, (
                "cell relocated or inserted by the Table B.1 erratum (errata_B1.csv) because it equals our derived "
                f"moment arm ({ev}): agreement by construction")
        rows.append(_row("Appendix B", "Table B.1", f"row {r['index']} {r['name']}: {r['joint']} {r['axis']} moment "
                         "arm (m)", _fmt(th), _fmt(o), d, within,
                         _tol_text(t, f"|d| <= {t.value:g} m (print rounding)"),
                         f"same sign: thesis {st_:+d}, ours {so:+d}", ("print",), ctx.rel, kind=kind,
                         basis=basis, test="moment_arm_sign", tv=th, ov=o, aux=(t.value, math.nan), stratum="B.1"))
    return rows


ICC_CLASSES = ((0.9, "excellent"), (0.75, "good"), (0.5, "moderate"), (-math.inf, "poor"))  # Koo & Li 2016


# Direction of the significant pairwise differences as printed (Sec. 3.4, line 355): WAD higher than recovered and
# control; recovered lower than control.
PAIRWISE_DIRECTION = {"WAD - Recovered": 1, "WAD - Control": 1, "Recovered - Control": -1}


def _icc_class(x: float) -> str:
    return next(name for lo, name in ICC_CLASSES if x > lo)


def _ch3_caveats(ctx: Context) -> tuple[str, ...]:
    return ("synthetic",) if ctx.match["dataset"] == "SYNTHETIC" else ()


def _ch3_kind(ctx: Context) -> tuple[str, str]:
    if ctx.match["dataset"] == "SYNTHETIC":
        return CALIBRATED, ("SYNTHETIC cohort drawn to the printed Table 3.2 means/SDs and limits of agreement "
                            "(the thesis's participant data were never published): agreement shows the "
                            "calibration and the internal consistency of the printed statistics, not a replication")
    return INDEPENDENT, "measured cohort from config chapter3.data"


def _parse_p(text: str):
    """'p < 0.001' -> ('<', 0.001, half-unit); 'p = 0.03' -> ('=', 0.03, 0.005); 'n.s. ...' -> ('ns', nan, nan)."""
    text = str(text or "")
    if text.startswith("n.s."):
        return "ns", math.nan, math.nan
    m = re.match(r"p\s*([<=>])\s*([0-9.]+)", text)
    if not m:
        return "", math.nan, math.nan
    digits = m.group(2).split(".")[1] if "." in m.group(2) else ""
    return m.group(1), float(m.group(2)), 0.5 * 10 ** -len(digits)


def score_ch3_statistics(ctx: Context) -> list[dict]:
    df = _read(ctx.path)
    df = df[df["kind"] != "table_3_2"]  # Table 3.2 cells are scored from table_3_2.csv (with n)
    alpha = float(ctx.config.get("chapter3", {}).get("mixed_model", {}).get("alpha", 0.05))
    synth = _ch3_caveats(ctx)
    cal = ("calibrated",) if synth else ()
    kind, basis = _ch3_kind(ctx)
    src = "Sec. 3.4"
    half = ctx.tols["ci_print_half_unit"]
    kw = dict(kind=kind, basis=basis)
    rows = []
    for r in df.to_dict("records"):
        k = r["kind"]
        th, o = _num(r["thesis_value"]), _num(r["ours_value"])
        if k == "loa":
            lo, hi = _num(r["ours_ci_low"]), _num(r["ours_ci_high"])
            within = not math.isnan(o) and lo - half.value <= th <= hi + half.value
            rows.append(_row("Chapter 3", src, r["statistic"], _fmt(th), f"{_fmt(o, 3)} (95% CI {_fmt(lo, 3)}, "
                             f"{_fmt(hi, 3)})", o - th, within,
                             _tol_text(half, f"printed limit inside our 95% CI +- {half.value:g}"),
                             f"same sign: thesis {_sign(th, 0):+d}, ours {_sign(o, 0) if not math.isnan(o) else 0:+d}",
                             ("random",), ctx.rel, always=synth + cal, test="loa_sign", tv=th, ov=o,
                             aux=(0.0, math.nan), **kw))
        elif k == "icc":
            lo, hi = _num(r["thesis_ci_low"]), _num(r["thesis_ci_high"])
            within = not math.isnan(o) and lo - half.value <= o <= hi + half.value
            ct, co = _icc_class(th), (_icc_class(o) if not math.isnan(o) else "-")
            rows.append(_row("Chapter 3", src, r["statistic"], f"{_fmt(th)} (95% CI {_fmt(lo)}, {_fmt(hi)})",
                             f"{_fmt(o, 3)} (95% CI {_fmt(r['ours_ci_low'], 3)}, {_fmt(r['ours_ci_high'], 3)})",
                             o - th, within, _tol_text(half, f"ours inside the printed 95% CI +- {half.value:g}"),
                             f"same reliability class (Koo & Li 2016): thesis {ct}, ours {co}",
                             ("random",), ctx.rel, always=synth, test="icc_class", tv=th, ov=o, **kw))
        elif k == "f_test":
            t = ctx.tols["f_rel"]
            within = not math.isnan(o) and abs(o - th) <= t.value * abs(th)
            sig_t, sig_o = str(r["thesis_significant"]), str(r["ours_significant"])
            code = {"True": 1.0, "False": 0.0}
            rows.append(_row("Chapter 3", src, r["statistic"], f"F[{r['thesis_df']}] = {_fmt(th)}, {r['thesis_p']}",
                             f"F_wald[{r['ours_df']}] = {_fmt(o, 3)}, p = {_fmt(r['ours_p'], 2)}", o - th, within,
                             _tol_text(t, f"|d| <= {t.value:g} x F"),
                             f"same significance at alpha = {alpha:g}: thesis {sig_t}, ours {sig_o}",
                             ("random", "satterthwaite"), ctx.rel, always=synth, test="f_significance",
                             tv=code.get(sig_t, math.nan), ov=code.get(sig_o, math.nan), **kw))
        elif k == "pairwise":
            op, p, h = _parse_p(r["thesis_p"])
            p_o = _num(r["ours_p"])
            contrast = r["statistic"].split(" in ")[0].replace("pairwise ", "")
            want = PAIRWISE_DIRECTION.get(contrast, 0)
            dir_ok = want == 0 or (not math.isnan(o) and _sign(o, 0) == want)
            if op == "<":
                holds = p_o < p
            elif op == "=":
                holds = abs(p_o - p) <= h + 1e-12
            elif op == "ns":
                holds = p_o > alpha
            else:
                holds = False
            sig_t = op != "ns" and (op == "<" or p <= alpha)
            sig_o = p_o <= alpha
            within = holds and (dir_ok or op == "ns")
            # signed significance: +-1 significant in that direction, 0 not significant
            code_t = float(want if want else 1) if sig_t else 0.0
            code_o = float(_sign(o, 0) if not math.isnan(o) else 0) if sig_o else 0.0
            rows.append(_row("Chapter 3", src, r["statistic"], f"{r['thesis_p']}" + (
                f" ({'higher' if want > 0 else 'lower'})" if want and op != "ns" else ""),
                f"p = {_fmt(p_o, 2)} (difference {o:+.3f})", math.nan, within, _tol_text(ctx.tols["p_print"],
                "printed p statement holds, same direction"),
                f"same significance at alpha = {alpha:g} and direction: thesis {sig_t}, ours {sig_o}"
                + ("" if dir_ok else " (direction reversed)"),
                ("random", "satterthwaite"), ctx.rel, always=synth, test="pairwise_significance", tv=code_t,
                ov=code_o, **kw))
    return rows


def score_table_3_2(ctx: Context) -> list[dict]:
    df = _read(ctx.path)
    df = df[df["thesis_mean"].notna()]
    t = ctx.tols["sampling_z"]
    synth = _ch3_caveats(ctx)
    cal = ("calibrated",) if synth else ()
    kind, basis = _ch3_kind(ctx)
    rows = []
    for stat in ("mean", "sd"):
        for i, r in df.iterrows():
            n = int(r["n"])
            sd = float(r["thesis_sd"])
            se = sd / math.sqrt(n) if stat == "mean" else sd / math.sqrt(2 * (n - 1))
            th, o = float(r[f"thesis_{stat}"]), float(r[f"mfi_{stat}"])
            within = abs(o - th) <= t.value * se
            rows.append(_row("Chapter 3", "Table 3.2", f"{r['level']} {r['quartile']} {r['group']} MFI {stat}",
                             _fmt(th), _fmt(o, 3), o - th, within,
                             _tol_text(t, f"|d| <= {t.value:g} SE = {t.value * se:.3g} (n = {n})"),
                             f"same rank of {r['group']} among the 3 groups at {r['level']} {r['quartile']}",
                             ("random",), ctx.rel, always=synth + cal, kind=kind, basis=basis,
                             test="table_3_2_rank", tv=th, ov=o, stratum=f"{stat}|{r['level']}|{r['quartile']}"))
    return rows


def score_ch4_claims(ctx: Context) -> list[dict]:
    df = _read(ctx.path)
    c4 = ctx.config.get("chapter4", {})
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
                         _tol_text(t, f"claim check (relative tolerance {c4.get('claim_tolerance_rel', '')}, anterior "
                                      f"|azimuth| < {c4.get('anterior_max_azimuth_deg', '')} deg)"),
                         str(r["numbers"]), ("geometry", "grouping") if "sagittal" in str(r["variants"])
                         else ("geometry",), ctx.rel,
                         basis="computed on the model's strength surfaces; nothing fitted to the claim"))
    return rows


def _baseline(df: pd.DataFrame, ctx: Context, model: str | None, thesis_table: str | None) -> dict:
    """Printed f_a of the unweakened simulated set ('norm' or 'Sim'), for the Table 5.1 caption claim: from the
    comparison table, else from the thesis table. Raises when neither can be read (the caller turns that into a
    'not evaluated' item with the error as its reason)."""
    fa = df[df["quantity"] == "f_a"]
    for ds in ("norm", "Sim"):
        sub = fa[fa["dataset"] == ds]
        if len(sub):
            return dict(zip(sub["muscle"], sub["thesis"].astype(float)))
    from neckstrength.estimation.datasets import thesis_result_table

    t = thesis_result_table(ctx.config["data"]["thesis_dir"], model or "p2m7", thesis_table)
    t = t[(t["quantity"] == "f_a") & t["dataset"].isin(["norm", "Sim"])]
    return dict(zip(t["group"], t["value_numeric"].astype(float)))


def _printed_group_strengths(ctx: Context, model: str | None) -> dict:
    """f_base: the printed baseline group strengths of the model (Table B.3/B.5/B.7; spatial groups by their right
    side), the baseline the thesis bootstraps its prior from (Sec. 5.2.2.1, 6.2)."""
    if model not in B_FILES:
        return {}
    path = Path(ctx.config.get("data", {}).get("thesis_dir", "data/thesis")) / B_FILES[model]
    if not path.exists():
        return {}
    t = _read(path)
    out = {}
    for r in t.to_dict("records"):
        g = str(r["group"])
        if g.endswith("-L"):
            continue
        out[re.sub(r"-R$", "", g)] = _num(r["strength_N"])
    return out


def _spearman_perm(a: np.ndarray, b: np.ndarray, seed: int, n: int = N_PERMUTATIONS) -> tuple[float, float]:
    """Spearman rank correlation and its one-sided permutation p-value (share of permutations at least as high)."""
    from scipy.stats import rankdata

    ok = ~np.isnan(a) & ~np.isnan(b)
    a, b = rankdata(a[ok]), rankdata(b[ok])
    if len(a) < 3:
        return math.nan, math.nan
    rho = float(np.corrcoef(a, b)[0, 1])
    rng = np.random.default_rng(seed)
    hits = sum(float(np.corrcoef(a, rng.permutation(b))[0, 1]) >= rho - 1e-12 for _ in range(n))
    return rho, (hits + 1) / (n + 1)


def _score_estimates(ctx: Context, chapter: str, source: str, model: str | None,
                     thesis_table: str | None) -> list[dict]:
    df = _read(ctx.path)
    tc, tab = (ctx.tols[k] for k in ("estimate_rel", "identified_sigma"))
    eps_d = float(ctx.config.get("chapter5", {}).get("eps_D", 0.95))
    clip = [float(x) for x in ctx.config.get("chapter5", {}).get("sigma_clip", SIGMA_CLIP)]
    thesis_col = "thesis" if "thesis" in df.columns else "thesis_value"
    ours_col = "ours" if "ours" in df.columns else "ours_value"
    if thesis_col not in df.columns or ours_col not in df.columns:
        raise ValueError(f"{ctx.rel}: a comparison table needs columns 'thesis' and 'ours' (has {list(df.columns)})")
    for c in ("dataset", "quantity", "muscle"):
        if c not in df.columns:
            df[c] = ""
    df["muscle"] = df["muscle"].astype(object).fillna("")
    df["_t"] = pd.to_numeric(df[thesis_col], errors="coerce")
    df["_o"] = pd.to_numeric(df[ours_col], errors="coerce")
    df = df[df["_t"].notna()].copy()  # only cells the thesis prints (e.g. Table 6.1 has no 'norm'/'weak' rows)
    f_base = _printed_group_strengths(ctx, model)
    simulated = set(df.loc[df["quantity"] == "f_a", "dataset"])
    fa = {(r["dataset"], r["muscle"]): r["_t"] for r in df[df["quantity"] == "f_a"].to_dict("records")}
    fc = {(r["dataset"], r["muscle"]): (r["_t"], r["_o"]) for r in df[df["quantity"] == "f_c"].to_dict("records")}
    seed = int(ctx.config.get("seed", 0) or 0)
    rank_text: dict = {}

    def participant_rank(ds):  # Spearman of f_c / f_base across the data set's groups, permutation p-value
        if ds not in rank_text:
            ms = [m for (d, m) in fc if d == ds and m in f_base and f_base[m] > 0]
            a = np.array([fc[(ds, m)][0] / f_base[m] for m in ms])
            b = np.array([fc[(ds, m)][1] / f_base[m] for m in ms])
            rho, p = _spearman_perm(a, b, seed + zlib.crc32(f"{ctx.rel}|{ds}".encode()) % 10_000)
            rank_text[ds] = f"; across the {len(ms)} groups of {ds}: Spearman rho {rho:.2f}, permutation p {p:.3f}"
        return rank_text[ds]

    rows = []
    for r in df.to_dict("records"):
        ds, q, m, th, o = r["dataset"], r["quantity"], r["muscle"], r["_t"], r["_o"]
        if q == "f_a":
            continue  # simulated 'actual' strengths are inputs, taken from the printed table
        note = str(r.get("note", "") if not pd.isna(r.get("note", "")) else "")
        d = o - th
        reasons = ["random", "q"] + (["geometry"] if ds not in simulated else [])
        label = f"{ds}: {m + ' ' if m else ''}{q}"
        basis = ("estimate from data simulated with the printed f_a (an input, not scored)" if ds in simulated
                 else "estimate from the participant's printed forces (Table A.2, an input)")
        test, tv, ov, aux, stratum = "", math.nan, math.nan, (math.nan, math.nan), ds
        th_txt = _fmt(th)
        kind = INDEPENDENT
        if q == "f_c":
            tol = max(0.5, tc.value * abs(th))
            within = abs(d) <= tol
            if ds in simulated and (ds, m) in fa:
                f_true = fa[(ds, m)]

                def cls(x):
                    return "recovers f_a" if abs(x - f_true) <= tc.value * f_true else (
                        "above f_a" if x > f_true else "below f_a")
                concl = f"same recovery of f_a = {f_true:g} N (within {tc.value:.0%}): thesis {cls(th)}, ours {cls(o)}"
                test, tv, ov, aux = "recovers_f_a", th, o, (f_true, tc.value)
            elif m in f_base and f_base[m] > 0:
                concl = (f"same rank of f_c / f_base (printed baseline {f_base[m]:g} N) among the groups of {ds}"
                         + participant_rank(ds))
                test, tv, ov = "relative_strength_rank", th / f_base[m], o / f_base[m]
            else:
                concl = "no baseline strength for this group: conclusion not available"
            tol_txt = _tol_text(tc, f"|d| <= max(0.5 N, {tc.value:g} x thesis) = {tol:.3g} N")
            label += " (N)"
        elif q in ("sigma_c", "v_c"):
            if q == "sigma_c":
                t = ctx.tols["sigma_c_abs"]
                tol = t.value
                tol_txt = _tol_text(t, f"|d| <= {tol:g}")
                s_t, s_o = th, o
            else:
                rel = (1 + tc.value) ** 2 - 1
                tol = max(0.5, rel * abs(th))
                tol_txt = _tol_text(tc, f"|d| <= max(0.5, {rel:.2f} x thesis) = {tol:.3g} N^2")
                f_t, f_o = fc.get((ds, m), (math.nan, math.nan))
                s_t = math.sqrt(th) / f_t if th >= 0 and f_t > 0 else math.nan
                s_o = math.sqrt(o) / f_o if o >= 0 and f_o > 0 else math.nan
                label += " (N^2)"
            within = abs(d) <= tol
            lim = _at_clip_limit(th, o, clip) if q == "sigma_c" else None
            if lim is not None:
                kind = BY_CONSTRUCTION
                basis += (f"; both runs at the sigma_c clip limit {lim:g} (chapter5.sigma_clip, Sec. 5.2.2.7): any "
                          "run that reaches the limit matches, so the agreement is by construction")
            cls = lambda s: "-" if math.isnan(s) else ("identified" if s < tab.value else "uncertain")  # noqa: E731
            concl = f"same identification (relative spread < {tab.value:g}): thesis {cls(s_t)}, ours {cls(s_o)}"
            test, tv, ov, aux, stratum = "identification", s_t, s_o, (tab.value, math.nan), q
        elif q == "D_fc":
            t, band = ctx.tols["D_fc_abs"], ctx.tols["D_fc_band"].value
            within = abs(d) <= t.value
            tol_txt = _tol_text(t, f"|d| <= {t.value:g}")
            if ds in simulated and min(th, o) >= 1.0 - t.value:
                kind = BY_CONSTRUCTION
                basis += (f"; noise-free simulated data: the printed f_a fits them exactly (D = 1), and both runs sit "
                          f"at that ceiling (D(f_c) >= {1.0 - t.value:g}), so the agreement is by construction")
            concl = (f"same fit: |d| <= {band:g} or both >= eps_D = {eps_d:g} (thesis {th:.2f}, ours {o:.2f})")
            test, tv, ov, aux, stratum = "D_fc_same_fit", th, o, (band, eps_d), ""
        elif q == "iters":
            t = ctx.tols["iters_rel"]
            cens_t = "thesis did not converge" in note
            cens_o = "ours did not converge" in note
            if cens_t or cens_o:
                # censored: '30+' is the statement 'did not converge within maxIter'
                within = cens_t and cens_o and o >= th
                tol_txt = _tol_text(t, "censored: matches only if both stopped at maxIter without converging")
                if cens_t and cens_o:
                    kind = BY_CONSTRUCTION
                    basis += ("; both runs stopped at maxIter without converging, and our maxIter is copied from "
                              "the thesis (chapter5.settings), so the counts agree by construction; the "
                              "convergence itself is the conclusion column")
            else:
                tol = max(1.0, t.value * abs(th))
                within = abs(d) <= tol
                tol_txt = _tol_text(t, f"|d| <= max(1, {t.value:g} x thesis) = {tol:.3g} (both converged)")
            ct = "did not converge" if cens_t else "converged"
            co = "did not converge" if cens_o else "converged"
            concl = f"same convergence: thesis {ct}, ours {co}"
            test, tv, ov, stratum = "convergence", float(not cens_t), float(not cens_o), ""
            th_txt = f"{_fmt(th)}+" if cens_t else _fmt(th)
            o_txt = f"{_fmt(o, 4)}+" if cens_o else _fmt(o, 4)
        else:  # any other printed quantity: relative tolerance only
            tol = tc.value * abs(th)
            within = abs(d) <= tol
            tol_txt = _tol_text(tc, f"|d| <= {tc.value:g} x thesis")
            concl = "no conclusion test defined for this quantity"
        ours_txt = o_txt if q == "iters" else _fmt(o, 4)
        rows.append(_row(chapter, source, label, th_txt, ours_txt, d, within, tol_txt, concl, reasons, ctx.rel,
                         kind=kind, basis=basis, test=test, tv=tv, ov=ov, aux=aux, stratum=stratum))
    return rows


# sigma_c clip limits of Sec. 5.2.2.7 (config chapter5.sigma_clip)
SIGMA_CLIP = (0.01, 0.3)


def _at_clip_limit(thesis: float, ours: float, clip: Sequence[float]) -> float | None:
    """The clip limit both sigma_c values sit at (the printed one within half a unit of its 0.01 print, ours to
    1e-6), or None."""
    for lim in clip:
        if abs(thesis - lim) <= 0.005 + 1e-12 and abs(ours - lim) <= 1e-6 * max(1.0, abs(lim)):
            return float(lim)
    return None


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


def score_ch6(ctx: Context) -> list[dict]:
    return _score_estimates(ctx, "Chapter 6", "Table 6.1 (p2m7)", "p2m7", "table_6_1_p2m7_sequential.csv")


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


def _finalize(df: pd.DataFrame, tols: Mapping[str, Tolerance], seed: int) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Chance rate of every conclusion test on these rows, then each row's verdict, conclusion note and reason."""
    cmax = tols["conclusion_chance_max"].value
    live = df[df["verdict"] != NOT_EVALUATED]
    chance = chance_rates(live, seed)
    rate = dict(zip(chance["test"], chance["chance_rate"]))
    verdicts, notes, reasons, rates = [], [], [], []
    for r in df.to_dict("records"):
        if r["verdict"] == NOT_EVALUATED:
            verdicts.append(NOT_EVALUATED), notes.append(r["conclusion"]), reasons.append(r["reason"])
            rates.append(math.nan)
            continue
        key = r["_test"]
        c = rate.get(key, math.nan) if key else math.nan
        usable = bool(key) and not math.isnan(c) and c <= cmax
        same = usable and bool(r["_agree"])
        v = MATCHES if r["_within"] else (SAME_CONCLUSION if same else DIFFERS)
        note = r["conclusion"]
        if key:
            note += (f" [chance rate {c:.2f}]" if usable else
                     f" [not a conclusion test here: chance rate {c:.2f} > {cmax:g}; the row can only match or differ]")
        always = (("construction",) if r["kind"] == BY_CONSTRUCTION else ()) + tuple(r["_always"])
        verdicts.append(v), notes.append(note), reasons.append(_reason(v, r["_codes"], always)), rates.append(c)
    df = df.assign(verdict=verdicts, conclusion=notes, reason=reasons, chance_rate=rates)
    return df, chance


def _agreement(df: pd.DataFrame) -> pd.Series:
    """Observed agreement of each row's conclusion test (vectorised per test: ranks need the whole stratum)."""
    out = pd.Series(False, index=df.index)
    for key in CONCLUSION_TESTS:
        sub = df[(df["_test"] == key) & (df["verdict"] != NOT_EVALUATED)]
        if len(sub):
            ok = CONCLUSION_TESTS[key].agree(sub["_tv"].to_numpy(float), sub["_ov"].to_numpy(float),
                                             sub[["_aux0", "_aux1"]].to_numpy(float),
                                             sub["_stratum"].astype(str).to_numpy())
            out[sub.index] = ok
    return out


def build_scorecard(paths: Iterable[str], config: Mapping,
                    overrides: Mapping[str, float] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Score every registered comparison table among ``paths``.

    Returns ``(scorecard, not_evaluated)``: scored rows (verdict in :data:`VERDICTS`, kind in :data:`KINDS`) and the
    items this configuration could not evaluate. ``scorecard.attrs["chance"]`` holds the chance rate of every
    conclusion test (:func:`chance_rates`), for :func:`tolerance_table`.
    """
    tols = tolerances(overrides)
    rows: list[dict] = []
    for p in paths:
        hit = source_for(str(p))
        if not hit:
            continue
        s, m = hit
        rows += s.loader(Context(config=config, tols=tols, match=m, path=Path(p), rel=str(p)))
    return score_rows(rows, config, overrides)


def score_rows(rows: Sequence[dict], config: Mapping,
               overrides: Mapping[str, float] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Verdicts of loader rows (:func:`_row`): chance rate of each conclusion test on these rows, then per row
    matches / same conclusion (only by a test whose chance rate is small) / differs."""
    tols = tolerances(overrides)
    df = pd.DataFrame(list(rows))
    if not len(df):
        empty = pd.DataFrame(columns=COLUMNS)
        empty.attrs["chance"] = chance_rates(pd.DataFrame(columns=["_test"]))
        return empty, empty.copy()
    df["_agree"] = _agreement(df)
    df, chance = _finalize(df, tols, int(config.get("seed", 0) or 0))
    order = {c: i for i, c in enumerate(CHAPTER_ORDER)}
    df["_o"] = df["chapter"].map(lambda c: order.get(c, len(order)))
    df = df.sort_values("_o", kind="stable").reset_index(drop=True)
    df = df[COLUMNS]
    skipped = df[df["verdict"] == NOT_EVALUATED].reset_index(drop=True)
    scored = df[df["verdict"] != NOT_EVALUATED].reset_index(drop=True)
    bad = set(scored["verdict"]) - set(VERDICTS)
    if bad:
        raise AssertionError(f"invalid verdicts {bad}")
    if set(scored["kind"]) - set(KINDS):
        raise AssertionError(f"invalid kinds {set(scored['kind']) - set(KINDS)}")
    scored.attrs["chance"] = chance
    return scored, skipped


SUMMARY_COLUMNS = ["chapter", "kind", "items", "matches", "same_conclusion", "differs", "not_evaluated"]


def summarize(scored: pd.DataFrame, skipped: pd.DataFrame | None = None) -> pd.DataFrame:
    """Counts per chapter, kind (independent, calibrated, by construction) and verdict, items not evaluated (on the
    chapter's independent row: claims this configuration cannot check and scorer errors), and totals per kind
    (chapter 'all'). Narrow on purpose (the report's front page shows it)."""
    skipped = skipped if skipped is not None else pd.DataFrame(columns=COLUMNS)
    chapters = [c for c in CHAPTER_ORDER if c in set(scored["chapter"]) | set(skipped["chapter"])]
    chapters += sorted((set(scored["chapter"]) | set(skipped["chapter"])) - set(chapters))
    rows = []
    for c in chapters + ["all"]:
        for kind in KINDS:
            sc = scored if c == "all" else scored[scored["chapter"] == c]
            sc = sc[sc["kind"] == kind]
            sk = skipped if c == "all" else skipped[skipped["chapter"] == c]
            counts = {v: int((sc["verdict"] == v).sum()) for v in VERDICTS}
            rows.append({"chapter": c, "kind": kind, "items": len(sc), "matches": counts[MATCHES],
                         "same_conclusion": counts[SAME_CONCLUSION], "differs": counts[DIFFERS],
                         "not_evaluated": len(sk) if kind == INDEPENDENT else 0})
    return pd.DataFrame(rows, columns=SUMMARY_COLUMNS)


def headline(summary: pd.DataFrame) -> str:
    """One sentence: independent counts first, calibrated and by-construction counts separately, then the items
    not evaluated. A summary without a kind's rows (written before that kind existed) counts it as zero."""
    s = summary.set_index(["chapter", "kind"])

    def part(kind):
        r = s.loc[("all", kind)] if ("all", kind) in s.index else dict.fromkeys(SUMMARY_COLUMNS[2:], 0)
        return (f"{int(r['items'])} {kind} items: {int(r['matches'])} match, {int(r['same_conclusion'])} same "
                f"conclusion, {int(r['differs'])} differ")
    n_ne = int(summary.loc[summary["chapter"] == "all", "not_evaluated"].sum())
    return (part(INDEPENDENT) + "; " + part(CALIBRATED) + " (calibrated: agreement shows the calibration); "
            + part(BY_CONSTRUCTION) + " (shown, never counted as reproduced); "
            + f"{n_ne} not evaluated")


def _source_family(source: str) -> str:
    """'Table B.3 (s3m24)' -> 'Table B.3'; 'Sec. 4.3.2' -> 'Sec. 4.3'."""
    s = re.sub(r"\s*\(.*\)$", "", source)
    return re.sub(r"^Sec\. (\d+\.\d+)\..*$", r"Sec. \1", s)


def header_lines(config: Mapping, tols: Mapping[str, Tolerance]) -> list[str]:
    over = [k for k, t in tols.items() if t.overridden]
    m = config.get("model", {})
    return ["thesis scorecard: every number the thesis prints that we reproduce, ours beside it "
            "(neckstrength.report.scorecard; tolerances, conclusion tests and chance rates: scorecard_tolerances.csv)",
            f"kinds: {' / '.join(KINDS)} (calibrated = an input was fitted or drawn to the thesis numbers that "
            f"determine this one; by construction = the agreement follows from the setup, shown but never counted "
            f"as reproduced); verdicts: {' / '.join(VERDICTS)}; difference = ours - thesis; seed "
            f"{config.get('seed')}",
            f"model.unprinted_strengths: {m.get('unprinted_strengths', 'b3_implied')}; model.grouping_supplements: "
            f"{m.get('grouping_supplements', True)}",
            "tolerance overrides from config report.tolerances: " + (", ".join(over) if over else "none")]
