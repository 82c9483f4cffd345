"""Chapter 3 (MFI): schema validation, synthetic-cohort calibration, reliability on published reference data,
the mixed model, and the stages end to end on a thesis-sized synthetic cohort."""

from pathlib import Path

import numpy as np
import pandas as pd
from PIL import Image
import pytest
import yaml

from neckstrength.io import DataValidationError
from neckstrength.mfi import mixedmodel as mm
from neckstrength.mfi.reliability import bland_altman, icc, reliability_table
from neckstrength.mfi.schema import read_mfi, validate_mfi_frame
from neckstrength.mfi.synthetic import CohortSpec, cell_parameters, load_targets, synthetic_cohort
from neckstrength.mfi.tables import read_thesis_statistics, table_3_2

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).resolve().parents[1] / "data"
TARGETS = load_targets(ROOT / "data" / "thesis")
CFG = yaml.safe_load(open(ROOT / "config" / "config.yaml"))

HEADER = "participant,group,sex,age,bmi,ndi,side,level,quartile,rater,trial,mfi\n"
GOOD_ROWS = ["P01,WAD,F,31.0,28.2,44,L,C3,Q1,A,1,0.331", "P01,WAD,F,31.0,28.2,44,R,C3,Q1,A,1,0.302",
             "P02,Control,M,35.5,24.0,,L,C3,Q1,A,1,0.201"]


def write(tmp_path, rows, header=HEADER, comments=""):
    p = tmp_path / "mfi.csv"
    p.write_text(comments + header + "\n".join(rows) + "\n")
    return p


# --------------------------------------------------------------------------- schema

def test_good_file_loads(tmp_path):
    df = read_mfi(write(tmp_path, GOOD_ROWS, comments="# units: age=years; bmi=kg/m^2; ndi=%; mfi=1\n"))
    assert len(df) == 3 and df["mfi"].iloc[0] == 0.331
    assert np.isnan(df["ndi"].iloc[2])          # NDI blank for a control, as in Table 3.1


@pytest.mark.parametrize("row, field, problem", [
    ("P03,WAD,F,31.0,28.2,44,L,C3,Q1,A,1,1.3", "mfi", "out of range"),
    ("P03,WAD,F,31.0,28.2,44,L,C3,Q1,A,1,abc", "mfi", "not a number"),
    ("P03,Whiplash,F,31.0,28.2,44,L,C3,Q1,A,1,0.3", "group", "not one of"),
    ("P03,WAD,F,31.0,28.2,44,L,C2,Q1,A,1,0.3", "level", "not one of"),
    ("P03,WAD,F,31.0,28.2,44,L,C3,Q5,A,1,0.3", "quartile", "not one of"),
    ("P03,WAD,X,31.0,28.2,44,L,C3,Q1,A,1,0.3", "sex", "not one of"),
    ("P03,WAD,F,31.0,28.2,44,L,C3,Q1,A,1.5,0.3", "trial", "not an integer"),
    ("P03,WAD,F,31.0,,44,L,C3,Q1,A,1,0.3", "bmi", "missing value"),
])
def test_bad_value_names_file_row_line_and_field(tmp_path, row, field, problem):
    p = write(tmp_path, GOOD_ROWS + [row])
    with pytest.raises(DataValidationError) as e:
        read_mfi(p)
    msg = str(e.value)
    assert str(p) in msg and "row 4" in msg and "line 5" in msg and f"'{field}'" in msg and problem in msg
    assert e.value.row == 4 and e.value.field == field


def test_inconsistent_participant_attribute_names_row_and_field(tmp_path):
    p = write(tmp_path, GOOD_ROWS + ["P01,WAD,F,33.0,28.2,44,L,C4,Q1,A,1,0.3"])
    with pytest.raises(DataValidationError) as e:
        read_mfi(p)
    assert e.value.row == 4 and e.value.field == "age" and "row 1" in str(e.value) and str(p) in str(e.value)


def test_duplicate_measurement_rejected(tmp_path):
    p = write(tmp_path, GOOD_ROWS + ["P01,WAD,F,31.0,28.2,44,L,C3,Q1,A,1,0.35"])
    with pytest.raises(DataValidationError, match=r"row 4 \(line 5\).*duplicate measurement.*first at row 1"):
        read_mfi(p)


