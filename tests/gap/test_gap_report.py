"""The gap report reads without contradicting itself: it says which statistic names the effect and how the bootstrap
ranking relates to it, labels each 'where' with what it is computed from, and draws no empty activation panel.
Checked on hand-made diagnoses (no fitting), so each statement's trigger is known."""

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

import neckstrength.gap.diagnose as dg
from neckstrength.gap.report import ranking_note, write_report
from neckstrength.gap.stage import DiagnoseResult, write_diagnose


def _effects(rows):
    """A ranking: (candidate, score, p_best, z)."""
    return pd.DataFrame(rows, columns=["candidate", "score", "p_best", "z"])


CAL = {"calibrated": True}


def test_ranking_note_agrees_includes_or_disagrees_never_silently():
    # S007's case: the named effect has P(best) 0.00, the bootstrap's favourite is a pair that includes it
    ef = _effects([("a+b", 0.60, 0.90, np.nan), ("b", 0.66, 0.02, 2.9), ("a", 0.73, 0.00, 4.0),
                   ("none", 0.77, 0.0, np.nan)])
    t = ranking_note({**CAL, "chosen": "a"}, ef)
    assert "`a` is named by the calibrated test" in t and "prefers the pair `a+b` (0.90; `a` alone 0.00)" in t
    assert "which includes `a`: adding `b` lowers the score further, but pairs are not tested" in t
    assert "Among single effects the lowest score is `b`'s (0.660 against 0.730 for `a`)" in t
    assert "commoner under noise (z 2.90 against 4.00)" in t and "disagree" not in t
    # S003's case: the favourite does not contain the named effect: said, in bold, with what it means
    ef = _effects([("b+c", 0.43, 0.61, np.nan), ("c", 0.46, 0.09, 9.5), ("a", 0.57, 0.01, 11.0),
                   ("none", 0.58, 0.0, np.nan)])
    t = ranking_note({**CAL, "chosen": "a"}, ef)
    assert "**The two disagree**" in t and "prefers `b+c` (0.61; `a` 0.01), which does not include `a`" in t
    assert "the effect whose improvement noise explains least" in t
    # agreement, and nothing named
    ef = _effects([("a", 0.40, 0.80, 5.0), ("b", 0.50, 0.20, 1.0), ("none", 0.6, 0.0, np.nan)])
    t = ranking_note({**CAL, "chosen": "a"}, ef)
    assert "agrees: `a` is its favourite (0.80)" in t and "Among single" not in t
    t = ranking_note({**CAL, "chosen": "none"}, ef)
    assert t.startswith("No effect is named by the calibrated test") and "prefers `a` (0.80)" in t
    assert "not a finding" in t
    # aiming scatter named after the calibrated choice: the bootstrap does not rank it
    t = ranking_note({**CAL, "chosen": "a", "named": "direction_scatter"}, ef)
    assert t.startswith("`direction_scatter` is named by the remainder's shape test")
    # uncalibrated: the score ranking decides and says so
    assert "score ranking alone (uncalibrated" in ranking_note({"calibrated": False, "chosen": "b"}, ef)


