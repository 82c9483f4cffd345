"""Pipeline stage of ``workflow/rules/appendix_a.smk``: Fig. A.4."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import pandas as pd

from neckstrength.io import atomic_write_csv, read_measurements
from neckstrength.pipeline.common import load_directions


def appendix_a4(config: Mapping, directions_csv: str | Path, baseline_csv: str | Path,
                      out_table: str | Path, out_fig: str | Path) -> pd.DataFrame:
    """Fig. A.4: measured strength of S003-S007 vs the baseline model scaled by Eq. 5.3."""
    from neckstrength.plotting import radar_grid

    cfg = config["appendix_a4"]
    directions = load_directions(directions_csv)
    base = pd.read_csv(baseline_csv, comment="#").set_index("direction")
    meas = read_measurements(config["data"]["measurements"], list(directions["name"]))
    parts = [p for p in config["participants"] if p in meas.columns]
    missing = [p for p in config["participants"] if p not in meas.columns]
    if missing:
        raise ValueError(f"{config['data']['measurements']}: participants {missing} not found")
    bd = cfg["bootstrap_direction"]
    rows = []
    for p in parts:
        a = float(meas.loc[bd, p] / base.loc[bd, "force_N"])  # Eq. 5.3 (closed form, see bootstrap_scale)
        for dname in meas.index:
            rows.append({"participant": p, "direction": dname, "measured_N": meas.loc[dname, p],
                         "scale_a": a, "model_scaled_N": a * base.loc[dname, "force_N"],
                         "model_baseline_N": base.loc[dname, "force_N"]})
    mean_meas = meas[parts].mean(axis=1)
    a_mean = float(mean_meas[bd] / base.loc[bd, "force_N"])
    for dname in meas.index:
        rows.append({"participant": "mean", "direction": dname, "measured_N": mean_meas[dname], "scale_a": a_mean,
                     "model_scaled_N": a_mean * base.loc[dname, "force_N"],
                     "model_baseline_N": base.loc[dname, "force_N"]})
    df = pd.DataFrame(rows)
    df["difference_N"] = df["model_scaled_N"] - df["measured_N"]
    df["rel_difference"] = df["difference_N"] / df["measured_N"]
    atomic_write_csv(df, out_table, [f"Appendix A.4: measured max force (Table A.2) beside the {cfg['model']} "
                                     f"baseline model scaled by Eq. 5.3 in direction '{bd}'",
                                     "difference = model - measured (N)"], float_format="%.4g")
    radar_grid(directions, {p: meas[p] for p in parts},
               {f"{cfg['model']} baseline x a (mean, '{bd}')": df[df.participant == "mean"]
                .set_index("direction")["model_scaled_N"]},
               out_fig, title=f"Fig. A.4: measured strength vs {cfg['model']} model (N)")
    return df
