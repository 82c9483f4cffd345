"""What to measure to tell (issue 32 item 4): power per protocol, its efficiency, the advice in every report."""

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from neckstrength.estimation.parameters import free_parameters
from neckstrength.gap import diagnose as dg
from neckstrength.gap.effects import EFFECTS, base_instance, compose
from neckstrength.gap.engine import CalibrationSettings
from neckstrength.gap.fit import FitSettings, Simulator
from neckstrength.gap.protocols import (
    PROTOCOLS,
    ProtocolSettings,
    _power,
    advice,
    fit_efficiency,
    posture_context,
    protocol_power,
)
from neckstrength.gap.report import write_report


def _phi(ctx):
    pidx, _ = free_parameters(ctx.model, ctx.tie_sides)
    return np.array([np.log(ctx.model.strengths[pidx == q].mean()) for q in range(int(pidx.max()) + 1)])


def test_power_table_shape_and_information_only_grows(ctx_s3):
    effs = [EFFECTS[n](ctx_s3) for n in ("submaximal_effort", "posture_drift", "anthropometric_scaling")]
    pw = protocol_power(ctx_s3, _phi(ctx_s3), 0.08, effs, ProtocolSettings(sizes=(0.5, 1.0)), alpha=0.05)
    assert len(pw) == 3 * 2 * len(PROTOCOLS) and set(pw["protocol"]) == set(PROTOCOLS)
    assert pw["power"].between(0, 1).all() and not pw["unproducible"].any()
    lam = pw.set_index(["effect", "size_share", "protocol"])["noncentrality"].unstack()
    # three trials per direction: the noise variance / 3, the same strengths absorbed: exactly 3 x the information
    np.testing.assert_allclose(lam["repeats"], 3 * lam["directions"], rtol=1e-8)
    # more observations never lose information (the projection on the strengths is over more rows)
    for p in ("emg", "postures", "all"):
        assert (lam[p] >= lam["directions"] * (1 - 1e-9)).all()
    assert (lam["all"] >= lam["postures"] * (1 - 1e-9)).all()
    # the posture tests see a posture drift the neutral tests barely see
    assert lam.loc[("posture_drift", 1.0), "postures"] > 5 * lam.loc[("posture_drift", 1.0), "directions"]


def test_posture_context_scales_the_neutral_strengths(ctx_s3):
    cq, rho = posture_context(ctx_s3, "flex20")
    np.testing.assert_allclose(cq.model.strengths, ctx_s3.model.strengths * rho, rtol=1e-12)
    assert cq.posture_angle == 20.0
    with pytest.raises(ValueError, match="no sagittal posture table"):
        posture_context(ctx_s3, "rotL30")


def test_efficiency_is_recovered_from_simulated_power():
    lams = {("a", 0.5): 5.0, ("a", 1.0): 40.0, ("b", 0.5): 80.0, ("b", 1.0): 300.0}
    pw = pd.DataFrame([{"effect": e, "protocol": "directions", "size_share": u, "noncentrality": v}
                       for (e, u), v in lams.items()])
    sim = pd.DataFrame([{"effect": e, "size_share": u, "replicates": 100,
                         "power": _power(v, 1 if e == "a" else 2, 0.05 / 2, 10.0)} for (e, u), v in lams.items()])
    k = fit_efficiency(pw, sim, 0.05, 2, {"a": 1, "b": 2})
    assert k == pytest.approx(10.0, rel=0.15)
    assert np.isnan(fit_efficiency(pw, pd.DataFrame(), 0.05, 2, {"a": 1, "b": 2}))
    assert np.isnan(fit_efficiency(pw, sim.assign(power=0.0), 0.05, 2, {"a": 1, "b": 2}))   # any large factor fits


def test_advice_names_the_cheapest_protocol_that_tells():
    rows = []
    for prot, pa, pb in (("directions", 0.1, 0.1), ("repeats", 0.5, 0.2), ("emg", 0.9, 0.3), ("postures", 0.9, 0.5),
                         ("all", 1.0, 0.6)):
        rows += [{"effect": "a", "protocol": prot, "size_share": 1.0, "theta": "x=1", "power": pa},
                 {"effect": "b", "protocol": prot, "size_share": 1.0, "theta": "y=1", "power": pb}]
    pw = pd.DataFrame(rows)
    sim = pd.DataFrame({"effect": ["a", "b", "c"], "min_detectable_share": [np.nan, np.nan, 0.5]})
    adv = {a["effect"]: a for a in advice(pw, sim, ProtocolSettings(target=0.8), 0.08, ["a", "b", "c"])}
    assert adv["a"]["protocol"] == "emg" and adv["a"]["line"].startswith("to tell `a` from noise, add a surface-EMG")
    assert adv["b"]["protocol"] == "-" and adv["b"]["line"].startswith("no listed protocol tells `b` from noise")
    assert adv["c"]["basis"] == "simulated" and "present tests" in adv["c"]["line"]


