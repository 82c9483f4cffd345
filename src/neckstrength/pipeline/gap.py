"""Pipeline stages of the sim-to-real gap diagnosis (issue 8), one function per rule."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from neckstrength.config import (
    benchmark_settings,
    calibration_settings,
    derive_rng,
    diagnose_stage,
    diagnosis_settings,
    gap_context,
)
from neckstrength.gap.benchmark import decision_settings, run_benchmark
from neckstrength.gap.diagnose import DiagnosisSettings
from neckstrength.gap.report import markdown_table
from neckstrength.gap.stage import answer_lines, header_line, run_diagnose, write_diagnose
from neckstrength.gap.store import ResultStore
from neckstrength.io import atomic_write_csv, atomic_write_text
from neckstrength.pipeline.common import load_directions


def _print(s: str) -> None:
    print(s, flush=True)


def gap_diagnose(config: Mapping, model_name: str, dataset: str, directions_csv: str | Path | pd.DataFrame,
                 outputs: Mapping[str, str | Path], workers: int = 1) -> dict:
    """Diagnose one data set: tables, figures, report.md and summary.json (keys of ``outputs``); ``workers``:
    processes for the calibration's screen (the rule's threads)."""
    directions = directions_csv if isinstance(directions_csv, pd.DataFrame) else load_directions(directions_csv)
    settings, inputs = diagnose_stage(config, model_name, dataset, directions, workers=workers)
    _print(header_line(inputs))
    result = run_diagnose(settings, inputs, resume_dir=Path(outputs["summary"]).parent / "resume", progress=_print)
    write_diagnose(result, outputs)
    for line in answer_lines(result):
        _print(line)
    return result.summary


def gap_pooled(config: Mapping, model_name: str, datasets: Sequence[str], summaries: Sequence[str],
                     effects: Sequence[str], out_csv: str | Path, out_ranking: str | Path) -> pd.DataFrame:
    """One row per data set (where / which / how far / Table A.3 check) plus a pooled row, and the pooled
    effect ranking (mean score over data sets, number of data sets where each candidate ranks first)."""
    rows, ranks = [], []
    for ds, sp, ep in zip(datasets, summaries, effects):
        s = json.loads(Path(sp).read_text())
        rows.append({"dataset": ds, "worst_plane": s["worst_plane"], "worst_component": s["worst_component"],
                     "model_too_weak_in": s["model_too_weak_plane"], "model_too_strong_in": s["model_too_strong_plane"],
                     "worst_directions": ";".join(s["worst_directions"]),
                     "unreachable": ";".join(s["unreachable"]) or "-", "chosen": s["chosen"],
                     "chosen_theta": s["chosen_theta"], "p_value": s.get("p_value", np.nan),
                     "named": s.get("named", s["chosen"]), "decided_by": s.get("decided_by", "calibrated"),
                     "named_calibrated": s.get("named_calibrated", s.get("named", s["chosen"])),
                     "decision": s.get("decision", ""), "noise_sigma": s.get("noise_sigma", np.nan),
                     "noise_source": s.get("noise_source", ""), "gap_over_noise": s.get("gap_over_noise", np.nan),
                     "remainder": s.get("remainder", ""), "p_best": s["p_best_chosen"],
                     "gap_before": s["gap_before"], "gap_after": s["gap_after"],
                     "rms_before": s["rms_before"], "rms_after": s["rms_after"],
                     "D_fit_base": s["D_fit_base"], "D_fit_chosen": s["D_fit_chosen"],
                     "a3_mean": s.get("a3_mean", np.nan), "a3_model_mean_base": s.get("a3_model_mean_base", np.nan),
                     "a3_model_mean_chosen": s.get("a3_model_mean_chosen", np.nan),
                     "a3_pearson_base": s.get("a3_pearson_base", np.nan),
                     "a3_pearson_chosen": s.get("a3_pearson_chosen", np.nan),
                     "evidence_most_probable": (s.get("evidence") or {}).get("most_probable", ""),
                     "evidence_fits": (s.get("evidence") or {}).get("fits", ""),
                     "evidence_named": (s.get("evidence") or {}).get("named", "")})
        e = pd.read_csv(ep, comment="#")
        e["dataset"] = ds
        ranks.append(e)
    df = pd.DataFrame(rows)
    num = df.select_dtypes("number").mean()
    pooled = {c: num.get(c, "") for c in df.columns}
    pooled.update({"dataset": "pooled (mean)", "worst_plane": df["worst_plane"].mode().iloc[0],
                   "worst_component": df["worst_component"].mode().iloc[0],
                   "model_too_weak_in": df["model_too_weak_in"].mode().iloc[0],
                   "model_too_strong_in": df["model_too_strong_in"].mode().iloc[0], "worst_directions": "",
                   "unreachable": "", "chosen": df["chosen"].mode().iloc[0], "chosen_theta": "", "decision": "",
                   "noise_source": "",
                   "remainder": "", "evidence_most_probable": "", "evidence_fits": "", "evidence_named": ""})
    df = pd.concat([df, pd.DataFrame([pooled])], ignore_index=True)
    atomic_write_csv(df, out_csv, [f"gap diagnosis pooled over data sets ({model_name}): where / which / how far, "
                                   "held-out gap = 1 - D_cv (Eq. 5.5 on held-out directions)",
                                   "a3_*: Table A.3 (withheld) vs the model's mean activation of the EMG-recorded "
                                   "groups; base = fitted model, chosen = with the chosen effect",
                                   "evidence_*: the Bayes evidence's second reading (gap.evidence; heuristic): most "
                                   "probable explanation, whether it fits (chi-square), the effect it names"],
                     float_format="%.4g")
    allr = pd.concat(ranks, ignore_index=True)
    rk = allr.groupby("candidate").agg(n_datasets=("dataset", "nunique"), mean_score=("score", "mean"),
                                        mean_gap_cv=("gap_cv", "mean"), mean_delta_vs_none=("delta_score_vs_none",
                                                                                             "mean"),
                                        n_ranked_first=("rank", lambda r: int((r == 1).sum())),
                                        mean_p_best=("p_best", "mean")).reset_index()
    rk = rk.sort_values(["n_datasets", "mean_score"], ascending=[False, True]).reset_index(drop=True)
    atomic_write_csv(rk, out_ranking, [f"pooled effect ranking ({model_name}) over {len(datasets)} data sets"],
                     float_format="%.4g")
    return df


def benchmark_setup(config: Mapping, model_name: str, directions: pd.DataFrame):
    """The benchmark's context, generator settings, diagnosis settings (``gap.benchmark`` over ``gap``) and
    generator stream, as the rule ``gap_benchmark`` uses them (also for ``benchmarks/bench_gap_benchmark.py``)."""
    ctx = gap_context(config, model_name, directions)
    b = config["gap"]["benchmark"]
    bs = benchmark_settings(config)
    ds = diagnosis_settings(config, b.get("diagnosis_effects"), protocols=False, evidence=False)
    cal = calibration_settings({"gap": {"calibration": {**(config["gap"].get("calibration") or {}),
                                                         **(b.get("calibration") or {})}}})
    ds = DiagnosisSettings(**{**ds.__dict__, "folds": b.get("folds", ds.folds),
                              "bootstrap": b.get("bootstrap", ds.bootstrap), "starts": b.get("starts", ds.starts),
                              "refine_iter": b.get("refine_iter", ds.refine_iter), "pairs_top": b.get("pairs_top",
                                                                                                      ds.pairs_top),
                              "reach_samples": 0, "reach_iter": 0, "calibration": cal})
    return ctx, bs, ds, derive_rng(config["seed"], f"gap-benchmark/{model_name}")


def gap_benchmark(config: Mapping, model_name: str, directions_csv: str | Path,
                        outputs: Mapping[str, str | Path], workers: int = 1) -> dict[str, pd.DataFrame]:
    """Withheld-effect benchmark; prints the confusion matrix (to the rule's log). ``workers``: processes (the
    rule's threads) that diagnose batches of cases in parallel."""
    t0 = time.time()
    directions = load_directions(directions_csv)
    ctx, bs, ds, rng = benchmark_setup(config, model_name, directions)
    b = config["gap"]["benchmark"]
    cal = ds.calibration
    store = ResultStore(Path(outputs["summary"]).parent / "resume", ctx, decision_settings(ds))
    power_store = ResultStore(Path(outputs["summary"]).parent / "resume", ctx, ds)
    cases, diags, tabs = run_benchmark(ctx, bs, ds, rng, progress=lambda m: print(f"[{time.time() - t0:.0f} s] {m}",
                                                                                  flush=True),
                                       store=store, chunk=b.get("chunk"), power_store=power_store,
                                       workers=workers)
    hdr = [f"withheld-effect benchmark ({model_name}): {len(cases)} cases ({bs.mismatch_replicates} per effect with "
           f"finer muscle control in the truth), noise {bs.noise_rel} (log-normal SD), strength spread "
           f"{bs.strength_spread}, effect size {bs.clear_size} of the way to the far bound",
           f"diagnosis effects: {', '.join(ds.effects)}; the diagnosis saw forces only; calibration "
           f"{cal.replicates} noise-only replicates, alpha {cal.alpha}, power sizes {list(cal.power_sizes)} x "
           f"{cal.power_replicates}"]
    atomic_write_csv(tabs["confusion"], outputs["confusion"], hdr + ["rows: injected effect; columns: identified"])
    atomic_write_csv(tabs["per_case"], outputs["cases"], hdr, float_format="%.4g")
    atomic_write_csv(tabs["effect_size"], outputs["effect_size"], hdr, float_format="%.4g")
    atomic_write_csv(tabs["accuracy"], outputs["accuracy"], hdr, float_format="%.4g")
    pc = tabs["per_case"]
    n_cand = len(set(ds.effects)) + 1
    acc = float(pc["correct"].mean())
    ctrl = pc[pc["injected"] == "none"]
    det = pc[(pc["injected"] != "none") & pc["detectable"]]
    false_alarm = float((ctrl["identified"] != "none").mean()) if len(ctrl) else float("nan")
    acc_det = float(det["correct"].mean()) if len(det) else float("nan")
    summ = {"model": model_name, "cases": len(cases), "accuracy": acc, "overlap_rate": float(pc["overlap"].mean()),
            "chance_single": 1.0 / n_cand, "mean_shrink_share": float(pc["shrink_share"].mean()),
            "mean_abs_effect_size_error_share": float(tabs["effect_size"]["error_share_of_range"].abs().mean())
            if len(tabs["effect_size"]) else None,
            "false_alarm_rate": false_alarm if len(ctrl) else None, "controls": len(ctrl),
            "accuracy_detectable": acc_det if len(det) else None, "detectable_cases": len(det),
            "effect_cases_wrong_effect_named": int(((pc["injected"] != "none") & (pc["identified"] != "none")
                                                    & ~pc["correct"]).sum()),
            "effect_cases": int((pc["injected"] != "none").sum()),
            "goal_accuracy_detectable": 0.8, "goal_false_alarm": 0.1,
            "goals_met": bool(len(det) and len(ctrl) and acc_det >= 0.8 and false_alarm <= 0.1),
            "seconds": time.time() - t0}
    text = ["# Withheld-effect benchmark", "", hdr[0], "", hdr[1], "", "## Confusion matrix (rows injected, columns "
            "identified)", "", markdown_table(tabs["confusion"], ".0f"), "",
            f"Accuracy {acc:.2f} (chance for one guess among {n_cand} single candidates incl. none: "
            f"{1 / n_cand:.2f}); identified and injected share an effect in {summ['overlap_rate']:.2f} of cases.", "",
            "## Accuracy by detectability (goals: >= 0.80 on detectable cases, <= 0.10 false alarms)", "",
            f"False alarms on controls: {false_alarm:.2f} ({len(ctrl)} controls); correct on cases the power analysis "
            f"calls detectable: {acc_det:.2f} ({len(det)} cases); a wrong effect named in "
            f"{summ['effect_cases_wrong_effect_named']} of {summ['effect_cases']} effect cases. Intervals: exact "
            "(Clopper-Pearson) 95%.", "", markdown_table(tabs["accuracy"]), "",
            "## Per case", "", markdown_table(pc), "", "## Effect size", "",
            markdown_table(tabs["effect_size"]), ""]
    atomic_write_text("\n".join(text), outputs["report"])
    atomic_write_text(json.dumps(summ, indent=2), outputs["summary"])
    print("\nconfusion matrix (rows: injected, columns: identified):")
    print(tabs["confusion"].to_string(index=False))
    print("\naccuracy by detectability:")
    print(tabs["accuracy"].to_string(index=False))
    print(f"\nfalse alarms on controls {false_alarm:.2f} (goal <= 0.10); correct on detectable cases {acc_det:.2f} "
          f"(goal >= 0.80, {len(det)} cases); a wrong effect named in {summ['effect_cases_wrong_effect_named']} of "
          f"{summ['effect_cases']} effect cases; overall accuracy {acc:.2f} vs chance {1 / n_cand:.2f}; "
          f"{time.time() - t0:.0f} s")
    return tabs
