"""Tolerances, verdicts, kinds and reasons of the thesis scorecard: every tolerance and conclusion threshold
with its reasoning (:data:`TOLERANCES`), and the small formatting helpers every scorer shares.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Mapping


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