def test_missing_column_and_wrong_unit_rejected(tmp_path):
    p = write(tmp_path, [r.rsplit(",", 1)[0] for r in GOOD_ROWS], header=HEADER.replace(",mfi", ""))
    with pytest.raises(DataValidationError, match=r"field 'mfi': missing column"):
        read_mfi(p)
    p = write(tmp_path, GOOD_ROWS, comments="# units: mfi=%\n")
    with pytest.raises(DataValidationError, match=r"field 'mfi': declared unit '%'"):
        read_mfi(p)


# --------------------------------------------------------------------------- reliability: published references

def test_icc_reproduces_shrout_fleiss_1979():
    wide = pd.read_csv(DATA / "shrout_fleiss_1979.csv", comment="#")
    long = wide.melt(id_vars="target", var_name="judge", value_name="rating")
    res = icc(long, "target", "judge", "rating").set_index("form")
    published = {"ICC(1,1)": 0.17, "ICC(2,1)": 0.29, "ICC(3,1)": 0.71, "ICC(1,k)": 0.44, "ICC(2,k)": 0.62,
                 "ICC(3,k)": 0.91}
    for form, value in published.items():
        assert round(res.loc[form, "icc"], 2) == value, form
    # the CI is unrounded and brackets the estimate
    r = res.loc["ICC(2,1)"]
    assert r["ci_low"] < r["icc"] < r["ci_high"] and r["ci_low"] != round(r["ci_low"], 2)


def test_bland_altman_reproduces_the_lancet_1986_example():
    d = pd.read_csv(DATA / "bland_altman_1986_pefr.csv", comment="#")
    assert len(d) == 17
    ba = bland_altman(d["wright_1"], d["mini_1"], k=2.0)
    assert round(ba.bias, 1) == -2.1 and round(ba.sd, 1) == 38.8
    # the paper's limits -79.7 and 75.5 are -2.1 -+ 2 x 38.8 from the rounded mean and SD
    assert ba.lower == pytest.approx(-79.7, abs=0.1) and ba.upper == pytest.approx(75.5, abs=0.1)
    # the paper's CI of the lower limit, -114.3 to -45.1, computed from the rounded mean and SD
    assert ba.lower_ci[0] == pytest.approx(-114.3, abs=0.15) and ba.lower_ci[1] == pytest.approx(-45.1, abs=0.15)
    assert ba.n == 17 and ba.bias_ci[0] < ba.bias < ba.bias_ci[1]
    ba196 = bland_altman(d["wright_1"], d["mini_1"])
    assert ba196.upper - ba196.lower == pytest.approx(2 * 1.96 * ba.sd)


def test_bland_altman_rejects_too_few_pairs():
    with pytest.raises(ValueError, match="at least 3"):
        bland_altman([1.0, 2.0], [1.1, 2.2])


# --------------------------------------------------------------------------- synthetic cohort

def test_cohort_is_seeded_and_valid():
    spec = CohortSpec()
    a = synthetic_cohort(TARGETS, spec, np.random.default_rng(7))
    b = synthetic_cohort(TARGETS, spec, np.random.default_rng(7))
    c = synthetic_cohort(TARGETS, spec, np.random.default_rng(8))
    pd.testing.assert_frame_equal(a, b)
    assert not a["mfi"].equals(c["mfi"])
    validate_mfi_frame(a)
    # thesis design: 5 per group, 3 females each; 6 re-traced participants (4 WAD, 2 controls) x 40 ROI quartiles
    per = a.drop_duplicates("participant")
    assert per.groupby("group").size().to_dict() == {"Control": 5, "Recovered": 5, "WAD": 5}
    assert (per.groupby("group")["sex"].apply(lambda s: (s == "F").sum()) == 3).all()
    assert per[per.group == "Control"]["ndi"].isna().all() and per[per.group == "WAD"]["ndi"].notna().all()
    retraced = a[a.trial == 2].drop_duplicates("participant")
    assert retraced.groupby("group").size().to_dict() == {"Control": 2, "WAD": 4}
    assert len(a[(a.rater == "A") & (a.trial == 1)]) == 15 * 40 and len(a[a.rater == "B"]) == 6 * 40


