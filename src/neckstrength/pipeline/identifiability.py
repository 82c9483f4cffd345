"""Pipeline stage of ``workflow/rules/identifiability.smk`` (issue 31 item 1): misfit profiles of the muscle groups,
the noise level below which a deficit is distinguishable, and their figure."""

from __future__ import annotations

import time
from typing import Mapping

import numpy as np
import pandas as pd

from neckstrength.config import full_model_from_config, identifiability_settings, model_from_config
from neckstrength.estimation.datasets import emg_mask, model_directions_table, thesis_f_actual
from neckstrength.identifiability.noise import RULE
from neckstrength.identifiability.profile import neutral_battery, posture_battery
from neckstrength.identifiability.study import run_study
from neckstrength.io import atomic_write_csv
from neckstrength.pipeline.common import load_directions, provenance_lines
from neckstrength.seeds import derive_rng
from neckstrength.wrench import solve


def _print(s: str) -> None:
    print(s, flush=True)


def batteries_for(config: Mapping, model_name: str, directions: pd.DataFrame, st) -> dict:
    """protocol -> (truth strengths -> Battery): neutral tests; + every posture of config ``postures.postures``;
    neutral tests with the recorded groups' activation bounded to the truth's +- ``emg_band``."""
    full = full_model_from_config(config)
    model = model_from_config(full, config, model_name)
    d, U = model_directions_table(model, directions)
    labels = list(d["name"])
    ic = config["identifiability"]
    out = {"neutral": lambda f: neutral_battery(model, labels, U)}
    if "postures" in st.protocols:
        from neckstrength.postures.datasets import posture_grid
        from neckstrength.postures.model import build_posture_set
        from neckstrength.postures.tables import load_posture_tables

        pc = config["postures"]
        tables = load_posture_tables(config["data"]["model_dir"], pc["postures"])
        pset = build_posture_set(full, model, tables, pc["postures"], pc["force_length"])
        grid = posture_grid(pset, directions)
        Ug = grid[[c for c in grid.columns if c.startswith("u") and c[1:].isdigit()]].to_numpy(float)
        pb = posture_battery(pset, list(grid["label"]), Ug, list(grid["posture"]))
        out["postures"] = lambda f: pb
    if "emg" in st.protocols:
        groups = ic["emg"]["groups"].get(model_name, [])
        mask = emg_mask(model, groups)
        band = float(ic["emg"]["band"])
        if mask.any():
            def emg_battery(f):
                _, alpha, status = solve(model, np.asarray(f, float)[None, :], U)
                lb, ub = np.zeros((len(U), model.m)), np.ones((len(U), model.m))
                lb[:, mask] = np.clip(alpha[0][:, mask] - band, 0.0, 1.0)
                ub[:, mask] = np.clip(alpha[0][:, mask] + band, 0.0, 1.0)
                return neutral_battery(model, labels, U, lb, ub)

            out["emg"] = emg_battery
    return model, out


def fig_profiles(prof: pd.DataFrame, deficit_group: str, model_name: str, out_png) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bounds = list(dict.fromkeys(prof["bounds"]))
    fig, axes = plt.subplots(2, len(bounds), figsize=(6.2 * len(bounds), 9.0), squeeze=False)
    for c, b in enumerate(bounds):
        # top: every profiled group on 'weak' (neutral tests)
        ax = axes[0, c]
        p = prof[(prof["bounds"] == b) & (prof["protocol"] == "neutral") & (prof["dataset"] == "weak")]
        cmap = plt.get_cmap("tab20")
        for k, (g, q) in enumerate(p.groupby("group", sort=False)):
            ax.plot(q["r"], q["rms"], "-o", ms=3, color=cmap(k % 20), lw=2.4 if g == deficit_group else 1.0,
                    label=g)
        ax.set_xlabel("fixed group's factor r (x 'norm' f_a)")
        ax.set_ylabel("best RMS log residual")
        lo, hi = p["lo"].iloc[0], p["hi"].iloc[0]
        n = int(p["n_tests"].iloc[0])
        ax.set_title(f"{model_name} 'weak', {n} neutral tests: each group fixed,\nothers free in {lo:g}-{hi:g}x ({b})",
                     fontsize=10)
        ax.legend(fontsize=7, ncol=2, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        # bottom: the deficit group on the deficit truths, per protocol
        ax = axes[1, c]
        q = prof[(prof["bounds"] == b) & (prof["group"] == deficit_group)
                 & prof["dataset"].str.match(r"^(deficit\d+|weak)$")]
        styles = {"neutral": "-", "postures": "--", "emg": ":"}
        colors = dict(zip(sorted(q["dataset"].unique()), plt.get_cmap("tab10").colors))
        for (proto, ds), s in q.groupby(["protocol", "dataset"], sort=False):
            ax.plot(s["r"], s["rms"], styles.get(proto, "-"), marker="o", ms=3, color=colors[ds],
                    label=f"{ds}, {proto} ({int(s['n_tests'].iloc[0])} tests)")
        ax.axvline(1.0, color="0.6", lw=0.8)
        # a profile point where the bounds leave a test unproducible (residual log 1e-3) would squash the rest:
        # the axis stops above the others and says how many points lie beyond it
        v = q["rms"].to_numpy(float)
        v = v[np.isfinite(v)]
        if len(v) and v.max() > 5 * np.quantile(v, 0.9):
            top = 1.3 * np.quantile(v, 0.9)
            n_off = int((v > top).sum())
            ax.set_ylim(0, top)
            ax.text(0.02, 0.97, f"{n_off} point(s) above {top:.3f} not shown",
                    transform=ax.transAxes, fontsize=7, va="top")
        ax.set_xlabel(f"{deficit_group} factor r (x 'norm' f_a)")
        ax.set_ylabel("best RMS log residual")
        ax.set_title(f"{deficit_group} profile on deficit truths ({b} bounds)", fontsize=10)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)


