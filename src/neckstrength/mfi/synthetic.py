"""SYNTHETIC MFI cohort calibrated to thesis Tables 3.1 and 3.2 and to the reported rater agreement.

The per-participant data behind Chapter 3 were never published.  This module
draws a cohort in the schema of :mod:`neckstrength.mfi.schema` whose population
moments match what the thesis prints:

- Table 3.1: group size, number of females, age and BMI (mean, SD), NDI;
- Table 3.2: mean and SD of MFI per group x level x quartile (the SD is read as
  the between-participant SD of the side-averaged value, n = 5 per group), and the
  SD of the whole-ROI value, which fixes how strongly a participant's quartiles
  move together;
- Sec. 3.4: 95 % limits of agreement intra-rater (-0.04, 0.06) and inter-rater
  (-0.07, 0.07) of quartile MFI, on re-traced participants (4 WAD and 2 controls,
  Sec. 3.3.2).

Generative model for participant p of group g, level l, quartile q, side s
(one tracing by rater r, trial t)::

    T_plqs = m_glq + C_p + sqrt(R_glq) * ( sqrt(rho_gl) * S_plq
                                          + sqrt(1 - rho_gl) * (sqrt(1 - phi) e_plq + sqrt(2 phi) v_plqs) )
    y      = T_plqs + b_rt + eps (sd sigma_t) [+ u (sd sigma_B), rater B only]

- m_glq: Table 3.2 mean; C_p = beta . (x_p - mean_g(x)): covariates age, BMI and
  female sex, centred at the Table 3.1 group means, so the cell means stay m_glq;
- S_plq = (z0 + c_l lam(l) z1 + c_q kap(q) z2) / norm: participant random intercept
  and random slopes over level and quartile (standardised), unit variance;
- R_glq = s_glq^2 - var(C) - sigma_t^2 / 2 (floored at 0): what the Table 3.2 SD
  leaves for the random effects after covariates and tracing error;
- rho_gl: solved so that the SD of the whole-ROI value (mean of the 4 quartiles)
  equals Table 3.2's "Whole" SD at that group and level (clipped to [0, 1]);
- e, v, eps, u: independent standard normal / normal draws; phi: share of the
  residual that differs between left and right sides;
- b_rt, sigma_t, sigma_B: from the limits of agreement: intra differences (trial 1
  - trial 2) have mean (lo + hi) / 2 and SD (hi - lo) / (2 k), k = 1.96, so
  sigma_t = SD_intra / sqrt(2); inter differences (rater A - rater B, trial 1) get
  the extra rater-B term sigma_B^2 = SD_inter^2 - 2 sigma_t^2.

Covariate effects are not printed in the thesis (only F tests); the defaults in
the config are assumptions, documented there and in ``docs/chapter3.md``.
Every random draw comes from the ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from neckstrength.io import Column, Schema, read_table
from neckstrength.mfi.schema import GROUPS, LEVELS, QUARTILES, SIDES

SYNTHETIC_LABEL = "SYNTHETIC"


TABLE_3_1_SCHEMA = Schema(
    name="Table 3.1 demographics",
    columns=(Column("group", "str", choices=GROUPS), Column("n", "int", None, 1, None),
             Column("females", "int", None, 0, None),
             Column("age_mean", "float", "years", 0, 120), Column("age_sd", "float", "years", 0, 100),
             Column("bmi_mean", "float", "kg/m^2", 10, 80), Column("bmi_sd", "float", "kg/m^2", 0, 50),
             Column("ndi_mean", "float", None, 0, 100, allow_missing=True),
             Column("ndi_sd", "float", None, 0, 100, allow_missing=True)),
    unique=("group",),
)


TABLE_3_2_SCHEMA = Schema(
    name="Table 3.2 MFI by group, level and quartile",
    columns=(Column("level", "str", choices=LEVELS), Column("quartile", "str", choices=QUARTILES + ("Whole",)),
             Column("group", "str", choices=GROUPS), Column("mfi_mean", "float", None, 0, 1),
             Column("mfi_sd", "float", None, 0, 1)),
)


@dataclass(frozen=True)
class Targets:
    """Calibration targets: Table 3.1 (indexed by group) and Table 3.2 (indexed by level, quartile, group)."""

    demographics: pd.DataFrame
    mfi: pd.DataFrame

    def mean(self, g: str, lvl: str, q: str) -> float:
        return float(self.mfi.loc[(lvl, q, g), "mfi_mean"])

    def sd(self, g: str, lvl: str, q: str) -> float:
        return float(self.mfi.loc[(lvl, q, g), "mfi_sd"])


def load_targets(thesis_dir: str | Path) -> Targets:
    """Tables 3.1 and 3.2 as transcribed in ``data/thesis`` (validated)."""
    d = Path(thesis_dir)
    t1 = read_table(d / "table_3_1_demographics.csv", TABLE_3_1_SCHEMA).set_index("group")
    t2 = read_table(d / "table_3_2_mfi.csv", TABLE_3_2_SCHEMA).set_index(["level", "quartile", "group"])
    return Targets(t1, t2)


@dataclass(frozen=True)
class CohortSpec:
    """Design and generative assumptions of the synthetic cohort (config ``chapter3.synthetic``, built by
    :func:`neckstrength.config.cohort_spec`)."""

    n_per_group: int = 5                                   # Table 3.1: n = 5 per group
    reliability_participants: Mapping[str, int] = field(default_factory=lambda: {"WAD": 4, "Control": 2})
    age_per_year: float = 0.0005                           # MFI per year of age (assumption)
    bmi_per_unit: float = 0.005                            # MFI per kg/m^2 (assumption)
    female: float = 0.02                                   # MFI female - male (assumption)
    level_slope: float = 0.3                               # SD of random level slope / SD of intercept
    quartile_slope: float = 0.3                            # SD of random quartile slope / SD of intercept
    side_share: float = 0.25                               # share of the residual that differs L vs R
    intra_loa: tuple[float, float] = (-0.04, 0.06)         # Sec. 3.4
    inter_loa: tuple[float, float] = (-0.07, 0.07)         # Sec. 3.4
    loa_multiplier: float = 1.96
    rater: str = "A"                                       # primary rater (traced everyone, trials 1 and 2)
    second_rater: str = "B"                                # second rater (re-traced, trial 1)
    age_range: tuple[float, float] = (18.0, 70.0)          # draws clipped to this range
    bmi_range: tuple[float, float] = (16.0, 50.0)
    mfi_range: tuple[float, float] = (0.005, 0.995)        # MFI draws clipped to this range

    # rater-error parameters implied by the limits of agreement
    @property
    def intra_bias(self) -> float:
        return 0.5 * (self.intra_loa[0] + self.intra_loa[1])

    @property
    def intra_sd(self) -> float:
        return (self.intra_loa[1] - self.intra_loa[0]) / (2 * self.loa_multiplier)

    @property
    def inter_bias(self) -> float:
        return 0.5 * (self.inter_loa[0] + self.inter_loa[1])

    @property
    def inter_sd(self) -> float:
        return (self.inter_loa[1] - self.inter_loa[0]) / (2 * self.loa_multiplier)

    @property
    def tracing_sd(self) -> float:
        """SD of one tracing's error (sigma_t): intra differences have SD sqrt(2) sigma_t."""
        return self.intra_sd / np.sqrt(2.0)

    @property
    def second_rater_sd(self) -> float:
        """Extra rater-B error sigma_B so that inter differences have SD ``inter_sd``."""
        return float(np.sqrt(max(self.inter_sd ** 2 - 2 * self.tracing_sd ** 2, 0.0)))