def test_large_cohort_regenerates_table_3_2():
    """Calibration: with 1000 participants per group, Table 3.2 regenerated from the data matches the targets."""
    spec = CohortSpec(n_per_group=1000, reliability_participants={})
    df = synthetic_cohort(TARGETS, spec, np.random.default_rng(20261123))
    thesis = TARGETS.mfi.reset_index()
    t = table_3_2(df, "A", 1, thesis)
    params = cell_parameters(TARGETS, spec).set_index(["group", "level", "quartile"])
    q = t[t.quartile != "Whole"]
    # means: SE <= 0.11 / sqrt(1000) = 0.0035
    assert q["diff_mean"].abs().max() < 0.013, q.loc[q["diff_mean"].abs().idxmax()]
    assert abs(q["diff_mean"].mean()) < 0.002
    # SDs: within 10% of the generator's population SD, which equals the printed SD except in floored cells
    model_sd = np.array([params.loc[(g, lvl, qq), "model_sd"] for g, lvl, qq in zip(q.group, q.level, q.quartile)])
    assert np.max(np.abs(q["mfi_sd"] / model_sd - 1)) < 0.10
    floored = params[params.floored]
    assert len(floored) <= 2
    ok = ~params.floored & (params.index.get_level_values("quartile") != "Whole")
    assert np.allclose(params.loc[ok, "model_sd"], params.loc[ok, "target_sd"])
    # whole ROI: mean of the quartiles (printed Whole is 0.003 higher on average, at most 0.007), SD as calibrated
    w = t[t.quartile == "Whole"]
    assert w["diff_mean"].abs().max() < 0.015
    wsd = np.array([params.loc[(g, lvl, "Whole"), "model_sd"] for g, lvl in zip(w.group, w.level)])
    assert np.max(np.abs(w["mfi_sd"] / wsd - 1)) < 0.10
    assert np.max(np.abs(wsd / w["thesis_sd"] - 1)) < 0.12


def test_large_reliability_sample_reproduces_limits_of_agreement():
    spec = CohortSpec(n_per_group=200, reliability_participants={"WAD": 200, "Control": 100})
    df = synthetic_cohort(TARGETS, spec, np.random.default_rng(3))
    rel, pairs = reliability_table(df, "A", "B")
    rel = rel.set_index("design")
    assert rel.loc["intra", "n_pairs"] == 300 * 40
    assert rel.loc["intra", "lower"] == pytest.approx(-0.04, abs=0.003)
    assert rel.loc["intra", "upper"] == pytest.approx(0.06, abs=0.003)
    assert rel.loc["inter", "lower"] == pytest.approx(-0.07, abs=0.003)
    assert rel.loc["inter", "upper"] == pytest.approx(0.07, abs=0.003)
    # no systematic relationship between MFI and the absolute difference (as the thesis reports)
    assert abs(rel.loc["intra", "r_absdiff_mean"]) < 0.05


# --------------------------------------------------------------------------- mixed model

@pytest.fixture(scope="module")
def medium_fit():
    spec = CohortSpec(n_per_group=30, reliability_participants={}, bmi_per_unit=0.01)
    df = synthetic_cohort(TARGETS, spec, np.random.default_rng(11))
    return mm.fit_mixed_model(mm.model_frame(df, "A", 1))


def test_mixed_model_terms_and_effect_recovery(medium_fit):
    fit = medium_fit
    assert fit.attempts["accepted"].sum() == 1
    tests = mm.wald_tests(fit).set_index("effect")
    dfs = {"sex": 1, "BMI": 1, "age": 1, "level^2": 1, "group:quartile": 6, "quartile:level": 3, "group:level": 2,
           "group:quartile:level": 6, "group": 2, "quartile": 3, "level": 1}
    assert tests["df"].to_dict() == dfs
    assert np.allclose(tests["F_wald"], tests["chi2"] / tests["df"])
    fe = mm.fixed_effects_table(fit).set_index("parameter")
    # generated with +0.01 MFI per kg/m^2: recovered within 3 SE
    assert abs(fe.loc["bmi", "estimate"] - 0.01) < 3 * fe.loc["bmi", "se"] and fe.loc["bmi", "se"] < 0.004
    # the quadratic level shape of Table 3.2 (minimum mid-neck) is found
    assert fe.loc["I(level_c ** 2)", "estimate"] > 0 and tests.loc["level^2", "p_chi2"] < 1e-6


