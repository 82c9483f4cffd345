"""``neckstrength estimate``: strengths of one participant from a user's table (or trials), no config to write.

:func:`run_estimate` takes :class:`EstimateSettings` (built from the default configuration, ``config/config.yaml``,
by :func:`neckstrength.config.estimate_settings`: every science setting from its ``chapter5`` / ``chapter6``
sections; command-line options are :meth:`EstimateSettings.with_options`) and calls the very stages the pipeline
rules call, keeping their results in memory: :func:`neckstrength.abc.stage.run_alg4` (+ ``alg4_figures``) for
Algorithm 4, then :func:`~neckstrength.abc.stage.run_smc_comparison` for ABC-SMC (compared with Algorithm 4 at equal
budget, as in the pipeline), and :func:`neckstrength.sequential.joint_estimate.run_joint_estimate` for the joint
estimator.

Directions without a value for the participant (e.g. no valid trial) are dropped from the fit and listed;
the Eq. 5.3 bootstrap direction must be present. The seed is the config's unless given, and is recorded in
``run.json`` with every input.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from neckstrength import __version__
from neckstrength.abc.algorithm4 import ABCSettings
from neckstrength.abc.smc import SMCSettings
from neckstrength.estimation.datasets import DatasetSettings
from neckstrength.io import DataValidationError, atomic_write_csv, atomic_write_text, read_measurements
from neckstrength.model.reduction import ReducedModel
from neckstrength.sequential.decision import DecisionSettings
from neckstrength.sequential.joint import JointSettings

METHODS = ("alg4", "smc", "joint")


@dataclass(frozen=True)
class EstimateSettings:
    """Everything that fixes ``neckstrength estimate``'s numbers for one model (built by
    :func:`neckstrength.config.estimate_settings`)."""

    seed: int                                  # config seed
    bootstrap_direction: str                   # chapter5.bootstrap_direction (Eq. 5.3)
    thesis_dir: str                            # data.thesis_dir: the healthy f_a the SMC comparison judges against
    abc: ABCSettings                           # chapter5 (Algorithm 4 of this model)
    smc: SMCSettings                           # chapter5.smc (budget = the cap, max_budget)
    joint: JointSettings                       # chapter6.joint
    decision: DecisionSettings                 # clinician.decision
    criteria: tuple[str, ...] = ("joint_eig", "marginal_entropy")   # chapter6.joint.criteria
    use_emg: bool = False                      # chapter6.joint.use_emg
    data_alg4: DatasetSettings = DatasetSettings()    # chapter5 (EMG groups and bands of this model)
    data_joint: DatasetSettings = DatasetSettings()   # chapter6

    @property
    def emg(self) -> str:
        """The participant EMG bounds ('none' or 'a3_band')."""
        return self.data_alg4.participant_emg

    def with_options(self, seed: int | None = None, emg: str | None = None, max_iter: int | None = None,
                     criterion: str | None = None) -> "EstimateSettings":
        """The command line's options on top (None: keep the config's): ``--seed``, ``--emg`` (both estimators'
        participant EMG bounds), ``--max-iter`` (Algorithm 4's cap), ``--criterion`` (the joint estimator's only
        criterion)."""
        s = self
        if seed is not None:
            s = replace(s, seed=int(seed))
        if emg is not None:
            s = replace(s, data_alg4=replace(s.data_alg4, participant_emg=emg),
                        data_joint=replace(s.data_joint, participant_emg=emg))
        if max_iter is not None:
            s = replace(s, abc=replace(s.abc, max_iter=int(max_iter)))
        if criterion is not None:
            s = replace(s, criteria=(criterion,))
        return s


def _prepare_inputs(bootstrap_direction: str, model: ReducedModel, d: pd.DataFrame, participant: str,
                    measurements: str | Path, activations: str | Path | None, out: Path,
                    log: Callable[[str], None]) -> dict:
    """Directions table (directions with a value only) and the participant's table, written into ``out``."""
    from neckstrength.estimation.datasets import model_directions_table

    names = list(d["name"])
    meas = read_measurements(measurements, names)
    if participant not in meas.columns:
        raise DataValidationError(measurements, f"no column for participant '{participant}' (columns: "
                                  f"{', '.join(meas.columns)})", field_name=participant)
    model_name = model.name
    dm, _ = model_directions_table(model, d)
    col = meas[participant].reindex(names)
    used = [n for n in dm["name"] if np.isfinite(col.get(n, np.nan))]
    dropped = [n for n in dm["name"] if n not in used]
    boot = bootstrap_direction
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


