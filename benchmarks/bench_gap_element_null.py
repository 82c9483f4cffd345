"""How well the Bayes evidence's element null fits the user benchmark's 96-element controls (issue 32).

The evidence's second "no effect" (``none_elements``) is a Gaussian of the log forces under independent element
strengths (log SD ``element_spread``) around the base fit. Where it fits the 96-element controls as well as "no
effect" fits the base-model controls, those controls should raise alarms as rarely as the base-model ones; where it
fits them worse, an effect that absorbs part of their deviation (a left/right ratio) wins. This script regenerates a
user-benchmark design's controls (``bench_gap_users.py``'s generator and stream) and prints, per control, the
smallest chi-square of "no effect" and of the element null at the base fit (the evidence's ``best_fit_chi2``, 25
tests, strengths marginalised around the fit), and the most probable explanation with its P(no effect).

    .venv/bin/python benchmarks/bench_gap_element_null.py --config CONFIG_WITH_THE_DESIGN_SEED
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv=None) -> pd.DataFrame:
    from bench_gap_users import add_design_args, design_from_args, finish

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_design_args(ap)
    ap.add_argument("--element-draws", type=int, default=None, help="the element null's draws (default: the config's)")
    ap.add_argument("--truths", default="none,rich96", help="which cases (comma-separated truths)")
    ap.add_argument("--evidence", action="store_true", help="also the full evidence (refits; about 5 s per case)")
    ap.add_argument("--out", default=None, help="CSV of the per-control table")
    a = ap.parse_args(argv)
    from neckstrength.gap import evidence as ev
    from neckstrength.seeds import derive_rng

    t0, c0 = time.perf_counter(), time.process_time()
    cfg, cases, ctx, ds = design_from_args(a)
    es = ds.evidence
    if a.element_draws is not None:
        from dataclasses import replace

        es = replace(es, element_draws=int(a.element_draws))
    ex = ev.Explanations(ctx, list(ds.effects), es)
    rows = []
    for c in cases:
        if c.truth not in a.truths.split(","):
            continue
        y, s = np.log(c.forces), float(c.noise_sd)
        rng = derive_rng(ds.seed, f"gap/evidence/{c.name}")
        f = ex.fit(y, s, rng)
        sig = ex.signatures(f, rng)
        J = ev.log_jacobian(ex.base, f, ex.pidx, base_rows=ex.base_rows)
        row = {"case": c.name, "truth": c.truth, "noise": s,
               "chi2_none": ev.best_fit_chi2(sig["none"], J, y, s, es.strength_sd, es.repeats),
               "chi2_none_elements": ev.best_fit_chi2(sig["none_elements"], J, y, s, es.strength_sd, es.repeats)}
        if a.evidence:
            r = ex.evidence(c.forces, s, derive_rng(ds.seed, f"gap/evidence/{c.name}"))
            row.update(p_no_effect=r.p_no_effect, most_probable=r.best, named=r.named)
        rows.append(row)
    tab = pd.DataFrame(rows)
    print(f"{a.model}, seed {cfg['seed']}: {len(tab)} cases; chi-square of 25 tests at the base fit "
          f"(strength SD {es.strength_sd}, element spread {es.element_spread}, {es.element_draws} draws)")
    print(tab.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    g = tab.groupby("truth")[["chi2_none", "chi2_none_elements"]].agg(["mean", "median"])
    print("\n" + g.to_string(float_format=lambda v: f"{v:.1f}"))
    return finish(tab, a.out, t0, c0)


if __name__ == "__main__":
    main()
