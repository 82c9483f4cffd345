#!/usr/bin/env python
"""Benchmark: which effect the calibrated gap decision names, under other selection rules, scored offline on the
user-facing benchmark's rows (issue 32).

The calibrated decision (``gap.calibrate.Calibration.decide``) tests with maxT: it names the effect with the
largest standardised improvement z_e = (delta_e - mu_e) / sd_e of the held-out gap if that maximum's adjusted
p-value (against the noise-only replicates' maxima) is at most alpha. Whether *some* effect is named depends only on
the maximum, so every rule below that names an effect exactly when the maxT test rejects has the same false-alarm
rate on the controls; the rules differ in *which* effect they name:

- ``maxT``: the effect with the largest z (the shipped rule);
- ``largest_improvement``: among the effects whose own z passes the maxT threshold (adjusted p <= alpha) and whose
  improvement is positive, the one with the largest improvement delta_e of the held-out gap;
- ``smallest_rms``: among the same effects, the one with the smallest held-out RMS log residual.

Reads ``rows.jsonl`` of ``benchmarks/bench_gap_users.py`` (rows written since 2026-11-28 keep each case's
``decision_inputs``), re-decides every case, rescored with ``gap.scoring.score_cases`` (model-free
detectability). Approximations, stated in the output: the aiming-scatter step (which tests the remainder of the
chosen effect) is held as run (a case it named ``direction_scatter`` keeps that name); the check that an effect's
all-direction fit is not neutral is not redone. The ``maxT`` row must reproduce the run's own decisions (printed:
cases where it does not).

    .venv/bin/python benchmarks/bench_gap_selection.py results/gap/s3m24/users3/rows.jsonl
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.gap.scoring import score_cases

RULES = ("maxT", "largest_improvement", "smallest_rms")


def redecide(inputs: dict, rule: str, alpha: float) -> str:
    """The effect (or 'none') that ``rule`` names from one case's decision inputs."""
    eff = list(inputs["effects"])
    gap = np.asarray(inputs["gap_obs"], float)
    delta = gap[0] - gap[1:]
    z = (delta - np.asarray(inputs["mu"], float)) / np.asarray(inputs["sd"], float)
    t_null = np.asarray(inputs["t_null"], float)
    p_of = (1 + (t_null[None, :] >= z[:, None] - 1e-12).sum(axis=1)) / (len(t_null) + 1)
    best = int(np.argmax(z))
    if p_of[best] > alpha or delta[best] <= 0:
        return "none"
    if rule == "maxT":
        return eff[best]
    ok = np.flatnonzero((p_of <= alpha) & (delta > 0))
    if rule == "largest_improvement":
        return eff[int(ok[np.argmax(delta[ok])])]
    if rule == "smallest_rms":
        rms = np.asarray(inputs["rms_obs"], float)[1:]
        return eff[int(ok[np.argmin(rms[ok])])]
    raise ValueError(f"unknown rule {rule!r}")


def main(argv=None) -> pd.DataFrame:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("rows", help="rows.jsonl of bench_gap_users.py")
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--out", default=None, help="CSV of the score tables per rule")
    a = ap.parse_args(argv)
    rows = [json.loads(x) for x in Path(a.rows).read_text().splitlines() if x.strip()]
    rows = [r for r in rows if "decision_inputs" in r]
    if not rows:
        raise SystemExit(f"{a.rows}: no row with decision_inputs (rows written before 2026-11-28 lack them)")
    mismatch = [r["case"] for r in rows if redecide(r["decision_inputs"], "maxT", a.alpha)
                != r.get("named_before_scatter", r["named"])]
    print(f"{len(rows)} cases; maxT re-decided differs from the run's decision in {len(mismatch)}"
          + (f": {', '.join(mismatch)}" if mismatch else ""))
    out = []
    for rule in RULES:
        new = []
        for r in rows:
            x = dict(r)
            if r["named"] != "direction_scatter":      # the aiming-scatter step held as run
                x["named"] = redecide(r["decision_inputs"], rule, a.alpha)
            new.append(x)
        _, tab, thr = score_cases(new)
        tab.insert(0, "rule", rule)
        out.append(tab)
        head = tab.set_index("group")
        g1 = head.iloc[0]
        g3 = head.iloc[2]
        changed = sum(x["named"] != r["named"] for x, r in zip(new, rows))
        print(f"{rule:>20}: detectable named correctly {int(g1['count'])}/{int(g1['cases'])} "
              f"({g1['share']:.2f}, {g1['wilson95_low']:.2f}-{g1['wilson95_high']:.2f}); false alarms "
              f"{int(g3['count'])}/{int(g3['cases'])}; cases named differently from the run: {changed}")
    res = pd.concat(out, ignore_index=True)
    if a.out:
        res.to_csv(a.out, index=False, float_format="%.4g")
    return res


if __name__ == "__main__":
    main()