def run_estimate(settings: EstimateSettings, model: ReducedModel, directions: pd.DataFrame, participant: str,
                 measurements: str | Path, out_dir: str | Path, method: str = "alg4",
                 activations: str | Path | None = None, threads: int = 1, log: Callable[[str], None] = print,
                 figures: bool = True) -> dict:
    """Estimate ``participant``'s strengths with ``method`` (alg4, smc, joint) of ``model`` from the tests of
    ``directions`` (the config's table, :func:`neckstrength.config.build_directions`); outputs under ``out_dir``.

    Returns a summary dict (also written as ``run.json``). Progress goes to ``log`` and the stages' to stdout.
    """
    from neckstrength.estimation.datasets import load_dataset
    from neckstrength.io import read_directions
    from neckstrength.seeds import derive_rng, seed_sequence

    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, not {method!r}")
    t0 = time.time()
    s = settings
    model_name = model.name
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    prep = _prepare_inputs(s.bootstrap_direction, model, directions, participant, measurements, activations, out, log)
    if s.emg != "none" and prep["activations"] is None:
        raise ValueError(f"--emg {s.emg} needs an activation table with a column for {participant}")
    # the stages read the inputs as the pipeline does: the tables written above
    d_used = read_directions(prep["directions"])
    summary = {"participant": participant, "model": model_name, "method": method, "seed": s.seed,
               "measurements": str(measurements), "activations": None if activations is None else str(activations),
               "emg": s.emg, "directions_used": prep["used"], "directions_dropped": prep["dropped"],
               "neckstrength": __version__}
    if method in ("alg4", "smc"):
        from neckstrength.abc.stage import ALG4_TABLES, alg4_figures, run_alg4, write_alg4

        data = load_dataset(model, d_used, participant, s.data_alg4, s.thesis_dir, prep["measurements"],
                            prep["activations"])
        outputs = {k: out / f"{k}.csv" for k in ALG4_TABLES}
        outputs["summary"] = out / "summary.json"
        run = run_alg4(model, data, s.abc, s.bootstrap_direction, derive_rng(s.seed, f"{model_name}/{participant}"),
                       s.seed, checkpoint=out / ".checkpoint.npz", n_threads=threads)
        write_alg4(run, outputs)
        (out / ".checkpoint.npz").unlink(missing_ok=True)      # only an interrupted run needs it (to resume)
        if figures:
            figs = {"traces": out / "fig_estimate_traces.png", "dk_hist": out / "fig_dk_hist.png",
                    "d_dir": out / "fig_d_by_direction.png", "parallel": out / "fig_parallel.png",
                    "radar": out / "fig_fit_radar.png"}
            alg4_figures(run.tables(), d_used, model_name, participant, figs, run.summary())
        res = run.result
        summary.update({"iterations": res.iterations, "converged": res.converged, "D_fc": res.D_fc,
                        "scale_a": run.a, "estimate": str(outputs["estimate"])})
        table = run.estimate.groupby("parameter", sort=False)[["f_base", "f_0", "f_c", "sigma_c"]].first().reset_index()
        if method == "smc":
            from neckstrength.abc.stage import run_smc_comparison, write_smc_comparison

            smc = run_smc_comparison(model, data, run.estimate, res.iterations, s.abc, s.smc, s.bootstrap_direction,
                                     s.thesis_dir, derive_rng(s.seed, f"smc/{model_name}/{participant}"), s.seed)
            write_smc_comparison(smc, out / "smc_vs_alg4.csv", out / "smc_generations.csv")
            summary["smc"] = str(out / "smc_vs_alg4.csv")
            table = smc.table[["muscle", "alg4_f_c", "smc_mean", "smc_q05", "smc_q95"]]
    else:
        from neckstrength.sequential.joint_estimate import run_joint_estimate, write_joint_estimate

        data = load_dataset(model, d_used, participant, s.data_joint, s.thesis_dir, prep["measurements"],
                            prep["activations"])
        key = f"chapter6/joint/{model_name}/{participant}"
        joint = run_joint_estimate(model, data, s.joint, s.criteria, s.use_emg, s.seed, key,
                                   seed_sequence(s.seed, key))
        write_joint_estimate(joint, out / "joint_iterations.csv", out / "joint_estimate.csv",
                             out / "joint_summary.json")
        summary["estimate"] = str(out / "joint_estimate.csv")
        est = joint.estimate
        table = est.drop(columns=[c for c in ("f_true", "rel_diff_true", "criterion") if c in est.columns])
    summary.update(_decision(s, model, d_used, participant, prep, out, threads, log))
    summary["seconds"] = round(time.time() - t0, 1)
    atomic_write_text(json.dumps(summary, indent=2, default=float), out / "run.json")
    summary["table"] = table
    return summary


def _decision(s: EstimateSettings, model: ReducedModel, d_used: pd.DataFrame, participant: str, prep: dict,
              out: Path, threads: int, log: Callable[[str], None]) -> dict:
    """The deficit decision (issue 31, the session's and the study's code) on the participant's forces, for a model
    with the decision's group; ``decision.csv`` (one row per test) and a summary entry. Empty for other models."""
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.seeds import derive_rng
    from neckstrength.sequential.decision import decide

    ds = s.decision
    model_name = model.name
    if not len(ds.group_indices(model.muscle_names)):
        return {}
    d, U = model_directions_table(model, d_used)
    meas = pd.read_csv(prep["measurements"], comment="#").set_index("direction")[participant]
    forces = meas.reindex(list(d["name"])).to_numpy(float)
    t0 = time.time()
    dec, hist = decide(model, list(d["name"]), U, d["force_scale"].to_numpy(float), model.strengths, forces, ds,
                       s.joint, derive_rng(s.seed, f"estimate/{model_name}/decision"), n_threads=threads)
    hdr = [f"deficit decision for {participant} ({model_name}; issue 31, docs/clinician.md): {ds.label()}; "
           f"{ds.n_candidates} candidates per hypothesis; seed {s.seed}, stream "
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
