#!/usr/bin/env python
"""Check by simulation of the gap diagnosis's power per protocol (issue 32, item 4; docs/gap_diagnosis.md).

The diagnosis predicts the power of added protocols from a linearised noncentrality scaled by an efficiency that
it fits to its own simulated power of the present tests (``neckstrength.gap.protocols``). This script checks that
prediction for the ``repeats`` protocol, the one the calibration can simulate directly: ``r`` trials per direction
analysed as their mean log force are the present tests at noise ``sigma / sqrt(r)``. For one data set it runs

1. the calibrated diagnosis at noise ``sigma`` with power: the simulated power of the present tests, the fitted
   efficiency and the *predicted* power of ``repeats``;
2. the calibrated diagnosis at noise ``sigma / sqrt(r)`` with power: the *simulated* power of ``repeats``;

and prints, per effect and size, predicted against simulated power, their mean absolute difference and how often
the two agree on "told from noise" (power >= the target). Seeds: the config's (every draw derives from it and the
data set's name). Reduced sizes by default (five effects, 19 noise-only replicates, power at 0.5 and 1.0 of each
effect's range with 4 replicates each): the simulated powers have a resolution of 0.25.

Run from the repository root::

    .venv/bin/python benchmarks/bench_protocol_power.py                       # s3m24, S003, sigma 0.08
    .venv/bin/python benchmarks/bench_protocol_power.py --dataset S005 --power-replicates 8 --out protocol_check.csv
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

import numpy as np
import pandas as pd

EFFECTS = ("asymmetry", "origin_offset", "submaximal_effort", "posture_drift", "anthropometric_scaling")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--model", default="s3m24")
    ap.add_argument("--dataset", default="S003")
    ap.add_argument("--effects", default=",".join(EFFECTS))
    ap.add_argument("--sigma", type=float, default=0.08, help="noise of the present tests (log SD; the prior's)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--replicates", type=int, default=19)
    ap.add_argument("--power-replicates", type=int, default=4)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=None, help="CSV of the comparison (refused if it exists, unless --force)")
    ap.add_argument("--force", action="store_true")
    a = ap.parse_args()
    if a.out and os.path.exists(a.out) and not a.force:
        raise SystemExit(f"{a.out} exists; use --force to replace it")

    from neckstrength.config import build_directions, diagnosis_settings, gap_blind_dataset, gap_context, load_config
    from neckstrength.gap.diagnose import diagnose
    from neckstrength.gap.protocols import ProtocolSettings

    cfg = load_config(a.config)
    directions = build_directions(cfg)
    ctx = gap_context(cfg, a.model, directions)
    data = gap_blind_dataset(cfg, ctx, directions, a.dataset)
    base = diagnosis_settings(cfg, a.effects.split(","))
    cal = replace(base.calibration, replicates=a.replicates, sensitivity=False, power_sizes=(0.5, 1.0),
                  power_replicates=a.power_replicates)
    s = replace(base, pairs_top=0, refine_iter=0, bootstrap=50, reach_samples=0, reach_iter=0,
                protocols=ProtocolSettings(repeats=a.repeats), calibration=cal)
    t0, load0 = time.time(), os.getloadavg()[0]
    d1 = diagnose(ctx, [data], replace(s, calibration=replace(cal, noise=a.sigma)), workers=a.workers)[0]
    d2 = diagnose(ctx, [data], replace(s, calibration=replace(cal, noise=a.sigma / np.sqrt(a.repeats)),
                                       protocols=None), workers=a.workers)[0]
    pred = d1.protocols[d1.protocols["protocol"] == "repeats"].set_index(["effect", "size_share"])
    pres = d1.protocols[d1.protocols["protocol"] == "directions"].set_index(["effect", "size_share"])
    sim1 = d1.power.set_index(["effect", "size_share"])
    sim2 = d2.power.set_index(["effect", "size_share"])
    rows = []
    for k in sim2.index:
        rows.append({"effect": k[0], "size_share": k[1], "sim_present": sim1.loc[k, "power"],
                     "lin_present": pres.loc[k, "power"], "sim_repeats": sim2.loc[k, "power"],
                     "predicted_repeats": pred.loc[k, "power"], "oracle_repeats": pred.loc[k, "power_oracle"],
                     "replicates": int(sim2.loc[k, "replicates"])})
    tab = pd.DataFrame(rows)
    ok = tab["sim_repeats"].notna() & tab["predicted_repeats"].notna()
    target = cal.power_target
    agree = ((tab.loc[ok, "sim_repeats"] >= target) == (tab.loc[ok, "predicted_repeats"] >= target)).mean()
    pd.set_option("display.width", 200)
    print(f"{a.model} {a.dataset}: sigma {a.sigma:g}, repeats {a.repeats} (sigma {a.sigma / np.sqrt(a.repeats):.4f}); "
          f"efficiency fitted at sigma: {d1.summary['protocol_efficiency']:.3g}; {a.replicates} noise-only "
          f"replicates, {a.power_replicates} per effect and size; seed {cfg['seed']}")
    print(tab.to_string(index=False, float_format=lambda v: f"{v:.2f}"))
    print(f"predicted vs simulated power of the repeats protocol: mean |difference| "
          f"{np.abs(tab.loc[ok, 'sim_repeats'] - tab.loc[ok, 'predicted_repeats']).mean():.2f} over {int(ok.sum())} "
          f"effect sizes; agree on power >= {target:g} in {agree:.0%}; oracle (efficiency 1) mean |difference| "
          f"{np.abs(tab.loc[ok, 'sim_repeats'] - tab.loc[ok, 'oracle_repeats']).mean():.2f}")
    print(f"wall {time.time() - t0:.0f} s; load {load0:.1f} -> {os.getloadavg()[0]:.1f} ({os.cpu_count()} CPUs)")
    if a.out:
        tab.to_csv(a.out, index=False)


if __name__ == "__main__":
    main()
