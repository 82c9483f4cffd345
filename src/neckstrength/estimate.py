"""``neckstrength estimate``: strengths of one participant from a user's table (or trials), no config to write.

:func:`run_estimate` takes the default configuration (``config/config.yaml``; every science setting from its
``chapter5`` / ``chapter6`` sections), points it at the user's max-force table and calls the very functions the
pipeline rules call: :func:`neckstrength.pipeline.chapter5.chapter5_estimate` (+ ``chapter5_figures``) for
Algorithm 4, then ``chapter5_smc`` for ABC-SMC (compared with Algorithm 4 at equal budget, as in the
pipeline), and :func:`neckstrength.pipeline.chapter6.chapter6_joint` for the joint estimator.

Directions without a value for the participant (e.g. no valid trial) are dropped from the fit and listed;
the Eq. 5.3 bootstrap direction must be present. The seed is the config's unless given, and is recorded in
``run.json`` with every input.
"""

from __future__ import annotations

import copy
import json
import time
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
import pandas as pd

from neckstrength import __version__
from neckstrength.io import DataValidationError, atomic_write_csv, atomic_write_text, read_measurements

METHODS = ("alg4", "smc", "joint")


def _prepare_inputs(cfg: Mapping, model_name: str, participant: str, measurements: str | Path,
                    activations: str | Path | None, out: Path, log: Callable[[str], None]) -> dict:
    """Directions table (directions with a value only) and the participant's table, written into ``out``."""
    from neckstrength.config import build_directions, full_model_from_config, model_from_config
    from neckstrength.estimation.datasets import model_directions_table

    d = build_directions(cfg)
    names = list(d["name"])
    meas = read_measurements(measurements, names)
    if participant not in meas.columns:
        raise DataValidationError(measurements, f"no column for participant '{participant}' (columns: "
                                  f"{', '.join(meas.columns)})", field_name=participant)
    model = model_from_config(full_model_from_config(cfg), cfg, model_name)
    dm, _ = model_directions_table(model, d)
    col = meas[participant].reindex(names)
    used = [n for n in dm["name"] if np.isfinite(col.get(n, np.nan))]
    dropped = [n for n in dm["name"] if n not in used]
    boot = cfg["chapter5"]["bootstrap_direction"]
    if boot not in used:
        raise DataValidationError(measurements, f"participant {participant} has no value in the bootstrap direction "
                                  f"'{boot}' (Eq. 5.3 scales the baseline there)", field_name=participant)
    if dropped:
        log(f"note: {participant} has no value in {len(dropped)} direction(s) of {model_name}: {', '.join(dropped)}; "
            f"estimating from the other {len(used)}")
    keep = d["name"].isin(used) | ~d["name"].isin(list(dm["name"]))
    d_used = d[keep].reset_index(drop=True)
    if model.planar:       # planar models use the sagittal directions; keep only those with a value
        d_used = d_used[~(d_used["sagittal"] & ~d_used["name"].isin(used))].reset_index(drop=True)
    dirs_csv = out / "directions.csv"
    atomic_write_csv(d_used, dirs_csv, [f"test directions used for {participant} ({model_name}); dropped (no value): "
                                        f"{', '.join(dropped) or 'none'}"], float_format="%.8g")
    mtab = pd.DataFrame({"direction": used, participant: col.reindex(used).to_numpy(float)})
    meas_csv = out / "input_max_force.csv"
    atomic_write_csv(mtab, meas_csv, [f"input: {measurements}, column {participant}", f"units: {participant}=N"],
                     float_format="%.4f")
    act_csv = None
    if activations is not None:
        from neckstrength.io import read_activations

        act = read_activations(activations, names)
        if participant in act.columns:
            atab = pd.DataFrame({"direction": used, participant: act[participant].reindex(used).to_numpy(float)})
            act_csv = out / "input_activation.csv"
            atomic_write_csv(atab, act_csv, [f"input: {activations}, column {participant}",
                                             f"units: {participant}=1"], float_format="%.4f")
    return {"directions": dirs_csv, "measurements": meas_csv, "activations": act_csv, "used": used,
            "dropped": dropped}


