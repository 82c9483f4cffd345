"""The calibration's null truths (issue 32): the fitted model's own structure or a finer one (each element its own
strength, gap.calibration.null_truth: elements)."""

import numpy as np
import pytest

from neckstrength.config import calibration_settings
from neckstrength.gap import calibrate as cb
from neckstrength.gap import diagnose as dg
from neckstrength.gap.effects import base_instance
from neckstrength.gap.engine import CalibrationSettings
from neckstrength.gap.fit import FitSettings, Simulator
from neckstrength.seeds import derive_rng


@pytest.mark.parametrize("model", ["s3m24", "p2m7"])
def test_elements_without_spread_reach_at_least_the_grouped_forces(model, request):
    # every element its own column can do what the grouped activation does (and more where the group's elements
    # pull differently), so with all factors 1 no test's force is lower and some are higher
    ctx = request.getfixturevalue("ctx_s3" if model == "s3m24" else "ctx_p2")
    en = cb.ElementNull(ctx, 0.0)
    F = ctx.model.strengths[None] * np.exp(derive_rng(0, "gap/elements/test").normal(0, 0.2, (3, ctx.model.m)))
    f_base = Simulator(ctx, base_instance(ctx)).forces(F)
    f_el = en.forces(F, en.factors(3, derive_rng(0, "gap/elements/test")))
    assert np.all(f_el >= f_base * (1 - 1e-6))
    assert (f_el > f_base * 1.01).any()


def test_element_factors_keep_each_free_parameter_and_let_the_sides_differ(ctx_s3):
    en = cb.ElementNull(ctx_s3, 0.3)
    c = en.factors(50, derive_rng(0, "gap/elements/test"))
    assert np.allclose(c, en.factors(50, derive_rng(0, "gap/elements/test")))      # seeded
    for q in np.unique(en.owner):                       # strength-weighted mean 1 over a free parameter's elements
        s = en.owner == q
        assert np.allclose(c[:, s] @ en.weight[s], en.weight[s].sum())
    # s3m24 ties the sides in the fit; the element null does not: left and right group totals differ
    g = en.inst.col_group
    names = ctx_s3.model.muscle_names
    right, left = names.index("SCM-R"), names.index("SCM-L")
    tot = np.array([[(ci * en.weight)[g == k].sum() for k in (right, left)] for ci in c])
    lr = np.log(tot[:, 1] / tot[:, 0])
    assert np.median(np.abs(lr)) > 0.05
    assert np.std(np.log(c)) == pytest.approx(0.3, rel=0.2)


def _settings(null_truth):
    return dg.DiagnosisSettings(effects=("cocontraction", "kinematic"), grid_points=3, folds=5, pairs_top=0,
                                bootstrap=0, starts=1, reach_samples=0, reach_iter=0, fit=FitSettings(max_iter=8),
                                seed=1, calibration=CalibrationSettings(replicates=3, noise=0.02, sensitivity=False,
                                                                        power_replicates=0, max_iter=8,
                                                                        cv="one_step", null_truth=null_truth))


def test_the_element_null_simulates_other_truths_and_the_report_names_its_source(ctx_p2):
    F = ctx_p2.model.strengths[None] * 1.1
    f = Simulator(ctx_p2, base_instance(ctx_p2)).forces(F)[0]
    data = [dg.BlindData("ctrl", f * np.exp(derive_rng(0, "gap/elements/test").normal(0, 0.02, ctx_p2.K)))]
    out = {}
    for nt in ("base", "elements"):
        d = dg.diagnose(ctx_p2, data, _settings(nt))[0]
        out[nt] = d
        assert d.summary["null_truth"] == nt and d.calibration.null == nt
    assert "exp(N(0, 0.3))" in out["elements"].summary["null_note"]
    assert "fitted model's own structure" in out["base"].summary["null_note"]
    # the measured data set is screened alike under both nulls; the replicates differ
    assert np.allclose(out["base"].calibration.gap_obs, out["elements"].calibration.gap_obs)
    assert not np.allclose(out["base"].calibration.gap_null, out["elements"].calibration.gap_null)
    from neckstrength.gap.report import _calibration_lines

    text = "\n".join(_calibration_lines(out["elements"]))
    assert "null truths `elements`" in text and "each full-model element its own strength" in text


def test_null_truth_from_the_config():
    cs = calibration_settings({"gap": {"calibration": {"replicates": 9}}})
    assert cs.null_truth == "base" and cs.element_spread == 0.3
    cs = calibration_settings({"gap": {"calibration": {"null_truth": "elements", "element_spread": 0.2}}})
    assert cs.null_truth == "elements" and cs.element_spread == 0.2
    with pytest.raises(ValueError, match="gap.calibration.null_truth"):
        calibration_settings({"gap": {"calibration": {"null_truth": "rich96"}}})
    for bad in (-0.1, True, "0.3"):
        with pytest.raises(ValueError, match="gap.calibration.element_spread"):
            calibration_settings({"gap": {"calibration": {"element_spread": bad}}})
