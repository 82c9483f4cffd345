"""Pipeline stages of the sim-to-real gap diagnosis (issue 8), one function per rule."""

from __future__ import annotations

import json
import time
import zlib
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from neckstrength.config import benchmark_settings, diagnosis_settings, full_model_from_config, model_from_config
from neckstrength.estimation.datasets import build_dataset, model_directions_table, participant_dataset
from neckstrength.gap.benchmark import run_benchmark
from neckstrength.gap.diagnose import BlindData, DiagnosisSettings, diagnose
from neckstrength.gap.effects import GapContext
from neckstrength.gap.report import activation_check, markdown_table, write_figures, write_report
from neckstrength.io import atomic_write_csv, atomic_write_text, read_activations
from neckstrength.pipeline.common import load_directions

DATASET_FILES = ("residuals", "planes", "components", "muscles", "effects", "strengths", "activation_check")


FIGURES = ("radar", "where", "effects", "activation")


def gap_context(config: Mapping, model_name: str, directions: pd.DataFrame) -> GapContext:
    g = config["gap"]
    full = full_model_from_config(config)
    model = model_from_config(full, config, model_name)
    d, _ = model_directions_table(model, directions)
    tie = g.get("tie_sides")
    if tie is None:
        tie = bool(config["chapter5"]["settings"].get(model_name, {}).get("tie_sides", False))
    emg = tuple(config["chapter5"].get("emg_groups", {}).get(model_name, []))
    return GapContext(full, model, d, np.asarray(config["geometry"]["head"]["centre"], float), emg,
                      tuple(g["shoulder_muscles"]), bool(tie), dict(g.get("effect_settings") or {}))


def _measurements(config: Mapping) -> str:
    return config["gap"].get("measurements") or config["data"]["measurements"]


def blind_dataset(config: Mapping, ctx: GapContext, directions: pd.DataFrame, dataset: str) -> BlindData:
    """Forces only: a participant column of the measurement table, or a simulated data set ('norm', 'weak')."""
    c5 = dict(config["chapter5"], participant_emg="none")
    if dataset in ("norm", "weak"):
        data = build_dataset(ctx.model, directions, dataset, c5, config["data"]["thesis_dir"],
                             _measurements(config), config["data"]["activations"])
    else:
        data = participant_dataset(ctx.model, directions, dataset, _measurements(config))
    if list(data.directions) != list(ctx.directions["name"]):
        raise ValueError("data set directions do not match the model's directions")
    return BlindData(dataset, data.forces)


def withheld_activations(config: Mapping, ctx: GapContext, dataset: str) -> np.ndarray | None:
    """Table A.3 column of ``dataset`` in direction order, or None when it has none (e.g. simulated)."""
    path = config["data"].get("activations")
    if not path or not Path(path).exists():
        return None
    act = read_activations(path)
    if dataset not in act.columns:
        return None
    return act[dataset].reindex(ctx.directions["name"]).to_numpy(float)


def _settings_text(config: Mapping, s: DiagnosisSettings) -> str:
    g = config["gap"]
    return "\n".join([f"- effects: {', '.join(s.effects)}",
                      f"- effect settings: `{json.dumps(g.get('effect_settings') or {})}`",
                      f"- grid points per effect: {s.grid_points}; folds: {s.folds}; starts per fit: {s.starts} "
                      f"(spread {s.start_spread} in log strength); pairs of the best {s.pairs_top} effects on the "
                      f"best {s.pair_grid_top} grid points of each",
                      f"- fit: {json.dumps(g['fit'])}; penalty {s.penalty} per extra parameter; bootstrap {s.bootstrap}",
                      f"- effect-parameter refinement iterations (all-direction fit): {s.refine_iter}",
                      f"- reach envelope: {s.reach_samples} samples, {s.reach_iter} gradient iterations",
                      f"- seed {config['seed']}"])


def stage_gap_diagnose(config: Mapping, model_name: str, dataset: str, directions_csv: str | Path | pd.DataFrame,
                       outputs: Mapping[str, str | Path]) -> dict:
    """Diagnose one data set: tables, figures, report.md and summary.json (keys of ``outputs``)."""
    t0 = time.time()
    directions = directions_csv if isinstance(directions_csv, pd.DataFrame) else load_directions(directions_csv)
    ctx = gap_context(config, model_name, directions)
    data = blind_dataset(config, ctx, directions, dataset)
    s = diagnosis_settings(config)
    rng = np.random.default_rng([config["seed"], zlib.crc32(f"gap/{model_name}/{dataset}".encode())])
    print(f"gap diagnosis: model {model_name}, data set {dataset}, {ctx.K} directions, forces only", flush=True)
    diag = diagnose(ctx, [data], s, rng, progress=lambda m: print(f"[{time.time() - t0:.0f} s] {m}", flush=True))[0]
    a3 = withheld_activations(config, ctx, dataset)
    act = activation_check(diag, a3)
    hdr = [f"gap diagnosis (issue 8): model {model_name}, data set {dataset}; forces only (Table A.3 withheld)"]
    tables = {"residuals": diag.residuals, "planes": diag.planes, "components": diag.components,
              "muscles": diag.muscles, "effects": diag.effects, "strengths": diag.strengths,
              "activation_check": act if len(act) else pd.DataFrame(
                  {"candidate": [], "pearson_r": [], "spearman_rho": [], "model_mean": [], "a3_mean": [],
                   "mean_abs_diff": []})}
    for k, df in tables.items():
        atomic_write_csv(df, outputs[k], hdr, float_format="%.6g")
    figs = {k: outputs[f"fig_{k}"] for k in FIGURES if f"fig_{k}" in outputs}
    if a3 is None:
        Path(figs["activation"]).parent.mkdir(parents=True, exist_ok=True)
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 2))
        ax.text(0.5, 0.5, f"no withheld activation data for {dataset}", ha="center", va="center")
        ax.axis("off")
        fig.savefig(figs["activation"], dpi=80)
        plt.close(fig)
    write_figures(diag, directions, figs, a3)
    rel = {k: Path(v).name for k, v in figs.items()}
    if a3 is None:
        rel.pop("activation")
    summary = dict(diag.summary)
    if len(act):
        a = act.set_index("candidate")
        for c, tag in (("none", "base"), (summary["chosen"], "chosen")):
            if c in a.index:
                summary[f"a3_pearson_{tag}"] = float(a.loc[c, "pearson_r"])
                summary[f"a3_model_mean_{tag}"] = float(a.loc[c, "model_mean"])
                summary[f"a3_mean_abs_diff_{tag}"] = float(a.loc[c, "mean_abs_diff"])
        summary["a3_mean"] = float(a["a3_mean"].iloc[0])
    summary["seconds"] = time.time() - t0
    write_report(diag, outputs["report"], rel, act, _settings_text(config, s))
    atomic_write_text(json.dumps(summary, indent=2, default=float), outputs["summary"])
    print(f"done in {time.time() - t0:.0f} s: chosen {summary['chosen']}, held-out gap "
          f"{summary['gap_before']:.3f} -> {summary['gap_after']:.3f}")
    return summary


def stage_gap_pooled(config: Mapping, model_name: str, datasets: Sequence[str], summaries: Sequence[str],
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


def stage_gap_benchmark(config: Mapping, model_name: str, directions_csv: str | Path,
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
    rng = np.random.default_rng([config["seed"], zlib.crc32(f"gap-benchmark/{model_name}".encode())])
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
