"""Linear mixed model of MFI (thesis Sec. 3.3.3) with statsmodels ``MixedLM``.

Data: the primary tracing (one rater, one trial) averaged over left and right
sides, one value per participant x level x quartile (the thesis's denominator
degrees of freedom, about 217 for 15 participants x 20 cells, fit this; sides are
not a factor of its model).

Fixed effects (REML)::

    mfi ~ group * quartile * level + level^2 + age + sex + BMI

i.e. group, quartile, level, group:quartile, quartile:level, group:level,
group:quartile:level (the "group * quartile + quartile * level + group * level +
group:quartile:level" of Sec. 3.3.3), the quadratic level term, and the
covariates.  group and quartile are factors with sum-to-zero (effect) coding, so
each term's Wald test is a type III test; level is numeric (C3..C7 -> 3..7)
centred at C5 (level_c = level - 5), as the 1- and 2-df level interactions of the
thesis's F tests require; sex enters as a numeric female indicator (SPSS
covariate); age and BMI are numeric.

Random effects per participant ("inter-subject differences in the change in MFI
across cervical level and across quartiles"): intercept and slopes over level_c
and quartile_c (quartile Q1..Q4 -> -1.5..1.5), unstructured covariance.  If that
fit does not converge to an interior solution, simpler structures are tried in the
order the config gives; every attempt is reported.

SPSS MIXED reports type III F tests with Satterthwaite denominator degrees of
freedom and t tests with Satterthwaite df for pairwise comparisons.  statsmodels
has no Satterthwaite (or Kenward-Roger) approximation for MixedLM, so this module
reports instead: Wald chi-square tests (``F_wald = chi2 / df`` is the statistic
SPSS calls F; its p-value here is from chi2(df), i.e. infinite denominator df) and
z tests for pairwise contrasts.  With few participants these p-values are smaller
(anti-conservative) than Satterthwaite ones.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
import pandas as pd
from scipy import stats

from neckstrength.mfi.schema import GROUPS, QUARTILES

SATTERTHWAITE_NOTE = ("SPSS reports F tests with Satterthwaite denominator df (fractional) and pairwise t tests "
                      "with Satterthwaite df; statsmodels MixedLM has no Satterthwaite or Kenward-Roger "
                      "approximation. Computed instead: Wald chi-square per term (F_wald = chi2/df, p from "
                      "chi2(df)) and Wald z tests for pairwise contrasts (Bonferroni-adjusted). These p-values are "
                      "asymptotic and smaller than small-sample ones.")


FIXED_FORMULA = "mfi ~ C(group, Sum) * C(quartile, Sum) * level_c + I(level_c ** 2) + age + female + bmi"


#: patsy factor code -> effect name used in outputs and in the thesis comparison
FACTOR_NAMES = {"C(group, Sum)": "group", "C(quartile, Sum)": "quartile", "level_c": "level",
                "I(level_c ** 2)": "level^2", "age": "age", "female": "sex", "bmi": "BMI"}


#: random-effect slope names -> model-frame columns
SLOPE_COLUMNS = {"level": "level_c", "quartile": "quartile_c"}


#: a random-effect variance below this fraction of the residual variance, or a random-effect correlation
#: matrix with an eigenvalue below it, counts as a fit on the boundary of the parameter space
BOUNDARY_TOL = 1e-3


PAIRS = (("WAD", "Recovered"), ("WAD", "Control"), ("Recovered", "Control"))


DEFAULT_RANDOM_EFFECTS = (
    {"slopes": ["level", "quartile"], "covariance": "unstructured"},
    {"slopes": ["level", "quartile"], "covariance": "diagonal"},
    {"slopes": ["level"], "covariance": "unstructured"},
    {"slopes": [], "covariance": "unstructured"},
)


def level_number(level: str) -> int:
    return int(str(level)[1:])


def model_frame(df: pd.DataFrame, rater: str, trial: int = 1) -> pd.DataFrame:
    """Primary tracing averaged over sides: one row per participant x level x quartile."""
    sel = df[(df["rater"] == rater) & (df["trial"] == trial)]
    if sel.empty:
        raise ValueError(f"no measurements by rater '{rater}' trial {trial} in the data "
                         f"(raters: {sorted(df['rater'].unique())}, trials: {sorted(df['trial'].unique())})")
    keys = ["participant", "group", "sex", "age", "bmi", "level", "quartile"]
    m = sel.groupby(keys, as_index=False, dropna=False)["mfi"].mean()
    m["group"] = pd.Categorical(m["group"], categories=list(GROUPS))
    m["quartile"] = pd.Categorical(m["quartile"], categories=list(QUARTILES))
    m["level_c"] = m["level"].map(level_number).astype(float) - 5.0
    m["quartile_c"] = m["quartile"].cat.codes.astype(float) - 1.5
    m["female"] = (m["sex"] == "F").astype(float)
    missing = [g for g in GROUPS if g not in set(m["group"])]
    if missing:
        raise ValueError(f"the mixed model needs all three groups; missing: {missing}")
    return m.reset_index(drop=True)


@dataclass
class MixedFit:
    """A fitted model with what was tried."""

    result: object                       # statsmodels MixedLMResults
    frame: pd.DataFrame
    random_effects: Mapping
    attempts: pd.DataFrame
    fe_names: list[str] = field(default_factory=list)

    @property
    def fe_params(self) -> np.ndarray:
        return np.asarray(self.result.fe_params, float)

    @property
    def fe_cov(self) -> np.ndarray:
        k = len(self.fe_names)
        return np.asarray(self.result.cov_params(), float)[:k, :k]


def _re_label(spec: Mapping) -> str:
    slopes = list(spec.get("slopes", []))
    s = "intercept" + "".join(f" + {x} slope" for x in slopes)
    return s + (f" ({spec.get('covariance', 'unstructured')})" if slopes else "")


def fit_mixed_model(frame: pd.DataFrame, random_effects: Sequence[Mapping] = DEFAULT_RANDOM_EFFECTS,
                    reml: bool = True) -> MixedFit:
    """Fit the Sec. 3.3.3 model, trying the random-effect structures in order.

    A fit is accepted when statsmodels reports convergence without a warning, all
    fixed-effect standard errors are finite and the random-effect covariance is not
    on the boundary: every variance above ``BOUNDARY_TOL`` x the residual variance
    and no eigenvalue of the random-effect correlation matrix below ``BOUNDARY_TOL``.
    If none qualifies, the last structure that produced finite standard errors is
    used and flagged in ``attempts``.
    """
    import statsmodels.formula.api as smf

    rows, chosen, fallback = [], None, None
    for spec in random_effects:
        slopes = [SLOPE_COLUMNS[s] for s in spec.get("slopes", [])]
        re_formula = "~" + " + ".join(["1"] + slopes)
        model = smf.mixedlm(FIXED_FORMULA, frame, groups=frame["participant"], re_formula=re_formula)
        fit_kw = {"reml": reml}
        if slopes and spec.get("covariance", "unstructured") == "diagonal":
            from statsmodels.regression.mixed_linear_model import MixedLMParams
            k_fe, k_re = model.k_fe, model.k_re
            fit_kw["free"] = MixedLMParams.from_components(np.ones(k_fe), np.eye(k_re))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                res = model.fit(**fit_kw)
                err = ""
            except Exception as exc:  # singular matrices etc.: record and try the next structure
                res, err = None, f"{type(exc).__name__}: {exc}"
        # statsmodels warns "MLE may be on the boundary" whenever a random-effect variance is below 0.01 in
        # absolute terms, which every MFI variance (~1e-3) is; that heuristic is replaced by the relative
        # checks below (variance / residual variance and the random-effect correlation matrix).
        msgs = sorted({str(w.message).split("\n")[0] for w in caught
                       if not str(w.message).startswith("The MLE may be on the boundary")})
        row = {"random_effects": _re_label(spec), "re_formula": re_formula, "error": err,
               "warnings": " | ".join(msgs), "converged": False, "min_re_variance_ratio": np.nan,
               "min_re_corr_eigenvalue": np.nan, "loglik_reml": np.nan, "accepted": False}
        if res is not None:
            cov_re = np.atleast_2d(np.asarray(res.cov_re, float))
            var = np.diag(cov_re)
            ratio = float(var.min() / res.scale)
            corr = cov_re / np.sqrt(np.outer(var, var)) if np.all(var > 0) else np.full_like(cov_re, np.nan)
            eig = float(np.linalg.eigvalsh(corr).min()) if np.all(np.isfinite(corr)) else np.nan
            finite = bool(np.all(np.isfinite(np.asarray(res.bse_fe, float))))
            row.update(converged=bool(res.converged), min_re_variance_ratio=ratio, min_re_corr_eigenvalue=eig,
                       loglik_reml=float(res.llf))
            ok = (res.converged and not msgs and finite and ratio > BOUNDARY_TOL and eig > BOUNDARY_TOL)
            row["accepted"] = bool(ok and chosen is None)
            if ok and chosen is None:
                chosen = (res, spec)
            if finite:
                fallback = (res, spec)
        rows.append(row)
        if chosen is not None:
            break
    attempts = pd.DataFrame(rows)
    if chosen is None:
        if fallback is None:
            raise RuntimeError("no mixed model could be fitted:\n" + attempts.to_string())
        chosen = fallback
        idx = attempts.index[attempts["random_effects"] == _re_label(chosen[1])][-1]
        attempts.loc[idx, "accepted"] = True
        attempts.loc[idx, "warnings"] += " | USED ALTHOUGH NOT CLEANLY CONVERGED (no structure qualified)"
    res, spec = chosen
    return MixedFit(res, frame, dict(spec), attempts, list(res.model.exog_names[:res.k_fe]))


def _design_info(fit: MixedFit):
    """The patsy DesignInfo of the fixed effects (statsmodels >= 0.15 keeps it as ``data.model_spec``)."""
    data = fit.result.model.data
    di = getattr(data, "design_info", None) or getattr(data, "model_spec", None)
    if di is None or not hasattr(di, "term_slices"):
        raise RuntimeError("statsmodels did not keep a patsy DesignInfo for the fixed effects; "
                           "set statsmodels.formula.options.formula_engine = 'patsy'")
    return di


def _term_label(term) -> str:
    return ":".join(FACTOR_NAMES.get(f.name(), f.name()) for f in term.factors) or "intercept"


def wald_tests(fit: MixedFit) -> pd.DataFrame:
    """Wald chi-square test of every fixed-effect term (type III with sum coding)."""
    di = _design_info(fit)
    b, V = fit.fe_params, fit.fe_cov
    rows = []
    for term, sl in di.term_slices.items():
        label = _term_label(term)
        if label == "intercept":
            continue
        idx = np.arange(len(b))[sl]
        bb = b[idx]
        chi2 = float(bb @ np.linalg.solve(V[np.ix_(idx, idx)], bb))
        df = len(idx)
        rows.append({"effect": label, "df": df, "chi2": chi2, "F_wald": chi2 / df,
                     "p_chi2": float(stats.chi2.sf(chi2, df))})
    return pd.DataFrame(rows)


def _design_rows(fit: MixedFit, newdata: pd.DataFrame) -> np.ndarray:
    from patsy import build_design_matrices

    nd = newdata.copy()
    nd["group"] = pd.Categorical(nd["group"], categories=list(GROUPS))
    nd["quartile"] = pd.Categorical(nd["quartile"], categories=list(QUARTILES))
    (X,) = build_design_matrices([_design_info(fit)], nd, return_type="matrix")
    return np.asarray(X, float)


def emm_covariates(fit: MixedFit, age: float, bmi: float, level: str, female: float | None = None) -> dict:
    """Covariate values of the estimated marginal means (female = sample share of women if None)."""
    if female is None:
        per_participant = fit.frame.drop_duplicates("participant")
        female = float(per_participant["female"].mean())
    return {"age": float(age), "bmi": float(bmi), "level_c": float(level_number(level) - 5), "female": female}


def estimated_marginal_means(fit: MixedFit, covariates: Mapping, confidence: float = 0.95) -> pd.DataFrame:
    """Model-predicted mean MFI per group x quartile at fixed covariates (Fig. 3.3)."""
    grid = pd.DataFrame([{"group": g, "quartile": q, **covariates} for q in QUARTILES for g in GROUPS])
    X = _design_rows(fit, grid)
    est = X @ fit.fe_params
    se = np.sqrt(np.einsum("ij,jk,ik->i", X, fit.fe_cov, X))
    z = stats.norm.ppf(0.5 + confidence / 2)
    out = grid[["group", "quartile"]].copy()
    out["emm"], out["se"], out["ci_low"], out["ci_high"] = est, se, est - z * se, est + z * se
    return out


def pairwise_group_comparisons(fit: MixedFit, covariates: Mapping, pairs=PAIRS) -> pd.DataFrame:
    """Between-group contrasts of the EMMs within each quartile, Wald z tests, Bonferroni over the pairs."""
    rows = []
    for q in QUARTILES:
        grid = pd.DataFrame([{"group": g, "quartile": q, **covariates} for g in GROUPS])
        X = dict(zip(GROUPS, _design_rows(fit, grid)))
        for g1, g2 in pairs:
            c = X[g1] - X[g2]
            diff = float(c @ fit.fe_params)
            se = float(np.sqrt(c @ fit.fe_cov @ c))
            z = diff / se
            p = float(2 * stats.norm.sf(abs(z)))
            rows.append({"quartile": q, "contrast": f"{g1} - {g2}", "group_1": g1, "group_2": g2,
                         "difference": diff, "se": se, "z": z, "p": p,
                         "p_bonferroni": min(1.0, p * len(pairs)), "n_comparisons": len(pairs)})
    return pd.DataFrame(rows)


def fixed_effects_table(fit: MixedFit) -> pd.DataFrame:
    b = fit.fe_params
    se = np.sqrt(np.diag(fit.fe_cov))
    z = b / se
    return pd.DataFrame({"parameter": fit.fe_names, "estimate": b, "se": se, "z": z,
                         "p": 2 * stats.norm.sf(np.abs(z))})


def random_effects_table(fit: MixedFit) -> pd.DataFrame:
    """Random-effect covariance (per participant) and residual variance."""
    cov = pd.DataFrame(np.atleast_2d(np.asarray(fit.result.cov_re, float)))
    names = list(fit.result.cov_re.index) if hasattr(fit.result.cov_re, "index") else list(range(len(cov)))
    names = ["intercept" if n == "Group" else n for n in names]
    rows = []
    for i, a in enumerate(names):
        for j, b in enumerate(names):
            if j < i:
                continue
            rows.append({"component": "variance" if i == j else "covariance", "term_1": a, "term_2": b,
                         "value": float(cov.iloc[i, j])})
    rows.append({"component": "residual variance", "term_1": "", "term_2": "", "value": float(fit.result.scale)})
    return pd.DataFrame(rows)