def test_marginal_means_and_pairwise(medium_fit):
    cov = mm.emm_covariates(medium_fit, 32.8, 27.27, "C4")
    assert cov["level_c"] == -1.0 and 0 < cov["female"] < 1
    emm = mm.estimated_marginal_means(medium_fit, cov).set_index(["group", "quartile"])
    assert len(emm) == 12 and (emm["ci_low"] < emm["emm"]).all()
    # WAD highest in Q1 (Table 3.2 at every level)
    assert emm.loc[("WAD", "Q1"), "emm"] > emm.loc[("Control", "Q1"), "emm"] > emm.loc[("Recovered", "Q1"), "emm"]
    pw = mm.pairwise_group_comparisons(medium_fit, cov)
    assert len(pw) == 12 and np.allclose(pw["p_bonferroni"], np.minimum(1, 3 * pw["p"]))
    x = pw.set_index(["contrast", "quartile"]).loc[("WAD - Control", "Q1")]
    assert x["difference"] == pytest.approx(emm.loc[("WAD", "Q1"), "emm"] - emm.loc[("Control", "Q1"), "emm"])


# --------------------------------------------------------------------------- stages end to end

def test_stages_end_to_end_on_thesis_sized_cohort(tmp_path):
    from neckstrength.pipeline.chapter3 import (
        chapter3_mixed_model,
        chapter3_reliability,
        chapter3_synthetic_cohort,
        chapter3_table_3_2,
        chapter3_vs_thesis,
    )

    cfg = {**CFG, "chapter3": CFG["chapter3"], "data": {**CFG["data"], "thesis_dir": str(ROOT / "data/thesis")}}
    o = tmp_path
    chapter3_synthetic_cohort(cfg, o / "mfi_cohort_SYNTHETIC.csv", o / "cal.csv")
    head = (o / "mfi_cohort_SYNTHETIC.csv").read_text().splitlines()[0]
    assert "SYNTHETIC" in head
    assert f"seed {CFG['seed']}, stream 'chapter3/synthetic'" in (o / "mfi_cohort_SYNTHETIC.csv").read_text()
    data = o / "mfi_cohort_SYNTHETIC.csv"
    chapter3_reliability(cfg, data, o / "rel.csv", o / "f32.png")
    chapter3_mixed_model(cfg, data, o / "tests.csv", o / "fixed.csv", o / "random.csv", o / "attempts.csv",
                      o / "emm.csv", o / "pw.csv", o / "f33.png")
    chapter3_table_3_2(cfg, data, o / "t32.csv", o / "f34.png")
    out = chapter3_vs_thesis(cfg, ROOT / CFG["chapter3"]["thesis_statistics"], o / "rel.csv", o / "tests.csv",
                          o / "pw.csv", o / "t32.csv", o / "vs.csv", o / "vs.md")
    stats = read_thesis_statistics(ROOT / CFG["chapter3"]["thesis_statistics"])
    assert len(out) == len(stats) + 150                     # 21 reported statistics + 75 cells x (mean, SD)
    assert out["ours_source"].str.contains("SYNTHETIC").all()
    assert out["ours_value"].notna().all()
    assert "Satterthwaite" in (o / "tests.csv").read_text() and "SYNTHETIC" in (o / "vs.md").read_text()
    for f in ("f32.png", "f33.png", "f34.png"):     # drawn on: an empty three-panel figure is ~3% non-white
        px = np.asarray(Image.open(o / f).convert("RGB")).reshape(-1, 3)
        assert (px.min(axis=1) < 250).mean() > 0.06, f
    t32 = pd.read_csv(o / "t32.csv", comment="#")
    assert len(t32) == 75 and (t32["n"] == 5).all()
