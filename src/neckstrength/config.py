"""The configuration: loading, and the science objects and typed settings built from it."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd
import yaml

from neckstrength.abc.algorithm4 import ABCSettings
from neckstrength.gap.benchmark import BenchmarkSettings
from neckstrength.gap.diagnose import DiagnosisSettings
from neckstrength.gap.fit import FitSettings
from neckstrength.model.full import FullModel, load_full_model
from neckstrength.model.geometry import (
    HeadEllipsoid,
    assign_planes,
    direction_table,
    read_point_spec,
    read_test_points,
    reconstruct_test_points,
)
from neckstrength.model.reduction import ReducedModel, named_model
from neckstrength.sequential.algorithms import SequentialSettings
from neckstrength.sequential.joint import JointSettings


def load_config(path: str | Path) -> dict:
    """Load a YAML config and validate it (defaults filled) against the workflow schema."""
    path = Path(path)
    with open(path) as fh:
        cfg = yaml.safe_load(fh)
    schema = path.resolve().parent.parent / "workflow" / "schemas" / "config.schema.yaml"
    if schema.exists():
        from snakemake.utils import validate

        validate(cfg, str(schema))
    return cfg


def full_model_from_config(config: Mapping) -> FullModel:
    d, m = config["data"], config["model"]
    return load_full_model(d["model_dir"], d["thesis_dir"], m["moment_arm_source"], m["apply_b1_errata"],
                           m.get("unprinted_strengths", "b3_implied"))


def model_from_config(full: FullModel, config: Mapping, model_name: str) -> ReducedModel:
    m = config["model"]
    return named_model(full, model_name, config["data"]["thesis_dir"], m.get("grouping_supplements", True),
                       m.get("signature_tol_m", 1e-3))


def head_from_config(config: Mapping) -> HeadEllipsoid:
    h = config["geometry"]["head"]
    return HeadEllipsoid(tuple(h["centre"]), tuple(h["semi_axes"]))


def build_directions(config: Mapping) -> pd.DataFrame:
    g = config["geometry"]
    head = head_from_config(config)
    if g.get("test_points"):
        pts = read_test_points(g["test_points"])
        pts["method"] = "measured"
    else:
        pts = reconstruct_test_points(read_point_spec(g["test_point_spec"]), head)
    d = direction_table(pts, head)
    d = assign_planes(d, g["plane_bands"]["elevation_deg"], g["plane_bands"]["azimuth_deg"])
    sag = d["sagittal"].to_numpy()
    d["sagittal_index"] = 0
    d.loc[sag, "sagittal_index"] = np.arange(1, sag.sum() + 1)
    return d


def chapter4_factors(config: Mapping) -> list[float]:
    c = config["chapter4"]
    sweep = np.linspace(c["sweep"]["start"], c["sweep"]["stop"], int(c["sweep"]["num"]))
    return sorted(set(np.round(np.r_[c["factors"], sweep], 6).tolist()))


def abc_settings(config: Mapping, model_name: str) -> ABCSettings:
    c = config["chapter5"]
    per = c["settings"].get(model_name, {})
    return ABCSettings(sigma0=per.get("sigma0", 0.2), epsilon=c["epsilon"], q=c["q"], eps_D=c["eps_D"],
                       max_iter=per.get("max_iter", 20), sigma_min=c["sigma_clip"][0], sigma_max=c["sigma_clip"][1],
                       tie_sides=per.get("tie_sides", False), store_candidates=c.get("store_candidates", 3000))


def diagnosis_settings(config: Mapping, effects: Sequence[str] | None = None) -> DiagnosisSettings:
    g = config["gap"]
    f = g["fit"]
    fit = FitSettings(max_iter=f["max_iter"], ridge=f["ridge"], bounds_rel=tuple(f["bounds_rel"]),
                      fd_step=f["fd_step"], tol=f["tol"])
    return DiagnosisSettings(effects=tuple(effects or g["effects"]), grid_points=g["grid_points"], folds=g["folds"],
                             pairs_top=g["pairs_top"], pair_grid_top=g["pair_grid_top"], penalty=g["penalty"],
                             epsilon=config["chapter5"]["epsilon"], bootstrap=g["bootstrap"], starts=g["starts"],
                             start_spread=g["start_spread"], refine_iter=g["refine_iter"],
                             reach_samples=g["reach_samples"], reach_iter=g["reach_iter"], seed=config["seed"], fit=fit)


def benchmark_settings(config: Mapping) -> BenchmarkSettings:
    b = config["gap"]["benchmark"]
    return BenchmarkSettings(effects=tuple(b["effects"]), pairs=tuple(tuple(p) for p in b.get("pairs", [])),
                             replicates=b["replicates"], controls=b["controls"], noise_rel=b["noise_rel"],
                             strength_spread=b["strength_spread"], clear_size=tuple(b["clear_size"]))


def chapter6_settings(config: Mapping, model_name: str | None = None, **over) -> SequentialSettings:
    c = config["chapter6"]
    per = c.get("model_settings", {}).get(model_name, {}) if model_name else {}
    keys = ("n_candidates", "n_sim", "prior_sd_rel", "epsilon", "q", "n_bins", "bin_range_sd", "n_wbins", "alpha_min",
            "likelihood", "likelihood_floor", "predictive", "emg_band")
    kw = {k: per.get(k, c[k]) for k in keys if k in c or k in per}
    kw.update(over)
    return SequentialSettings(**kw)


def joint_settings(config: Mapping, **over) -> JointSettings:
    """``chapter6.joint`` (keys of :class:`JointSettings`; others ignored), with the Chapter 6 grid."""
    c = config["chapter6"]
    j = dict(c.get("joint", {}))
    names = {f.name for f in fields(JointSettings)}
    kw = {k: v for k, v in j.items() if k in names}
    kw.setdefault("prior_sd_rel", float(c.get("prior_sd_rel", 0.3)))
    kw.setdefault("n_bins", int(c.get("n_bins", 50)))
    kw.setdefault("bin_range_sd", float(c.get("bin_range_sd", 4.0)))
    kw.setdefault("emg_band", float(c.get("emg_band", 0.05)))
    kw.update(over)
    return JointSettings(**kw)
