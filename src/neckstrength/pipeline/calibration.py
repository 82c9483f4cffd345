"""Pipeline stages of the calibration checks (issue 18), one function per rule (workflow/rules/calibration.smk)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import pandas as pd

from neckstrength.abc.smc import SMCSettings
from neckstrength.config import abc_settings, derive_rng, full_model_from_config, joint_settings, model_from_config
from neckstrength.estimation.datasets import thesis_f_actual
from neckstrength.io import atomic_write_csv
from neckstrength.pipeline.common import load_directions


def sbc_settings_for(config: Mapping, model_name: str):
    """(SBCSettings, SMCSettings, JointSettings) of ``calibration`` (per-model sizes) for ``model_name``."""
    from neckstrength.calibration.sbc import SBCSettings

    c = config["calibration"]
    per = c["model_settings"][model_name]
    sbc = SBCSettings(n_participants=int(per["n_participants"]), noise=float(c["noise"]),
                      methods=tuple(per["methods"]), checkpoints=tuple(int(t) for t in c["checkpoints"]),
                      bootstrap_direction=config["chapter5"]["bootstrap_direction"])
    sc = config["chapter5"]["smc"]
    smc = SMCSettings(n_particles=int(per["smc"]["n_particles"]), budget=int(per["smc"]["budget"]),
                      prior_sigma=float(sc["prior_sigma"]), quantile=float(sc["quantile"]),
                      epsilon=float(config["chapter5"]["epsilon"]))
    joint = joint_settings(config, **dict(per["joint"]))
    return sbc, smc, joint


def calibration_sbc(config: Mapping, model_name: str, directions_csv, out_rows, out_summary, out_groups) -> pd.DataFrame:
    """SBC of Algorithm 4's sigma_c (heuristic), ABC-SMC and the joint sequential posterior on ``model_name``."""
    from neckstrength.calibration.sbc import coverage_summary, run_sbc

    full = full_model_from_config(config)
    model = model_from_config(full, config, model_name)
    d = load_directions(directions_csv)
    f_ref = thesis_f_actual(model, config["data"]["thesis_dir"], "norm")
    sbc, smc, joint = sbc_settings_for(config, model_name)
    seed = config["seed"]
    print(f"SBC of {model_name}: {sbc}\nABC-SMC {smc}\njoint {joint}\nseed {seed}; streams "
          f"'calibration/{model_name}/<method>' + participant index", flush=True)
    df = run_sbc(model, d, f_ref, sbc, abc_settings(config, model_name), smc, joint,
                 lambda method, i: derive_rng(seed, f"calibration/{model_name}/{method}", i),
                 progress=lambda s: print(s, flush=True))
    summ = coverage_summary(df)
    groups = coverage_summary(df, by=("group",))
    hdr = [f"Simulation-based calibration, {model_name}: {sbc.n_participants} simulated participants per method, "
           f"truths from each method's prior around the 'norm' f_a, forces only, log-normal noise sd {sbc.noise}",
           "alg4: f_c (1 +- z sigma_c) read as a normal interval; sigma_c is a sampling-width HEURISTIC, not a "
           "posterior width (coverage_reported_1sigma: the printed f_c (1 +- sigma_c))",
           f"smc: {smc.n_particles} particles, budget {smc.budget}; joint: {joint.n_candidates} candidates, "
           f"kernel noise_rel {joint.noise_rel}, n_moves {joint.n_moves}, max_resamples {joint.max_resamples}; "
           f"seed {seed}",
           "calibrated90: 90% coverage within [0.85, 0.95] (the issue-18 goal)"]
    print("\n".join(hdr))
    print(summ.to_string(index=False))
    atomic_write_csv(df, out_rows, hdr, float_format="%.6g")
    atomic_write_csv(summ, out_summary, hdr, float_format="%.4g")
    atomic_write_csv(groups, out_groups, hdr, float_format="%.4g")
    return summ


def calibration_figures(config: Mapping, model_name: str, rows_csv, out_ranks, out_coverage) -> None:
    from neckstrength.calibration.plots import coverage_plot, rank_histograms

    df = pd.read_csv(rows_csv, comment="#")
    n = df.groupby("method")["participant"].nunique().to_dict()
    sizes = ", ".join(f"{k} {v}" for k, v in n.items())
    rank_histograms(df, out_ranks, f"SBC rank (PIT) histograms per muscle group, {model_name} "
                    f"(participants: {sizes}); flat = calibrated, U = too narrow, hump = too wide")
    coverage_plot(df, out_coverage, f"Coverage of central 50% / 90% intervals, {model_name} (participants: {sizes})")


def calibration_outputs_exist(paths) -> bool:  # pragma: no cover - helper for interactive use
    return all(Path(p).exists() for p in paths)


def calibration_misfit(config: Mapping, model_name: str, directions_csv, out_rows, out_summary) -> pd.DataFrame:
    """Coverage of the joint posterior with the nominal and the misfit-aware kernel, on data from the model itself
    and from a richer truth (the same kinematics, one strength per muscle element)."""
    from neckstrength.calibration.misfit import MisfitSettings, misfit_coverage, misfit_summary
    from neckstrength.estimation.datasets import model_directions_table

    c = dict(config["calibration"]["misfit"])
    c.update(c.pop("model_settings", {}).get(model_name, {}))
    full = full_model_from_config(config)
    model = model_from_config(full, config, model_name)
    elements = model_from_config(full, config, f"{model.kinematic}-independent")
    dirs = load_directions(directions_csv)
    d, U = model_directions_table(model, dirs)
    _, Ue = model_directions_table(elements, dirs)
    noise = float(config["calibration"]["noise"])
    st = MisfitSettings(n_participants=int(c["n_participants"]), folds=int(c["folds"]), noise=noise,
                        element_sd=float(c["element_sd"]))
    joint = joint_settings(config, n_candidates=int(c["n_candidates"]), noise_rel=noise)
    seed = config["seed"]
    print(f"misfit check of {model_name} (richer truth: {elements.name}, {elements.m} elements): {st}\n{joint}\n"
          f"seed {seed}; streams 'calibration/misfit/{model_name}/<what>/<truth>' + participant", flush=True)
    df = misfit_coverage(model, elements, full.strengths, list(d["name"]), U, Ue, d["force_scale"].to_numpy(float),
                         st, joint, lambda k, i: derive_rng(seed, f"calibration/misfit/{model_name}/{k}", i),
                         progress=lambda s: print(s, flush=True))
    summ = misfit_summary(df)
    hdr = [f"Coverage under misspecification, {model_name}: {st.n_participants} participants per truth; 'well' from "
           f"the model's prior, 'rich' from {elements.name} (each of {elements.m} element strengths x exp({st.element_sd} "
           f"z)); forces with log-normal noise sd {noise}; joint posterior on every direction, {joint.n_candidates} "
           "candidates",
           f"kernel 'nominal': noise_rel {noise}; 'misfit': sqrt(noise_rel^2 + misfit^2), misfit from {st.folds} "
           f"held-out folds of directions; seed {seed}; calibrated90 = 90% coverage in [0.85, 0.95]"]
    print(summ.to_string(index=False))
    atomic_write_csv(df, out_rows, hdr, float_format="%.6g")
    atomic_write_csv(summ, out_summary, hdr, float_format="%.4g")
    return summ