def _lam(level: str) -> float:
    """Standardised level (C3..C7 -> -sqrt2..sqrt2, unit mean square)."""
    return (int(level[1]) - 5) / np.sqrt(2.0)


def _kap(quartile: str) -> float:
    """Standardised quartile (Q1..Q4 -> unit mean square)."""
    return (int(quartile[1]) - 2.5) / np.sqrt(1.25)


def _female_share(t1: pd.DataFrame, g: str) -> float:
    return float(t1.loc[g, "females"]) / float(t1.loc[g, "n"])


def covariate_variance(targets: Targets, spec: CohortSpec, g: str) -> float:
    """Population variance of the covariate part C_p in group g."""
    t = targets.demographics
    f = _female_share(t, g)
    return float(spec.age_per_year ** 2 * t.loc[g, "age_sd"] ** 2 + spec.bmi_per_unit ** 2 * t.loc[g, "bmi_sd"] ** 2
                 + spec.female ** 2 * f * (1 - f))


def _shared_corr(spec: CohortSpec, level: str) -> np.ndarray:
    """Correlation of S_plq between the quartiles of one level (4 x 4)."""
    cl, cq, lam = spec.level_slope, spec.quartile_slope, _lam(level)
    kap = np.array([_kap(q) for q in QUARTILES])
    norm = np.sqrt(1 + cl ** 2 * lam ** 2 + cq ** 2 * kap ** 2)
    cov = 1 + cl ** 2 * lam ** 2 + cq ** 2 * np.outer(kap, kap)
    return cov / np.outer(norm, norm)