def run_estimate(config: Mapping, model_name: str, participant: str, measurements: str | Path, out_dir: str | Path,
                 method: str = "alg4", activations: str | Path | None = None, seed: int | None = None,
                 emg: str = "none", max_iter: int | None = None, threads: int = 1,
                 criterion: str = "joint_eig", log: Callable[[str], None] = print, figures: bool = True) -> dict:
    """Estimate ``participant``'s strengths with ``method`` (alg4, smc, joint); outputs under ``out_dir``.

    Returns a summary dict (also written as ``run.json``). Progress goes to ``log``.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, not {method!r}")
    t0 = time.time()
    cfg = copy.deepcopy(dict(config))
    if seed is not None:
        cfg["seed"] = int(seed)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    prep = _prepare_inputs(cfg, model_name, participant, measurements, activations, out, log)
    cfg["data"] = {**cfg["data"], "measurements": str(prep["measurements"]),
                   "activations": str(prep["activations"] or cfg["data"]["activations"])}
    if emg != "none" and prep["activations"] is None:
        raise ValueError(f"--emg {emg} needs an activation table with a column for {participant}")
    cfg["chapter5"] = {**cfg["chapter5"], "participant_emg": emg}
    cfg["chapter6"] = {**cfg["chapter6"], "participant_emg": emg}
    if max_iter is not None:
        st = copy.deepcopy(cfg["chapter5"]["settings"])
        st.setdefault(model_name, {})["max_iter"] = int(max_iter)
        cfg["chapter5"]["settings"] = st
    summary = {"participant": participant, "model": model_name, "method": method, "seed": int(cfg["seed"]),
               "measurements": str(measurements), "activations": None if activations is None else str(activations),
               "emg": emg, "directions_used": prep["used"], "directions_dropped": prep["dropped"],
               "neckstrength": __version__}
    if method in ("alg4", "smc"):
        from neckstrength.pipeline.chapter5 import OUTPUTS, chapter5_estimate, chapter5_figures

        outputs = {k: out / f"{k}.csv" for k in OUTPUTS}
        outputs["summary"] = out / "summary.json"
        chapter5_estimate(cfg, model_name, participant, prep["directions"], outputs, threads=threads)
        figs = {"traces": out / "fig_estimate_traces.png", "dk_hist": out / "fig_dk_hist.png",
                "d_dir": out / "fig_d_by_direction.png", "parallel": out / "fig_parallel.png",
                "radar": out / "fig_fit_radar.png"}
        if figures:
            chapter5_figures(cfg, model_name, participant, prep["directions"],
                              {k: str(v) for k, v in outputs.items()}, figs)
        meta = json.loads((out / "summary.json").read_text())
        est = pd.read_csv(outputs["estimate"], comment="#")
        summary.update({"iterations": meta["iterations"], "converged": meta["converged"], "D_fc": meta["D_fc"],
                        "scale_a": meta["scale_a"], "estimate": str(outputs["estimate"])})
        table = est.groupby("parameter", sort=False)[["f_base", "f_0", "f_c", "sigma_c"]].first().reset_index()
        if method == "smc":
            from neckstrength.pipeline.chapter5 import chapter5_smc

            smc = chapter5_smc(cfg, model_name, participant, prep["directions"], outputs["estimate"],
                                out / "summary.json", out / "smc_vs_alg4.csv", out / "smc_generations.csv")
            summary["smc"] = str(out / "smc_vs_alg4.csv")
            table = smc[["muscle", "alg4_f_c", "smc_mean", "smc_q05", "smc_q95"]]
    else:
        from neckstrength.pipeline.chapter6 import chapter6_joint

        cfg["chapter6"] = {**cfg["chapter6"], "joint": {**cfg["chapter6"].get("joint", {}), "criteria": [criterion]}}
        chapter6_joint(cfg, model_name, participant, prep["directions"], out / "joint_iterations.csv",
                        out / "joint_estimate.csv", out / "joint_summary.json")
        est = pd.read_csv(out / "joint_estimate.csv", comment="#")
        summary["estimate"] = str(out / "joint_estimate.csv")
        table = est.drop(columns=[c for c in ("f_true", "rel_diff_true", "criterion") if c in est.columns])
    summary.update(_decision(cfg, model_name, participant, prep, out, threads, log))
    summary["seconds"] = round(time.time() - t0, 1)
    atomic_write_text(json.dumps(summary, indent=2, default=float), out / "run.json")
    summary["table"] = table
    return summary


def _decision(cfg: Mapping, model_name: str, participant: str, prep: dict, out: Path, threads: int,
              log: Callable[[str], None]) -> dict:
    """The deficit decision (issue 31, the session's and the study's code) on the participant's forces, for a model
    with the decision's group; ``decision.csv`` (one row per test) and a summary entry. Empty for other models."""
    from neckstrength.config import decision_settings, derive_rng, full_model_from_config, joint_settings, \
        model_from_config
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.pipeline.common import load_directions
    from neckstrength.sequential.decision import decide

    ds = decision_settings(cfg)
    model = model_from_config(full_model_from_config(cfg), cfg, model_name)
    if not len(ds.group_indices(model.muscle_names)):
        return {}
    d, U = model_directions_table(model, load_directions(prep["directions"]))
    meas = pd.read_csv(prep["measurements"], comment="#").set_index("direction")[participant]
    forces = meas.reindex(list(d["name"])).to_numpy(float)
    t0 = time.time()
    dec, hist = decide(model, list(d["name"]), U, d["force_scale"].to_numpy(float), model.strengths, forces, ds,
                       joint_settings(cfg), derive_rng(int(cfg["seed"]), f"estimate/{model_name}/decision"),
                       n_threads=threads)
    hdr = [f"deficit decision for {participant} ({model_name}; issue 31, docs/clinician.md): {ds.label()}; "
           f"{ds.n_candidates} candidates per hypothesis; seed {int(cfg['seed'])}, stream "
           f"'estimate/{model_name}/decision'",
           "log_bf: log Bayes factor deficit : normal, log_bf_se its Monte Carlo error (heuristic); p_deficit at the "
           "prevalence; decision at p_decide; how well it decides on simulated patients: docs/clinician.md; "
           "not checked under model misfit",
           f"p_deficit: {dec.p_label()}; p_model: the model's own P (heuristic)"]
    atomic_write_csv(hist, out / "decision.csv", hdr, float_format="%.6g")
    log(f"deficit decision: {dec.decision()} (P(deficit) {dec.p_deficit():.2f}, {dec.p_label()}; log Bayes factor "
        f"{dec.log_bf():+.1f} ± {dec.log_bf_se():.1f} heuristic; {ds.label()}) in {time.time() - t0:.0f} s")
    return {"decision": dec.decision(), "p_deficit": dec.p_deficit(), "p_deficit_label": dec.p_label(),
            "log_bf": dec.log_bf(),
            "log_bf_se": dec.log_bf_se(), "decision_settings": ds.label(), "decision_csv": str(out / "decision.csv")}
