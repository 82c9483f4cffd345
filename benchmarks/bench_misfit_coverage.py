#!/usr/bin/env python
"""Coverage under misspecification with the misfit-aware kernel (issue 18 item 2; neckstrength.calibration.misfit).

Simulated participants from s3m24's prior ('well') and from a richer truth ('rich': the 96 muscle elements of the
s3 kinematics, each element's strength varied on its own, simulated with the 's3-independent' model), forces with
log-normal noise; the s3m24 joint posterior on all 25 directions with the nominal kernel (noise_rel = the noise)
and with the kernel widened by the misfit estimated from held-out directions. Prints the coverage table.

Run from the repository root::

    python benchmarks/bench_misfit_coverage.py --participants 10 --n-candidates 1000 --csv misfit_rows.csv
"""

from __future__ import annotations

import argparse
import os
import time


def main(argv=None) -> int:
    from neckstrength.calibration.misfit import MisfitSettings, misfit_coverage, misfit_summary
    from neckstrength.config import (
        build_directions,
        derive_rng,
        full_model_from_config,
        joint_settings,
        load_config,
        model_from_config,
    )
    from neckstrength.estimation.datasets import model_directions_table

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--participants", type=int, default=10, help="per truth")
    ap.add_argument("--n-candidates", type=int, default=1000)
    ap.add_argument("--noise", type=float, default=0.05)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seed", type=int, default=None, help="default: config seed")
    ap.add_argument("--csv", default=None, help="also write the per-group rows here")
    a = ap.parse_args(argv)
    cfg = load_config(a.config)
    seed = int(cfg["seed"] if a.seed is None else a.seed)
    full = full_model_from_config(cfg)
    model = model_from_config(full, cfg, "s3m24")
    elements = model_from_config(full, cfg, "s3-independent")
    dirs = build_directions(cfg)
    d, U = model_directions_table(model, dirs)
    _, Ue = model_directions_table(elements, dirs)
    st = MisfitSettings(n_participants=a.participants, folds=a.folds, noise=a.noise)
    joint = joint_settings(cfg, n_candidates=a.n_candidates, noise_rel=a.noise)
    print(f"{st}\n{joint}\nseed {seed}; streams 'misfit/<what>/<truth>' + participant", flush=True)
    t0 = time.time()
    df = misfit_coverage(model, elements, full.strengths, list(d["name"]), U, Ue, d["force_scale"].to_numpy(float),
                         st, joint, lambda k, i: derive_rng(seed, f"misfit/{k}", i),
                         progress=lambda s: print(s, flush=True))
    if a.csv:
        df.to_csv(a.csv, index=False)
    print(misfit_summary(df).to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    load = os.getloadavg()
    print(f"{time.time() - t0:.0f} s; {os.cpu_count()} cpus, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