def identifiability_profiles(config: Mapping, model_name: str, directions_csv, out_profiles, out_dist,
                             out_fig) -> pd.DataFrame:
    t0 = time.time()
    st = identifiability_settings(config, model_name)
    directions = load_directions(directions_csv)
    model, batteries = batteries_for(config, model_name, directions, st)
    normal = thesis_f_actual(model, config["data"]["thesis_dir"], "norm")
    weak = thesis_f_actual(model, config["data"]["thesis_dir"], "weak")
    seed = int(config["seed"])
    _print(f"identifiability of {model_name}: {st}\nseed {seed}; streams 'identifiability/{model_name}/<key>'")
    prof, dist = run_study(model_name, normal, weak, batteries, st,
                           lambda key: derive_rng(seed, f"identifiability/{model_name}/{key}"), _print)
    s = st.profile
    hdr = provenance_lines(config, f"identifiability profiles of {model_name} (issue 31 item 1)") + [
        f"normal = the thesis's 'norm' f_a; r = the profiled group's factor (both sides tied); the other groups' factors "
        f"(sides tied) minimise the RMS log residual within the bounds ({', '.join(f'{n} {lo:g}-{hi:g}x' for n, lo, hi in s.bounds)})",
        f"batched box-constrained Levenberg-Marquardt in log factors: the normal start + {s.n_starts} uniform starts in "
        f"the log box (seeded), then {'a continuation round from the neighbouring grid points' if s.continuation else 'no continuation'}; "
        f"max_iter {s.max_iter}; every value is an upper bound on the minimum (best of the starts)",
        f"highs_max_rel_diff: the optimum's forces re-solved by fresh HiGHS LPs built here (asserted <= {st.check_rtol:g}); "
        f"a test the candidate cannot produce gets residual log(1e-3) (n_unproducible)",
        f"protocols: neutral (the model's test directions), postures (config postures.postures), emg (groups "
        f"{config['identifiability']['emg']['groups'].get(model_name, [])} bounded to the truth's activation "
        f"+- {config['identifiability']['emg']['band']})",
        f"truths: norm, weak (Table 5.{ {'p2m7': 1, 'p3m12': 2, 's3m24': 3}[model_name] } f_a), deficitNN = norm with "
        f"{st.deficit_group} x (1 - NN%), participantN = norm x exp(N(0, {st.population_sd}^2)) per group, "
        f"{st.deficit_group} then x {1 - st.participant_deficit:g}; seed {seed}"]
    atomic_write_csv(prof, out_profiles, hdr, float_format="%.6g")
    atomic_write_csv(dist, out_dist, hdr + [RULE + f"; sigma_ref {st.sigma_ref}: sigma in log-force units "
                                                    "(0.05 = 5% noise)"], float_format="%.5g")
    fig_profiles(prof, st.deficit_group, model_name, out_fig)
    if not dist.empty:
        _print(dist.drop(columns=["on_bounds"]).to_string(index=False))
    _print(f"done in {time.time() - t0:.1f} s; largest batched-vs-HiGHS relative difference "
           f"{prof['highs_max_rel_diff'].max():.2e}")
    return dist