def _diagnosis(directions, chosen="asymmetry", activations=True):
    """A hand-made calibrated diagnosis of the 25 directions: the base model misses most in the mid sagittal
    plane, the named candidate's held-out residuals are largest in the posterior coronal plane."""
    K = len(directions)
    names = list(directions["name"])
    planes = directions["planes"].astype(str)
    meas = np.linspace(60.0, 300.0, K)
    in_p = lambda p: planes.str.split(";").apply(lambda ps: p in ps).to_numpy()  # noqa: E731
    r_cv = np.where(in_p("sagittal_mid"), 0.8, 0.05)
    r_ch = np.where(in_p("coronal_posterior"), 0.6, 0.02)
    r_in = 0.5 * r_cv
    d_cv = np.exp(-(3 * r_cv) ** 2)
    res = pd.DataFrame({"direction": names, "planes": planes, "measured_N": meas, "fit_N": meas * (1 + r_in),
                        "residual": r_in, "heldout_N": meas * (1 + r_cv), "residual_cv": r_cv, "d_cv": d_cv,
                        "fold": np.arange(K) % 5, "chosen_fit_N": meas, "chosen_heldout_N": meas * (1 + r_ch),
                        "chosen_residual_cv": r_ch, "chosen_d_cv": np.exp(-(3 * r_ch) ** 2), "reach_s_min": -1.0,
                        "reach_s_max": 1.0, "reach_s_fit": 0.0, "reach": "reachable"})
    dirs = directions.reset_index(drop=True)
    pl = dg._plane_table(dirs, r_in, r_cv, d_cv)
    co = dg._component_table(dirs, r_in, r_cv, d_cv)
    mu = pd.DataFrame({"muscle": ["SCM-R", "SCM-L"], "activation_sum": [3.0, 3.0], "n_active": [3, 3],
                       "mean_residual": [0.1, 0.2], "rms_residual": [0.2, 0.3], "mean_residual_cv": [0.1, 0.2],
                       "rms_residual_cv": [0.2, 0.3]})
    ef = pd.DataFrame({"rank": [1, 2, 3], "candidate": [f"{chosen}+kinematic", chosen, "none"], "n_params": [2, 1, 0],
                       "gap_cv": [0.3, 0.35, 0.4], "rms_rel_cv": [0.3, 0.35, 0.4], "score": [0.31, 0.355, 0.4],
                       "delta_ci_low": [-0.1, -0.05, 0.0], "delta_ci_high": [0.0, 0.01, 0.0],
                       "p_best": [0.9, 0.1, 0.0], "p_raw": [np.nan, 0.025, np.nan], "z": [np.nan, 4.0, np.nan],
                       "D_fit": [0.7, 0.65, 0.6], "theta": ["-", "x=1", "-"], "at_bound": ["-", "-", "-"]})
    act = np.linspace(0.1, 0.4, K) if activations else np.full(K, np.nan)
    s = {"dataset": "hand", "model": "s3m24", "n_directions": K, "folds": 5, "epsilon": 3.0,
         "penalty_per_param": 0.005, "worst_plane": str(pl.sort_values("D_cv")["plane"].iloc[0]),
         "worst_component": "+Fx", "model_too_weak_plane": "transverse_mid", "model_too_weak_mean_residual": -0.1,
         "model_too_strong_plane": "sagittal_mid", "model_too_strong_mean_residual": 0.4,
         "worst_directions": names[:3], "unreachable": [], "calibrated": True, "chosen": chosen, "named": chosen,
         "decision": f"effect {chosen} (p = 0.025 <= 0.05, adjusted for 2 effects)", "chosen_theta": "x=1",
         "best_score": f"{chosen}+kinematic", "at_bound": "-", "gap_before": 0.4, "gap_after": 0.35,
         "rms_before": 0.4, "rms_after": 0.35, "D_fit_base": 0.6, "D_fit_chosen": 0.65, "p_value": 0.025,
         "replicates": 39, "p_resolution": 0.025, "best_effect_calibrated": chosen, "p_raw_best": 0.025,
         "null_truth": "base", "null_note": "", "alpha": 0.05, "noise_sigma": 0.08, "noise_source": "prior",
         "noise_note": "", "remainder": "the remaining gap is not explained by any candidate: it lies in "
         "coronal_posterior (held-out mean residual +0.60)", "remainder_structure": 0.7,
         "p_remainder_structure": 0.025, "p_remainder_gap": 0.025, "rms_heldout_log_chosen": 0.3,
         "gap_over_noise": 3.7, "gap_over_noise_null_median": 1.1, "remainder_unexplained": True,
         "power_target": 0.8, "p_best_chosen": 0.1}
    return SimpleNamespace(name="hand", residuals=res, planes=pl, components=co, muscles=mu, effects=ef, summary=s,
                           activations={"none": act, chosen: act[::-1].copy()},
                           power=pd.DataFrame({"effect": [chosen], "size_share": [1.0], "power": [0.9]}),
                           power_summary=pd.DataFrame({"effect": [chosen], "statement": ["detectable from 1"]}))


def test_where_and_remainder_say_what_they_are_computed_from(directions, tmp_path):
    d = _diagnosis(directions)
    text = write_report(d, tmp_path / "report.md", {"effects": "e.png", "where": "w.png", "radar": "r.png"},
                        pd.DataFrame(), "-")
    base = next(ln for ln in text.splitlines() if ln.startswith("- **Where, base model**"))
    after = next(ln for ln in text.splitlines() if ln.startswith("- **Where, after `asymmetry`**"))
    rem = next(ln for ln in text.splitlines() if ln.startswith("- **Remainder**"))
    assert "largest held-out RMS relative residual in `sagittal_mid` (RMS 0.80" in base
    assert "largest held-out RMS relative residual in `coronal_posterior` (RMS 0.60" in after
    assert "the source of the Remainder below" in after and "coronal_posterior" in rem
    assert "from the held-out residuals of `asymmetry`" in rem and "'Where, after'" in rem
    assert "D (Eq. 5.5) and the RMS residual can name different planes" in text
    # the Which line says why the named effect's P(best) is low (the pair that includes it)
    which = next(ln for ln in text.splitlines() if ln.startswith("- **Which**"))
    assert "prefers the pair `asymmetry+kinematic` (0.90; `asymmetry` alone 0.10)" in which