def cell_parameters(targets: Targets, spec: CohortSpec) -> pd.DataFrame:
    """Population parameters per group x level x quartile, and the calibration they achieve.

    Columns: group, level, quartile, target_mean, target_sd, R (random-effect variance),
    rho (share of R shared across the participant's quartiles), model_sd (population SD
    of the side-averaged value), floored (True where the target SD is smaller than
    covariates and tracing error alone allow).  Rows with quartile 'Whole' give the
    whole-ROI target and the population SD of the mean of the 4 quartiles.
    """
    st2 = spec.tracing_sd ** 2
    rows = []
    for g in GROUPS:
        vc = covariate_variance(targets, spec, g)
        for lvl in LEVELS:
            s = np.array([targets.sd(g, lvl, q) for q in QUARTILES])
            raw = s ** 2 - vc - st2 / 2
            R = np.maximum(raw, 0.0)
            K = _shared_corr(spec, lvl)
            sq = np.sqrt(np.outer(R, R))
            w_target = targets.sd(g, lvl, "Whole")
            base = vc + st2 / 8 + R.sum() / 16            # var(Whole) at rho = 0
            slope = ((sq * K).sum() - R.sum()) / 16        # d var(Whole) / d rho
            rho = float(np.clip((w_target ** 2 - base) / slope, 0.0, 1.0)) if slope > 0 else 1.0
            for k, q in enumerate(QUARTILES):
                rows.append({"group": g, "level": lvl, "quartile": q, "target_mean": targets.mean(g, lvl, q),
                             "target_sd": s[k], "R": R[k], "rho": rho,
                             "model_mean": targets.mean(g, lvl, q),
                             "model_sd": float(np.sqrt(vc + R[k] + st2 / 2)), "floored": bool(raw[k] < 0)})
            rows.append({"group": g, "level": lvl, "quartile": "Whole",
                         "target_mean": targets.mean(g, lvl, "Whole"), "target_sd": w_target, "R": np.nan,
                         "rho": rho, "model_mean": float(np.mean([targets.mean(g, lvl, q) for q in QUARTILES])),
                         "model_sd": float(np.sqrt(base + rho * slope)), "floored": False})
    return pd.DataFrame(rows)


def _participant_ids(g: str, n: int) -> list[str]:
    width = max(2, len(str(n)))
    return [f"SYN-{g[0]}{i + 1:0{width}d}" for i in range(n)]


