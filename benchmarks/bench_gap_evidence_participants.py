#!/usr/bin/env python
"""The Bayes evidence of the diagnosis's explanations on the thesis's participants (issue 32; heuristic).

For each participant (S003-S007, s3m24 full config, the config's twelve candidates) and each noise level of the
literature prior's range (0.05, 0.08, 0.15; the participants have no repeats, so each recorded force is taken as
one trial, ``repeats`` 1): :class:`neckstrength.gap.evidence.Explanations` with its default settings, the posterior
probability of "no effect", the three most probable explanations, and whether the most probable one fits at all
(its smallest Mahalanobis distance^2 and the chi-square tail with 25 degrees of freedom). Not the diagnosis's
decision (docs/gap_diagnosis.md, "What the 25 tests allow").

    .venv/bin/python benchmarks/bench_gap_evidence_participants.py
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

import numpy as np
import pandas as pd


def main(argv=None) -> pd.DataFrame:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--model", default="s3m24")
    ap.add_argument("--datasets", default="S003,S004,S005,S006,S007")
    ap.add_argument("--noise", default="0.05,0.08,0.15", help="log SD of one trial")
    ap.add_argument("--repeats", type=int, default=1, help="trials per recorded force (the largest kept)")
    ap.add_argument("--out", default=None, help="CSV of the table (not overwritten without --force)")
    ap.add_argument("--force", action="store_true")
    a = ap.parse_args(argv)

    from neckstrength.config import build_directions, gap_blind_dataset, gap_context, load_config
    from neckstrength.gap.evidence import EvidenceSettings, Explanations
    from neckstrength.io import atomic_write_csv
    from neckstrength.seeds import derive_rng

    if a.out and os.path.exists(a.out) and not a.force:
        raise SystemExit(f"{a.out} exists; use --force to replace it")
    t0 = time.perf_counter()
    cfg = load_config(a.config)
    dirs = build_directions(cfg)
    ctx = gap_context(cfg, a.model, dirs)
    ex = Explanations(ctx, list(cfg["gap"]["effects"]), EvidenceSettings(repeats=a.repeats))
    rows = []
    for name in a.datasets.split(","):
        data = gap_blind_dataset(cfg, ctx, dirs, name)
        for sigma in (float(x) for x in a.noise.split(",")):
            r = ex.evidence(data.forces, sigma, derive_rng(cfg["seed"], f"gap/evidence/{name}"))
            top = sorted(r.posterior.items(), key=lambda kv: -kv[1])[:3]
            rows.append({"dataset": name, "noise": sigma, "repeats": a.repeats, "p_no_effect": r.p_no_effect,
                         "named": r.named, "most_probable": r.best,
                         "top3": "; ".join(f"{k} {v:.3g}" for k, v in top),
                         "fit_chi2_best": r.fit_chi2, "fit_p_best": r.fit_p,
                         "strength_sd": r.settings.strength_sd, "prior_no_effect": r.settings.prior_no_effect})
    df = pd.DataFrame(rows)
    pd.set_option("display.width", 220)
    print(df.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    print(f"{time.perf_counter() - t0:.0f} s wall, load {os.getloadavg()[0]:.1f}; seed {cfg['seed']}")
    if a.out:
        atomic_write_csv(df, a.out)
    return df


if __name__ == "__main__":
    main()
