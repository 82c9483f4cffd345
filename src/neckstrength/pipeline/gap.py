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
    derive_rng,
    diagnosis_settings,
    gap_blind_dataset,
    gap_context,
    gap_settings_text,
    gap_withheld_activations,
)
from neckstrength.gap.benchmark import run_benchmark
from neckstrength.gap.diagnose import DiagnosisSettings
from neckstrength.gap.report import markdown_table
from neckstrength.gap.run import run_diagnosis
from neckstrength.io import atomic_write_csv, atomic_write_text
from neckstrength.pipeline.common import load_directions


def gap_diagnose(config: Mapping, model_name: str, dataset: str, directions_csv: str | Path | pd.DataFrame,
                 outputs: Mapping[str, str | Path]) -> dict:
    """Diagnose one data set: tables, figures, report.md and summary.json (keys of ``outputs``)."""
    directions = directions_csv if isinstance(directions_csv, pd.DataFrame) else load_directions(directions_csv)
    ctx = gap_context(config, model_name, directions)
    data = gap_blind_dataset(config, ctx, directions, dataset)
    s = diagnosis_settings(config)
    return run_diagnosis(ctx, data, s, directions, gap_withheld_activations(config, ctx, dataset), outputs,
                         gap_settings_text(config, s), model_name)


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
                     "chosen_theta": s["chosen_theta"], "p_best": s["p_best_chosen"],
                     "gap_before": s["gap_before"], "gap_after": s["gap_after"],
                     "rms_before": s["rms_before"], "rms_after": s["rms_after"],
                     "D_fit_base": s["D_fit_base"], "D_fit_chosen": s["D_fit_chosen"],
                     "a3_mean": s.get("a3_mean", np.nan), "a3_model_mean_base": s.get("a3_model_mean_base", np.nan),
                     "a3_model_mean_chosen": s.get("a3_model_mean_chosen", np.nan),
                     "a3_pearson_base": s.get("a3_pearson_base", np.nan),
                     "a3_pearson_chosen": s.get("a3_pearson_chosen", np.nan)})
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
                   "unreachable": "", "chosen": df["chosen"].mode().iloc[0], "chosen_theta": ""})
    df = pd.concat([df, pd.DataFrame([pooled])], ignore_index=True)
    atomic_write_csv(df, out_csv, [f"gap diagnosis pooled over data sets ({model_name}): where / which / how far, "
                                   "held-out gap = 1 - D_cv (Eq. 5.5 on held-out directions)",
                                   "a3_*: Table A.3 (withheld) vs the model's mean activation of the EMG-recorded "
                                   "groups; base = fitted model, chosen = with the chosen effect"],
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


def gap_benchmark(config: Mapping, model_name: str, directions_csv: str | Path,
                        outputs: Mapping[str, str | Path]) -> dict[str, pd.DataFrame]:
    """Withheld-effect benchmark; prints the confusion matrix (to the rule's log)."""
    t0 = time.time()
    directions = load_directions(directions_csv)
    ctx = gap_context(config, model_name, directions)
    b = config["gap"]["benchmark"]
    bs = benchmark_settings(config)
    ds = diagnosis_settings(config, b.get("diagnosis_effects"))
    ds = DiagnosisSettings(**{**ds.__dict__, "folds": b.get("folds", ds.folds),
                              "bootstrap": b.get("bootstrap", ds.bootstrap), "starts": b.get("starts", ds.starts),
                              "reach_samples": 0, "reach_iter": 0})
    rng = derive_rng(config["seed"], f"gap-benchmark/{model_name}")
    cases, diags, tabs = run_benchmark(ctx, bs, ds, rng, progress=lambda m: print(f"[{time.time() - t0:.0f} s] {m}",
                                                                                  flush=True))
    hdr = [f"withheld-effect benchmark ({model_name}): {len(cases)} cases, noise {bs.noise_rel} (log-normal SD), "
           f"strength spread {bs.strength_spread}, effect size {bs.clear_size} of the way to the far bound",
           f"diagnosis effects: {', '.join(ds.effects)}; the diagnosis saw forces only"]
    atomic_write_csv(tabs["confusion"], outputs["confusion"], hdr + ["rows: injected effect; columns: identified"])
    atomic_write_csv(tabs["per_case"], outputs["cases"], hdr, float_format="%.4g")
    atomic_write_csv(tabs["effect_size"], outputs["effect_size"], hdr, float_format="%.4g")
    pc = tabs["per_case"]
    n_cand = len(set(ds.effects)) + 1
    acc = float(pc["correct"].mean())
    summ = {"model": model_name, "cases": len(cases), "accuracy": acc, "overlap_rate": float(pc["overlap"].mean()),
            "chance_single": 1.0 / n_cand, "mean_shrink_share": float(pc["shrink_share"].mean()),
            "mean_abs_effect_size_error_share": float(tabs["effect_size"]["error_share_of_range"].abs().mean())
            if len(tabs["effect_size"]) else None, "seconds": time.time() - t0}
    text = ["# Withheld-effect benchmark", "", hdr[0], "", hdr[1], "", "## Confusion matrix (rows injected, columns "
            "identified)", "", markdown_table(tabs["confusion"], ".0f"), "",
            f"Accuracy {acc:.2f} (chance for one guess among {n_cand} single candidates incl. none: "
            f"{1 / n_cand:.2f}); identified and injected share an effect in {summ['overlap_rate']:.2f} of cases.", "",
            "## Per case", "", markdown_table(pc), "", "## Effect size", "",
            markdown_table(tabs["effect_size"]), ""]
    atomic_write_text("\n".join(text), outputs["report"])
    atomic_write_text(json.dumps(summ, indent=2), outputs["summary"])
    print("\nconfusion matrix (rows: injected, columns: identified):")
    print(tabs["confusion"].to_string(index=False))
    print(f"\naccuracy {acc:.2f} vs chance {1 / n_cand:.2f}; mean shrinkage share {summ['mean_shrink_share']:.2f}; "
          f"{time.time() - t0:.0f} s")
    return tabs