def test_evidence_reading_states_its_choices_and_whether_anything_fits(directions, tmp_path):
    """The Bayes evidence's second reading (gap.evidence): its choices in the line, and a most probable explanation
    that does not fit is said not to fit, not named."""
    ev = {"named": "none", "p_no_effect": 0.003, "most_probable": "direction_scatter",
          "best_effect": "direction_scatter", "fit_p_most_probable": 1e-5, "fit_p_best_effect": 1e-5, "fits": False,
          "top3": [["direction_scatter", 0.99], ["origin_offset", 0.005], ["none", 0.003]], "noise_sigma": 0.08,
          "trials_per_force": 1, "strength_sd": 0.3, "prior_no_effect": 0.5, "threshold": 0.05, "fit_alpha": 0.001}
    d = _diagnosis(directions)
    d.summary["evidence"] = ev
    text = write_report(d, tmp_path / "a.md", {"effects": "e.png", "where": "w.png", "radar": "r.png"},
                        pd.DataFrame(), "-")
    line = next(ln for ln in text.splitlines() if ln.startswith("- **Second reading: Bayes evidence**"))
    assert "log SD of 0.3" in line and "prior P(no effect) 0.5" in line and "largest of 1 trial(s)" in line
    assert "does **not** fit (chi-square p = 1e-05)" in line and "It names nothing" in line
    assert "least bad, not what is true" in line
    d.summary["evidence"] = {**ev, "named": "origin_offset", "most_probable": "origin_offset", "fits": True,
                             "fit_p_most_probable": 0.4, "p_no_effect": 0.01}
    text = write_report(d, tmp_path / "b.md", {"effects": "e.png", "where": "w.png", "radar": "r.png"},
                        pd.DataFrame(), "-")
    line = next(ln for ln in text.splitlines() if ln.startswith("- **Second reading: Bayes evidence**"))
    assert "`origin_offset`, which fits (chi-square p = 0.4)" in line and "It names `origin_offset`" in line
    assert "least bad" not in line
    del d.summary["evidence"]
    text = write_report(d, tmp_path / "c.md", {"effects": "e.png", "where": "w.png", "radar": "r.png"},
                        pd.DataFrame(), "-")
    assert "Second reading" not in text


def test_evidence_as_the_decision_keeps_the_calibrated_test_beside_it(directions, tmp_path):
    """gap.evidence.decides: the summary's named effect and decision are the evidence's, the calibrated test's are
    kept, and the report says which rule decided (heading, Named effect, Calibrated test, Which)."""
    from neckstrength.gap.diagnose import evidence_decision

    ev = {"named": "origin_offset", "p_no_effect": 0.002, "most_probable": "origin_offset",
          "best_effect": "origin_offset", "fit_p_most_probable": 0.4, "fit_p_best_effect": 0.4, "fits": True,
          "top3": [["origin_offset", 0.99], ["none", 0.002], ["asymmetry", 0.001]], "noise_sigma": 0.04,
          "trials_per_force": 3, "strength_sd": 0.3, "prior_no_effect": 0.5, "threshold": 0.01, "fit_alpha": 0.001}
    d = _diagnosis(directions)
    before = d.summary["decision"]
    d.summary["evidence"] = ev
    d.summary.update(evidence_decision(d.summary))
    assert d.summary["named"] == "origin_offset" and d.summary["named_calibrated"] == "asymmetry"
    assert d.summary["decision_calibrated"] == before and d.summary["decided_by"] == "evidence"
    assert "P(no effect) 0.002 < 0.01" in d.summary["decision"]
    assert d.summary["decision"].endswith("prior P(no effect) 0.5, noise 0.040, strengths to a log SD of 0.3)")
    text = write_report(d, tmp_path / "d.md", {"effects": "e.png", "where": "w.png", "radar": "r.png"},
                        pd.DataFrame(), "-")
    assert "## Decision (Bayes evidence; the calibrated test beside it)" in text
    named = next(ln for ln in text.splitlines() if ln.startswith("- **Named effect**"))
    assert named.startswith("- **Named effect**: origin_offset named (Bayes evidence")
    cal = next(ln for ln in text.splitlines() if ln.startswith("- **Calibrated test**"))
    assert before in cal and "Adjusted p-value" in cal
    assert any(ln.startswith("- **Bayes evidence** (the decision") for ln in text.splitlines())
    which = next(ln for ln in text.splitlines() if ln.startswith("- **Which**"))
    assert "The decision is the Bayes evidence's" in which and "calibrated test beside it names `asymmetry`" in which
    # a most probable effect that does not fit is not named, and the decision says why
    nf = evidence_decision({**d.summary, "evidence": {**ev, "named": "none", "fit_p_best_effect": 1e-6}})
    assert nf["named"] == "none" and "does not fit" in nf["decision"]
    # a remainder the calibrated test finds consistent with noise, where nothing fits (the most probable
    # explanation fails its chi-square check): not noise, and the report says so; where it fits, unchanged
    quiet = {**d.summary, "remainder_tested": True, "remainder_unexplained": False, "p_remainder_gap": 0.4,
             "remainder": "the remaining held-out gap is consistent with noise"}
    bad = {**ev, "named": "none", "most_probable": "none", "fit_p_most_probable": 2e-5, "fits": False}
    nn = evidence_decision({**quiet, "evidence": bad})
    assert nn["remainder_unexplained"] is True and nn["remainder"].startswith("the remaining gap is not explained")
    assert "chi-square p = 2e-05 < 0.001" in nn["remainder"] and "(p = 0.4)" in nn["remainder"]
    assert nn["remainder_calibrated"] == quiet["remainder"]
    assert "remainder" not in evidence_decision({**quiet, "evidence": ev})
    from neckstrength.gap.scoring import case_row

    assert case_row("x", "none", "none", [], {**quiet, **nn}, d.effects)["consistent_with_noise"] is False
    assert case_row("x", "none", "none", [], quiet, d.effects)["consistent_with_noise"] is True