def test_every_calibrated_report_ends_with_the_advice(ctx_p2, tmp_path):
    """p2m7, a posture drift injected (1% noise), calibrated with power: the report's last lines are one advice
    line per effect."""
    rng = np.random.default_rng(7)
    F = ctx_p2.model.strengths[None] * np.exp(rng.normal(0, 0.2, (1, ctx_p2.model.m)))
    e = EFFECTS["posture_drift"](ctx_p2)
    f = Simulator(ctx_p2, compose(ctx_p2, [e], [e.upper])).forces(F)[0]
    data = [dg.BlindData("drift", f * np.exp(rng.normal(0, 0.01, ctx_p2.K)))]
    s = dg.DiagnosisSettings(effects=("kinematic", "posture_drift"), grid_points=3, folds=7, pairs_top=0,
                             bootstrap=10, starts=1, reach_samples=0, reach_iter=0, fit=FitSettings(max_iter=10),
                             seed=1, calibration=CalibrationSettings(replicates=4, noise=0.01, power_sizes=(1.0,),
                                                                     power_replicates=2, sensitivity=False),
                             protocols=ProtocolSettings())
    d = dg.diagnose(ctx_p2, data, s)[0]
    # the calibration's power table has the new effect like the others: one row per effect and size
    assert list(d.power["effect"]) == ["kinematic", "posture_drift"] and (d.power["replicates"] <= 2).all()
    assert set(d.protocols["effect"]) == {"kinematic", "posture_drift"}
    k = d.summary["protocol_efficiency"]
    assert (k >= 1.0 or np.isnan(k)) and len(d.summary["protocol_advice"]) == 2
    text = write_report(d, tmp_path / "report.md", {"effects": "e.png", "where": "w.png", "radar": "r.png"},
                        pd.DataFrame(), "-")
    last = [ln for ln in text.strip().splitlines() if ln.strip()][-2:]
    assert all(("from noise" in ln) for ln in last), last
    assert {ln.split("`")[1] for ln in last} == {"kinematic", "posture_drift"}
    bare = dg.diagnose(ctx_p2, data, replace(s, protocols=None))[0]
    assert "protocol_advice" not in bare.summary and bare.summary["decision"] == d.summary["decision"]


def test_discrimination_pool_has_the_posture_tests_predicted_in_their_posture(cfg, ctx_p2):
    """The proposal's pool holds the directions again in flex20 and ext20; a candidate's predicted force there is
    the posture model's (neutral strengths x rho), not the neutral one, and carries its uncertainty."""
    from neckstrength.config import head_from_config
    from neckstrength.gap import discriminate as dc

    head = head_from_config(cfg)
    s = dc.DiscriminateSettings(surface=False, repeats=False)
    pool = dc.measurement_pool(ctx_p2, head, s, cfg["geometry"]["plane_bands"])
    assert list(dict.fromkeys(pool["posture"])) == ["flex20", "ext20"] and (pool["kind"] == "posture").all()
    assert list(pool["name"][:2]) == [f"flex20:{n}" for n in ctx_p2.directions["name"][:2]]
    T = Simulator(ctx_p2, base_instance(ctx_p2)).forces(ctx_p2.model.strengths[None])[0]
    pr = dc.predict_candidate(ctx_p2, T, "none", {}, pool, 0.05, s)
    K = ctx_p2.K
    cq, rho = posture_context(ctx_p2, "ext20")
    sq = Simulator(cq, base_instance(cq))
    f_ext = sq.forces(Simulator(ctx_p2, base_instance(ctx_p2)).muscles(pr.phi[None]) * rho[None])[0]
    np.testing.assert_allclose(np.exp(pr.log_force[K + K:K + 2 * K]), f_ext, rtol=1e-6)
    assert np.all(np.diag(pr.cov)[K:] > 0)
    assert not np.allclose(pr.log_force[K:2 * K], pr.log_force[2 * K:3 * K])


def test_advice_says_when_every_size_is_unproducible():
    pw = pd.DataFrame([{"effect": "a", "protocol": p, "size_share": u, "theta": "x", "unproducible": True,
                        "power": np.nan} for p in PROTOCOLS for u in (0.5, 1.0)])
    line = advice(pw, None, ProtocolSettings(target=0.8), 0.08, ["a"])[0]["line"]
    assert "unproducible" in line and "from noise" not in line


def test_advice_cautions_where_the_heuristic_overstates_the_present_tests():
    pw = pd.DataFrame([{"effect": "a", "protocol": p, "size_share": 1.0, "theta": "x=1", "power": v}
                       for p, v in (("directions", 0.6), ("repeats", 0.95), ("emg", 0.6), ("postures", 0.7),
                                    ("all", 1.0))])
    sim = pd.DataFrame({"effect": ["a"], "size_share": [1.0], "power": [0.0]})
    summ = pd.DataFrame({"effect": ["a"], "min_detectable_share": [np.nan]})
    line = advice(pw, summ, ProtocolSettings(target=0.8), 0.08, ["a"], simulated_table=sim)[0]["line"]
    assert line.startswith("to tell `a` from noise, add 3 trials") and "overstates" in line
    ok = advice(pw, summ, ProtocolSettings(target=0.8), 0.08, ["a"], simulated_table=sim.assign(power=0.5))[0]
    assert "overstates" not in ok["line"]
