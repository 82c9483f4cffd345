"""Pipeline stages of the model rules (``workflow/rules/model.smk``): full model, directions,
reduction, comparison with Tables B.3/B.5/B.7, baseline strength."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from neckstrength.config import build_directions, full_model_from_config, model_from_config
from neckstrength.estimation.datasets import model_directions_table
from neckstrength.io import atomic_write_csv
from neckstrength.model.full import AXES, B1_JOINTS, COORDINATES, load_full_model, load_table_b1
from neckstrength.model.geometry import DIRECTIONS_HEADER
from neckstrength.model.reduction import ReducedModel
from neckstrength.pipeline.common import load_directions, provenance_lines
from neckstrength.wrench import solve
from neckstrength.wrench.problem import STATUS_CODES

THESIS_PARAM_TABLES = {"s3m24": "table_B3_params_s3m24.csv", "p3m12": "table_B5_params_p3m12.csv",
                       "p2m7": "table_B7_params_p2m7.csv"}


def model_full(config: Mapping, out_csv: str | Path, out_b1_compare: str | Path) -> None:
    """Full-model table (strengths with source, R in thesis sign convention) and the B.1 comparison."""
    full = full_model_from_config(config)
    df = full.muscles.copy()
    for k, c in enumerate(COORDINATES):
        df[c] = full.moment_arms[k]
    atomic_write_csv(df, out_csv, provenance_lines(config, "full model: 96 muscles x 21 coordinates "
                                                   "(moment arms m, strengths N)"))
    # every printed B.1 value beside the OpenSim-derived one
    derived = load_full_model(config["data"]["model_dir"], None, "derived")
    b1 = load_table_b1(config["data"]["thesis_dir"], apply_errata=config["model"]["apply_b1_errata"])
    rows = []
    for r in b1.to_dict("records"):
        i = int(r["index"]) - 1
        rows.append({"index": r["index"], "name": r["name"], "joint": "strength", "axis": "",
                     "thesis_B1": r["strength_N"], "derived": derived.strengths[i],
                     "difference": derived.strengths[i] - r["strength_N"],
                     "rel_difference": (derived.strengths[i] - r["strength_N"]) / r["strength_N"]})
        for j in B1_JOINTS:
            for a in AXES:
                v = r[f"{j}_{a}"]
                if v is None or np.isnan(v):
                    continue
                dv = derived.moment_arms[COORDINATES.index(f"{j}_{a}"), i]
                rows.append({"index": r["index"], "name": r["name"], "joint": j, "axis": a, "thesis_B1": v,
                             "derived": dv, "difference": dv - v,
                             "rel_difference": (dv - v) / abs(v) if v != 0 else np.nan})
    atomic_write_csv(pd.DataFrame(rows), out_b1_compare,
                     ["Table B.1 (as printed, errata applied) beside the OpenSim-derived full model",
                      "strength rows: N; moment-arm rows: m; difference = derived - thesis"],
                     float_format="%.5g")


def model_directions(config: Mapping, out_csv: str | Path) -> None:
    d = build_directions(config)
    # full precision (shortest round-trip repr): every rule reads the directions from this file, the command
    # line builds them in memory; rounded to 6 decimals they differed by up to 5e-7, enough to move a gap
    # diagnosis's calibrated p-value (S005: 0.175 from the pipeline, 0.15 from the command line)
    atomic_write_csv(d, out_csv, DIRECTIONS_HEADER)


def model_reduce(config: Mapping, model_name: str, out_params: str | Path, out_jt: str | Path,
                 out_groups: str | Path | None = None) -> ReducedModel:
    full = full_model_from_config(config)
    model = model_from_config(full, config, model_name)
    if out_groups is not None:
        rows = [{"group": g, "n_members": int(model.S[:, k].sum()),
                 "members": "; ".join(full.names[i] for i in np.nonzero(model.S[:, k])[0])}
                for k, g in enumerate(model.muscle_names)]
        atomic_write_csv(pd.DataFrame(rows), out_groups, [f"muscle groups of {model.name} (grouping matrix S_m)"])
    atomic_write_csv(model.to_frame(), out_params,
                     provenance_lines(config, f"reduced model {model.name}: kinematic {model.kinematic}, "
                                      f"grouping {model.grouping}; strengths N, moment arms m "
                                      "(group strength = 2-norm, arm = torque contribution / strength)"),
                     float_format="%.6g")
    jt = pd.DataFrame(model.JT, columns=list(model.task))
    jt.insert(0, "coordinate", list(model.coordinates))
    atomic_write_csv(jt, out_jt, [f"J^T of {model.name}: torque (N*m) per unit skull wrench component"],
                     float_format="%.6g")
    return model


def model_vs_thesis(config: Mapping, model_name: str, out_csv: str | Path) -> pd.DataFrame:
    """Our reduced parameters beside Table B.3 / B.5 / B.7, with differences."""
    full = full_model_from_config(config)
    model = model_from_config(full, config, model_name)
    thesis = pd.read_csv(Path(config["data"]["thesis_dir"]) / THESIS_PARAM_TABLES[model_name], comment="#")
    ours = model.to_frame().set_index("muscle")
    rows = []
    for r in thesis.to_dict("records"):
        g = r["group"]
        if g not in ours.index:
            rows.append({"group": g, "quantity": "strength_N", "thesis": r["strength_N"], "ours": np.nan,
                         "difference": np.nan, "note": "group not in our model"})
            continue
        rows.append({"group": g, "quantity": "strength_N", "thesis": r["strength_N"],
                     "ours": ours.loc[g, "strength_N"], "difference": ours.loc[g, "strength_N"] - r["strength_N"],
                     "note": ""})
        for col in thesis.columns:
            if col in ("index", "group", "strength_N"):
                continue
            t = r[col]
            o = ours.loc[g, col] if col in ours.columns else np.nan
            t0 = 0.0 if pd.isna(t) else t
            rows.append({"group": g, "quantity": f"{col} (m)", "thesis": t0, "ours": o, "difference": o - t0,
                         "note": "blank in thesis (0)" if pd.isna(t) else ""})
    df = pd.DataFrame(rows)
    atomic_write_csv(df, out_csv, [f"reduced model {model_name}: ours beside thesis Table "
                                   f"{THESIS_PARAM_TABLES[model_name]}, difference = ours - thesis",
                                   f"moment arms: {config['model']['moment_arm_source']}"], float_format="%.5g")
    return df


def model_baseline_strength(config: Mapping, model_name: str, directions_csv: str | Path,
                            out_csv: str | Path) -> pd.DataFrame:
    """Maximum wrench of the baseline model in each test direction, with activations."""
    full = full_model_from_config(config)
    model = model_from_config(full, config, model_name)
    d, U = model_directions_table(model, load_directions(directions_csv))
    w, alpha, status = solve(model, model.strengths[None, :], U, method="highs")
    out = pd.DataFrame({"direction": d["name"], "wrench": w[0], "force_N": w[0] / d["force_scale"].to_numpy(),
                        "status": [STATUS_CODES[s] for s in status[0]]})
    for j, mname in enumerate(model.muscle_names):
        out[f"alpha[{mname}]"] = alpha[0, :, j]
    atomic_write_csv(out, out_csv, [f"baseline max wrench of {model_name} (Eq. 4.1), strengths f'_base",
                                    "wrench: magnitude along the unit wrench (mixed N, N*m norm); force_N: applied "
                                    "force at the test point"], float_format="%.6g")
    return out