def synthetic_cohort(targets: Targets, spec: CohortSpec, rng: np.random.Generator) -> pd.DataFrame:
    """Draw a SYNTHETIC cohort in the per-ROI schema (one row per tracing).

    Every participant is traced once by ``spec.rater`` (trial 1) on both sides at
    C3-C7, Q1-Q4.  The first ``reliability_participants[g]`` participants of group g
    are re-traced: by ``spec.rater`` again (trial 2, intra-rater) and by
    ``spec.second_rater`` (trial 1, inter-rater).
    """
    t1 = targets.demographics
    params = cell_parameters(targets, spec).set_index(["group", "level", "quartile"])
    nl, nq, ns = len(LEVELS), len(QUARTILES), len(SIDES)
    lam = np.array([_lam(lvl) for lvl in LEVELS])[:, None]
    kap = np.array([_kap(q) for q in QUARTILES])[None, :]
    cl, cq, phi = spec.level_slope, spec.quartile_slope, spec.side_share
    norm = np.sqrt(1 + cl ** 2 * lam ** 2 + cq ** 2 * kap ** 2)             # (nl, nq)
    frames = []
    for g in GROUPS:
        n = spec.n_per_group
        ids = _participant_ids(g, n)
        # covariates (Table 3.1)
        n_f = int(round(n * _female_share(t1, g)))
        female = rng.permutation(np.r_[np.ones(n_f, bool), np.zeros(n - n_f, bool)])
        age = np.clip(rng.normal(t1.loc[g, "age_mean"], t1.loc[g, "age_sd"], n), *spec.age_range)
        bmi = np.clip(rng.normal(t1.loc[g, "bmi_mean"], t1.loc[g, "bmi_sd"], n), *spec.bmi_range)
        if np.isnan(t1.loc[g, "ndi_mean"]):
            ndi = np.full(n, np.nan)
        else:
            ndi = np.round(np.clip(rng.normal(t1.loc[g, "ndi_mean"], t1.loc[g, "ndi_sd"], n), 0, 100), 0)
        cov = (spec.age_per_year * (age - t1.loc[g, "age_mean"]) + spec.bmi_per_unit * (bmi - t1.loc[g, "bmi_mean"])
               + spec.female * (female - _female_share(t1, g)))
        # random effects and residuals
        z = rng.standard_normal((n, 3))
        S = (z[:, 0, None, None] + cl * lam[None] * z[:, 1, None, None]
             + cq * kap[None] * z[:, 2, None, None]) / norm[None]              # (n, nl, nq)
        e = rng.standard_normal((n, nl, nq))
        v = rng.standard_normal((n, nl, nq, ns))
        m = np.array([[targets.mean(g, lvl, q) for q in QUARTILES] for lvl in LEVELS])
        R = np.array([[params.loc[(g, lvl, q), "R"] for q in QUARTILES] for lvl in LEVELS])
        rho = np.array([params.loc[(g, lvl, QUARTILES[0]), "rho"] for lvl in LEVELS])[:, None]
        shared = np.sqrt(rho) * S + np.sqrt(1 - rho) * np.sqrt(1 - phi) * e   # (n, nl, nq)
        T = (m[None, :, :, None] + cov[:, None, None, None]
             + np.sqrt(R)[None, :, :, None] * (shared[..., None] + np.sqrt(1 - rho)[None, :, :, None]
                                                * np.sqrt(2 * phi) * v))        # (n, nl, nq, ns)
        tracings = [(spec.rater, 1, np.ones(n, bool), 0.0, 0.0)]
        n_rel = int(spec.reliability_participants.get(g, 0))
        rel = np.arange(n) < min(n_rel, n)
        tracings.append((spec.rater, 2, rel, -spec.intra_bias, 0.0))
        tracings.append((spec.second_rater, 1, rel, -spec.inter_bias, spec.second_rater_sd))
        for rater, trial, who, bias, extra_sd in tracings:
            y = (T + bias + spec.tracing_sd * rng.standard_normal(T.shape)
                 + extra_sd * rng.standard_normal(T.shape))
            y = np.clip(y, *spec.mfi_range)
            for i in np.nonzero(who)[0]:
                for a, lvl in enumerate(LEVELS):
                    for b, q in enumerate(QUARTILES):
                        for c, s in enumerate(SIDES):
                            frames.append((ids[i], g, "F" if female[i] else "M", age[i], bmi[i], ndi[i], s, lvl,
                                           q, rater, trial, y[i, a, b, c]))
    df = pd.DataFrame(frames, columns=["participant", "group", "sex", "age", "bmi", "ndi", "side", "level",
                                       "quartile", "rater", "trial", "mfi"])
    df["age"] = df["age"].round(1)
    df["bmi"] = df["bmi"].round(2)
    df["mfi"] = df["mfi"].round(5)
    return df