def _write(diag, directions, out, a3=None):
    inputs = SimpleNamespace(directions=directions, a3=a3, data=SimpleNamespace(name=diag.name), extra_trials=None,
                             settings_text="-")
    res = DiagnoseResult(diag, {}, diag.summary, pd.DataFrame(), inputs)
    outputs = {f"fig_{k}": out / f"fig_{k}.png" for k in ("radar", "where", "effects", "activation")}
    outputs.update({"summary": out / "summary.json", "report": out / "report.md"})
    write_diagnose(res, outputs)
    return (out / "report.md").read_text()


def _declared_outputs(rule: str) -> list[str]:
    """The output names of ``rule`` in workflow/rules/gap.smk."""
    text = (Path(__file__).resolve().parents[2] / "workflow" / "rules" / "gap.smk").read_text()
    block = text.split(f"rule {rule}:", 1)[1].split("    output:", 1)[1]
    block = re.split(r"\n    \w+:", block, maxsplit=1)[0]
    return re.findall(r"^        (\w+)=", block, flags=re.M)


def test_no_activation_data_gives_the_prediction_of_the_groups_or_of_the_muscles(directions, tmp_path, figures):
    # without Table A.3 the activation figure shows the model's prediction (two curves with values), not a text
    # placeholder, and the report links it under its own heading
    text = _write(_diagnosis(directions), directions, tmp_path / "pred")
    fig = next(f for f in figures if f._suptitle is None and "Predicted activation" in f.axes[0].get_title())
    lines = [ln for ln in fig.axes[0].get_lines() if np.isfinite(ln.get_ydata()).any()]
    assert len(lines) == 2 and fig.axes[0].get_xlabel() and fig.axes[0].get_ylabel()
    assert "## Predicted activation\n" in text and "![activation](fig_activation.png)" in text
    # no EMG-recorded group either: every figure the pipeline rule declares is still written (the rule failed on
    # a missing fig_activation.png), the activation figure showing each muscle group's mean predicted activation
    declared = [k for k in _declared_outputs("gap_diagnose") if k.startswith("fig_")]
    assert "fig_activation" in declared and "fig_radar" in declared
    out = tmp_path / "none"
    text = _write(_diagnosis(directions, activations=False), directions, out)
    assert all((out / f"{k}.png").exists() for k in declared), [k for k in declared if not (out / f"{k}.png").exists()]
    fig = next(f for f in figures if "by muscle group" in f.axes[0].get_title())
    heights = [b.get_height() for b in fig.axes[0].patches]
    assert np.allclose(heights, 3.0 / len(directions))      # activation_sum / directions, per group
    assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == ["SCM-R", "SCM-L"]
    assert fig.axes[0].get_xlabel() and fig.axes[0].get_ylabel()
    assert "## Predicted activation by muscle group" in text and "![activation](fig_activation.png)" in text
