"""Pipeline stage of ``workflow/rules/postures.smk`` (issue 20): what testing in several postures buys."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from neckstrength.abc.smc import SMCSettings, abc_smc
from neckstrength.config import full_model_from_config, joint_settings, model_from_config
from neckstrength.io import atomic_write_csv
from neckstrength.pipeline.common import load_directions
from neckstrength.plotting import save_png
from neckstrength.postures.compare import ComparisonSettings, compare_postures, first_picks, summarize
from neckstrength.postures.datasets import posture_dataset, posture_grid
from neckstrength.postures.model import build_posture_set
from neckstrength.postures.tables import check_posture_tables, load_posture_tables, provenance
from neckstrength.seeds import derive_rng, seed_sequence


def _print(s: str) -> None:
    print(s, flush=True)


def comparison_settings(config: Mapping) -> ComparisonSettings:
    c = config["postures"]["comparison"]
    lo, hi = c["deficit"]
    return ComparisonSettings(int(c["n_deficit"]), int(c["n_normal"]), float(lo), float(hi), float(c["spread"]),
                              float(c["noise_rel"]), tuple(int(t) for t in c["t_values"]), float(c["threshold"]),
                              float(c["p_identify"]), float(c["change_cost"]), str(c["criterion"]))


def fig_postures(summary: pd.DataFrame, ident: pd.DataFrame, picks: pd.DataFrame, model_name: str, out_png) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ts = sorted(summary["t"].unique())
    groups = list(dict.fromkeys(summary["group"]))
    fig, axes = plt.subplots(1, len(ts) + 1, figsize=(5.2 * (len(ts) + 1), 4.6))
    x = np.arange(len(groups))
    for ax, t in zip(axes, ts):
        counts = []
        for k, (arm, col) in enumerate((("neutral", "tab:blue"), ("postures", "tab:orange"))):
            s = summary[(summary["t"] == t) & (summary["arm"] == arm)].groupby("group")[["rel_error", "rel_sd"]].mean()
            s = s.reindex(groups)
            counts.append(f"{arm} {int(summary[(summary['t'] == t) & (summary['arm'] == arm)]['n_tests'].max())}")
            ax.bar(x + (k - 0.5) * 0.4, s["rel_error"], 0.4, color=col, label=f"{arm}: error |E - f_a| / f_a")
            ax.plot(x + (k - 0.5) * 0.4, s["rel_sd"], "k_", ms=9, mew=2,
                    label="posterior sd / f_a (heuristic width)" if k == 0 else None)
        ax.set_xticks(x)
        ax.set_xticklabels(groups, rotation=60, ha="right", fontsize=8)
        ax.set_ylabel("|E - f_a| / f_a (bars), sd / f_a (marks)")
        ax.set_title(f"{model_name}, t = {t} (tests: {', '.join(counts)})", fontsize=10)
    ax = axes[-1]
    p = picks[picks["arm"] == "postures"]
    tab = pd.crosstab(p["t"], p["posture"], normalize="index")
    bottom = np.zeros(len(tab))
    for col in tab.columns:
        ax.bar(tab.index, tab[col], bottom=bottom, label=col)
        bottom += tab[col].to_numpy()
    ax.set_xlabel("test number t")
    ax.set_ylabel("share of participants")
    ax.set_title("posture of the t-th pick (neutral + postures)")
    ax.legend(fontsize=7, title="posture", title_fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1))
    # the bars' legend below the error panels, the postures' beside the share panel: neither covers a bar
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower left", bbox_to_anchor=(0.02, 0.0), ncol=len(labels), fontsize=8)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    save_png(fig, out_png)
    plt.close(fig)


def postures_compare(config: Mapping, model_name: str, directions_csv, out_groups, out_summary, out_identified,
                     out_picks, out_first, out_smc, out_checks, out_fig, out_json) -> pd.DataFrame:
    """Checks of the shipped posture tables; neutral-only vs neutral + postures on simulated participants (joint
    sequential estimator); ABC-SMC on one participant's mixed tests vs neutral tests only."""
    t_start = time.time()
    pc = config["postures"]
    full = full_model_from_config(config)
    tables = load_posture_tables(config["data"]["model_dir"], pc["postures"])
    checks = check_posture_tables(tables, full)
    atomic_write_csv(pd.DataFrame({"check": list(checks), "max_abs_error": list(checks.values())}), out_checks,
                     ["posture tables: OpenSim-free consistency checks (docs/postures.md); all passed"],
                     float_format="%.3g")
    neutral = model_from_config(full, config, model_name)
    pset = build_posture_set(full, neutral, tables, pc["postures"], pc["force_length"])
    d = load_directions(directions_csv)
    s = comparison_settings(config)
    jset = joint_settings(config, n_candidates=int(pc["comparison"]["n_candidates"]))
    key = f"postures/compare/{model_name}"
    groups, picks = compare_postures(pset, d, pc["deep_extensor_groups"][model_name], jset, s,
                                     seed_sequence(config["seed"], key), progress=_print)
    summary, ident = summarize(groups, picks, s)
    note = [f"issue 20: neutral-only vs neutral + postures ({', '.join(pset.postures)}), {model_name}, joint "
            f"sequential estimator ({s.criterion}, N {jset.n_candidates}), seed {config['seed']} key {key}",
            f"participants: {s.n_deficit} with deep extensors ({', '.join(pc['deep_extensor_groups'][model_name])}) at "
            f"U({s.deficit_low}, {s.deficit_high}) x baseline, {s.n_normal} normal; other groups baseline x "
            f"exp(N(0, {s.spread}^2)); forces x exp(N(0, {s.noise_rel}^2))"]
    atomic_write_csv(groups, out_groups, note, float_format="%.6g")
    atomic_write_csv(summary, out_summary, note + ["per condition, arm, t and group: mean over participants (and "
                                                   "sides) of |E - f_a| / f_a and of the posterior sd / f_a (heuristic: "
                                                   "not calibrated for s3m24 or mixed tests); n_tests "
                                                   "< t where the arm has fewer tests"], float_format="%.4g")
    atomic_write_csv(ident, out_identified, note + [f"identified = P(deep group < {s.threshold} x baseline) >= "
                                                    f"{s.p_identify} (mean over its sides); for normal participants "
                                                    "this is a false alarm"], float_format="%.4g")
    atomic_write_csv(picks, out_picks, note)
    atomic_write_csv(first_picks(picks), out_first, note + ["share of each posture among the first 5 picks and all "
                                                            "picks (arm neutral + postures)"], float_format="%.4g")
    # ABC-SMC on mixed tests: the first deficit participant, every test vs the neutral tests only, equal budget
    sm = pc["smc"]
    grid = posture_grid(pset, d)
    rng = derive_rng(config["seed"], f"postures/smc/{model_name}")
    from neckstrength.postures.compare import simulated_participants

    pid, cond, fa = simulated_participants(pset, pc["deep_extensor_groups"][model_name], s, rng)[0]
    rows = []
    for arm, labels in (("neutral", list(grid[grid["posture"] == "neutral"]["label"])), ("postures", None)):
        data = posture_dataset(pset, grid, pid, fa, labels)
        res = abc_smc(pset, data, pset.strengths, SMCSettings(n_particles=int(sm["n_particles"]),
                                                              budget=int(sm["budget"])),
                      derive_rng(config["seed"], f"postures/smc/{model_name}/{arm}"),
                      progress=_print)
        q = res.quantiles((0.05, 0.5, 0.95))
        mean = res.mean()
        for j, name in enumerate(pset.muscle_names):
            rows.append({"arm": arm, "n_tests": len(data.directions), "muscle": name, "f_a": fa[j], "mean": mean[j],
                         "q05": q[0, j], "q95": q[2, j], "rel_error": abs(mean[j] - fa[j]) / fa[j],
                         "rel_width90": (q[2, j] - q[0, j]) / fa[j], "n_simulations": res.n_simulations})
    atomic_write_csv(pd.DataFrame(rows), out_smc, [f"ABC-SMC (chapter 5 beyond the thesis) on mixed (posture, "
                                                   f"direction) tests vs neutral tests only: {model_name}, "
                                                   f"participant {pid} ({cond}), {sm['n_particles']} particles, "
                                                   f"budget {sm['budget']} each; seed key postures/smc/{model_name}"],
                     float_format="%.5g")
    fig_postures(summary, ident, picks, model_name, out_fig)
    info = {"model": model_name, "seed": int(config["seed"]), "seed_key": key, "postures": pset.postures,
            "force_length": pc["force_length"], "table_provenance": {k: provenance(config["data"]["model_dir"])[k]
                                                                     for k in ("inputs", "opensim_version", "date_utc")},
            "seconds": round(time.time() - t_start, 1)}
    tmp = Path(str(out_json) + ".tmp")
    tmp.write_text(json.dumps(info, indent=2))
    tmp.replace(out_json)
    return summary
