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

Where the rows keep the null's improvements per replicate (since 2026-11-28 09:00 UTC), other max-statistic tests
are recomputed too (``STATISTICS``; these change whether an effect is named, so the false alarms too).

Reads ``rows.jsonl`` of ``benchmarks/bench_gap_users.py`` (rows written since 2026-11-28 keep each case's
``decision_inputs``), re-decides every case, rescored with ``gap.scoring.score_cases`` (model-free
detectability). Approximations, stated in the output: the aiming-scatter step (which tests the remainder of the
chosen effect) is held as run (a case it named ``direction_scatter`` keeps that name); the check that an effect's
all-direction fit is not neutral is not redone. The run's own rule must reproduce its decisions (printed: how many
cases each rule decides differently from the run).

    .venv/bin/python benchmarks/bench_gap_selection.py results/gap/s3m24/users3/rows.jsonl
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.gap.calibrate import at_least
from neckstrength.gap.scoring import score_cases

RULES = ("maxT", "largest_improvement", "smallest_rms")

#: test statistics over the effects, computed from the stored null improvements (rows since 2026-11-28 09:00 UTC):
#: 'z' the shipped standardised improvement (SD floor 1e-3); 'z_floor_<f>' its SD floored at f x the null's median
#: base-model held-out gap; 'raw' the improvement minus the null's mean; 'share' that over the base-model held-out gap
STATISTICS = ("z", "z_floor_0.1", "z_floor_0.5", "raw", "share")


def redecide_statistic(inputs: dict, statistic: str, alpha: float) -> str:
    """The effect (or 'none') named with the max-statistic test ``statistic`` recomputed from the stored null
    improvements, the largest improvement among the effects that pass (the shipped selection)."""
    eff = list(inputs["effects"])
    gap = np.asarray(inputs["gap_obs"], float)
    d = gap[0] - gap[1:]
    dn = np.asarray(inputs["delta_null"], float)
    mu = dn.mean(axis=0)
    if statistic == "raw":
        zo, zn = d - mu, dn - mu
    elif statistic == "share":
        gn = np.asarray(inputs["gap_null_none"], float)[:, None]
        zo, zn = (d - mu) / gap[0], (dn - mu) / gn
    else:
        floor = 1e-3
        if statistic.startswith("z_floor_"):
            floor = max(floor, float(statistic[len("z_floor_"):]) * float(np.median(inputs["gap_null_none"])))
        elif statistic != "z":
            raise ValueError(f"unknown statistic {statistic!r}")
        sd = np.maximum(dn.std(axis=0, ddof=1), floor)
        zo, zn = (d - mu) / sd, (dn - mu) / sd
    t_null = zn.max(axis=1)
    p_of = (1 + at_least(t_null[None, :], zo[:, None]).sum(axis=1)) / (len(t_null) + 1)
    best = int(np.argmax(zo))
    if p_of[best] > alpha or d[best] <= 0:
        return "none"
    ok = np.flatnonzero((p_of <= alpha) & (d > 0))
    return eff[int(ok[np.argmax(d[ok])])]


def _score(rows: list, name_of) -> tuple[pd.DataFrame, str]:
    new = []
    for r in rows:
        x = dict(r)
        if r["named"] != "direction_scatter":      # the aiming-scatter step held as run
            x["named"] = name_of(r)
        new.append(x)
    pc, tab, _ = score_cases(new)
    head = tab.set_index("group")
    g1, g4, g5 = head.iloc[0], head.iloc[3], head.iloc[4]
    line = (f"detectable named correctly {int(g1['count'])}/{int(g1['cases'])} ({g1['share']:.2f}, "
            f"{g1['wilson95_low']:.2f}-{g1['wilson95_high']:.2f}); false alarms base-model {int(g4['count'])}/"
            f"{int(g4['cases'])}, 96-element {int(g5['count'])}/{int(g5['cases'])}")
    return tab, line


def redecide(inputs: dict, rule: str, alpha: float) -> str:
    """The effect (or 'none') that ``rule`` names from one case's decision inputs."""
    eff = list(inputs["effects"])
    gap = np.asarray(inputs["gap_obs"], float)
    delta = gap[0] - gap[1:]
    z = (delta - np.asarray(inputs["mu"], float)) / np.asarray(inputs["sd"], float)
    t_null = np.asarray(inputs["t_null"], float)
    p_of = (1 + at_least(t_null[None, :], z[:, None]).sum(axis=1)) / (len(t_null) + 1)
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
    # the calibrated test's rules: where the Bayes evidence decided the run, its calibrated test's choice is the one
    # re-decided here
    rows = [{**r, "named": r.get("named_calibrated", r["named"])} for r in rows]
    if not rows:
        raise SystemExit(f"{a.rows}: no row with decision_inputs (rows written before 2026-11-28 lack them)")
    mism = {rule: [r["case"] for r in rows if redecide(r["decision_inputs"], rule, a.alpha)
                   != r.get("named_before_scatter", r["named"])] for rule in RULES}
    own = min(mism, key=lambda k: len(mism[k]))
    print(f"{len(rows)} cases; re-decided, the run's decision differs in: "
          + ", ".join(f"{k} {len(v)}" for k, v in mism.items())
          + f" (the run's rule is presumably {own}" + (f"; differs in {', '.join(mism[own])}: the neutral-fit check"
                                                        if mism[own] else "") + ")")
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
    if all("delta_null" in r["decision_inputs"] for r in rows):
        print("max-statistic tests recomputed from the stored null improvements (selection: largest improvement; "
              "the check that the named effect's fit is not neutral is not redone):")
        for st in STATISTICS:
            tab, line = _score(rows, lambda r, st=st: redecide_statistic(r["decision_inputs"], st, a.alpha))
            tab.insert(0, "rule", f"statistic {st}")
            out.append(tab)
            print(f"{st:>20}: {line}")
    res = pd.concat(out, ignore_index=True)
    if a.out:
        res.to_csv(a.out, index=False, float_format="%.4g")
    return res


if __name__ == "__main__":
    main()
