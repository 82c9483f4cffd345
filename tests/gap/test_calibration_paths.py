"""The diagnosis's calibration with the power in two stages (diagnose.calibrate_with_power) against the previous
single screen (calibrate with the power data sets beside the null): the same null, decision and power tables."""

import numpy as np
import pandas as pd

from neckstrength.gap import calibrate as cb
from neckstrength.gap import diagnose as dg
from neckstrength.gap.effects import EFFECTS, available_effects, base_instance, compose
from neckstrength.gap.engine import CalibrationSettings, _Engine, direction_folds
from neckstrength.gap.fit import FitSettings, Simulator
from neckstrength.seeds import derive_rng


def test_two_stage_power_gives_the_single_screen_calibration(ctx_p2):
    s = dg.DiagnosisSettings(effects=("cocontraction", "kinematic", "origin_offset"), grid_points=4, folds=7,
                             pairs_top=0, bootstrap=20, starts=1, reach_samples=0, reach_iter=0,
                             fit=FitSettings(max_iter=15), seed=1,
                             calibration=CalibrationSettings(replicates=19, noise=0.01, power_sizes=(0.5, 1.0),
                                                             power_replicates=3, cv="one_step", max_iter=8))
    rng = np.random.default_rng(4)
    F = ctx_p2.model.strengths[None] * np.exp(rng.normal(0, 0.2, (1, ctx_p2.model.m)))
    data = []
    for name, th in (("kin", ("kinematic", [0.9])), ("ctrl", None)):
        inst = base_instance(ctx_p2) if th is None else compose(ctx_p2, [EFFECTS[th[0]](ctx_p2)], [np.array(th[1])])
        data.append(dg.BlindData(name, Simulator(ctx_p2, inst).forces(F)[0] * np.exp(rng.normal(0, 0.01, ctx_p2.K))))
    effects = available_effects(ctx_p2, s.effects)
    folds = np.array([direction_folds(ctx_p2.K, s.folds, derive_rng(s.seed, f"gap/folds/{d.name}")) for d in data])
    eng = _Engine(ctx_p2, data, s, folds, {e.name: e for e in effects})
    eng.evaluate((), eng.prior)
    pf = [int(np.nonzero((eng.pds == i) & (eng.pfold < 0))[0][0]) for i in range(len(data))]
    args = (ctx_p2, [d.name for d in data], folds, eng.T[pf], eng.results[()]["forces"][pf],
            eng.results[()]["phi"][pf], np.full((len(data), len(effects) + 1), np.nan), effects, s)
    before = cb.calibrate(*args)
    now = dg.calibrate_with_power(*args)
    hits = 0
    for a, b in zip(before, now):
        np.testing.assert_allclose(a.gap_null, b.gap_null, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(a.gap_obs, b.gap_obs, rtol=1e-9, atol=1e-12)
        da, db = a.decide(a.gap_obs), b.decide(b.gap_obs)
        assert (da["best"], da["p_adjusted"]) == (db["best"], db["p_adjusted"])
        pd.testing.assert_frame_equal(a.power.reset_index(drop=True), b.power.reset_index(drop=True))
        hits += int(a.power["identified"].sum())
    assert hits > 0                      # the comparison includes power data sets that are named
