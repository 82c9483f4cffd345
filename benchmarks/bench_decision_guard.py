"""The calibrated misfit guard of the deficit decision (issue 31): fitted on the decision study's forces-only runs
(the model's own patients), checked held out, and read on runs from a richer truth.

The guard flags a patient "model misfit" when, at some t >= min_tests, the best candidate's log RMS relative
force error, standardised by the study patients' median and sd at that t, exceeds ``factor``
(:class:`neckstrength.sequential.decision.MisfitGuard`; ``factor``: the ``1 - level`` quantile of the study
patients' largest standardised value over the session). Its
false-flag rate on the model's own patients is ``level`` by construction and checked held out (2 folds by
participant); its flag rate on the richer truths (:mod:`benchmarks.bench_decision_richer`'s runs: 96 elements,
pushes off direction) is measured here, per level.

    python benchmarks/bench_decision_guard.py --runs results/clinician/s3m24/decision_runs.csv \\
        --richer richer_runs.csv [--level 0.05] [--out guard.csv]

``--runs``: runs with the best-fit RMS (``misfit_rms``) at every t (the study's ``decision_runs.csv`` or its cache
``decision_cache/forces.csv``); ``--richer``: ``bench_decision_richer.py --out``'s CSV. ``--out`` writes the
guard (the file ``clinician.decision.misfit_guard`` reads).
"""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd


def rule_with_guard(runs: pd.DataFrame, guard, cal, dec) -> pd.DataFrame:
    """Per truth and kind, the stopping rule read afterwards from each run: at the first t >= min_tests at which the
    guard flags ("model misfit") or the recalibrated P reaches a threshold; with no guard for comparison."""
    out = []
    for (truth, kind), g in runs.groupby(["protocol", "kind"], sort=False):
        row = {"truth": truth, "kind": kind, "n": g["participant"].nunique()}
        for name, use in (("no guard", False), ("guard", True)):
            calls = []
            for _, gp in g.groupby("participant"):
                gp = gp[gp["t"] >= dec.min_tests].sort_values("t")
                call = "undecided"
                for t, lbf, rms in zip(gp["t"], gp["log_bf"], gp["misfit_rms"]):
                    if use and t <= guard.t_max and rms > guard.threshold(int(t)):
                        call = "model misfit"
                        break
                    p = 1 / (1 + np.exp(-cal.log_lr(float(lbf))))
                    if p >= dec.p_decide or p <= 1 - dec.p_decide:
                        call = "deficit" if p >= dec.p_decide else "no deficit"
                        break
                calls.append(call)
            c = pd.Series(calls)
            row[name] = " / ".join(str(int((c == x).sum())) for x in ("deficit", "no deficit", "undecided",
                                                                       "model misfit"))
            row[f"wrong, {name}"] = int((c == ("no deficit" if kind == "deficit" else "deficit")).sum())
        out.append(row)
    return pd.DataFrame(out)


def main() -> int:
    from neckstrength.config import decision_settings, decision_study_settings, load_config
    from neckstrength.io import atomic_write_csv
    from neckstrength.sequential.decision_study import fit_misfit_guard, misfit_flag_table

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--runs", required=True)
    ap.add_argument("--richer", default=None)
    ap.add_argument("--level", type=float, default=None, help="default: clinician.decision_study.misfit_level")
    ap.add_argument("--n-directions", type=int, default=25)
    ap.add_argument("--out", default=None)
    ap.add_argument("--force", action="store_true", help="overwrite --out")
    a = ap.parse_args()
    cfg = load_config(a.config)
    study, n_cand = decision_study_settings(cfg, "s3m24")
    dec = decision_settings(cfg, n_candidates=n_cand, calibration=None, misfit_guard=None)
    level = study.misfit_level if a.level is None else a.level
    runs = pd.read_csv(a.runs, comment="#")
    runs = runs[runs["protocol"] == "forces"]
    n_pat = runs.groupby("kind")["participant"].nunique().to_dict()
    guard, check = fit_misfit_guard(runs, dec, "s3m24", a.n_directions, level,
                                    source=f"{a.runs}: {n_pat} forces-only patients")
    pd.set_option("display.width", 250)
    print(f"patients of the model: {n_pat}; guard at level {level:g}: factor {guard.factor:.3f}")
    print("t, median best fit, its log sd, threshold: " + "; ".join(
        f"{t}: {np.exp(m):.1%} {s:.2f} {guard.threshold(t):.1%}"
        for t, m, s in zip(range(guard.t_from, guard.t_max + 1), guard.log_median, guard.log_sd)))
    print("held-out false flags on the model's own patients (2 folds by participant):")
    print(check.to_string(index=False))
    tabs = []
    for lv in check["level"]:
        g, _ = fit_misfit_guard(runs, dec, "s3m24", a.n_directions, float(lv))
        both = runs.assign(protocol="model's own truth (in sample)")
        if a.richer:
            both = pd.concat([both, pd.read_csv(a.richer, comment="#")], ignore_index=True)
        tabs.append(misfit_flag_table(both, g, dec.min_tests).assign(level=lv))
    print("flagged per truth and kind (any t >= min_tests):")
    print(pd.concat(tabs, ignore_index=True).to_string(index=False))
    if a.richer:
        print(f"the stopping rule with the recalibrated P and this guard (level {level:g}) read on each run: "
              "deficit / no deficit / undecided / model misfit (wrong calls: deficit for a normal participant, no "
              "deficit for a deficit patient)")
        print(rule_with_guard(pd.concat([runs.assign(protocol="model's own truth (in sample)"),
                                         pd.read_csv(a.richer, comment="#")], ignore_index=True),
                              guard, decision_settings(cfg).calibration, dec).to_string(index=False))
    if a.out:
        from pathlib import Path

        if Path(a.out).exists() and not a.force:
            raise SystemExit(f"{a.out} exists: pass --force to overwrite it")
        atomic_write_csv(guard.to_frame(), a.out,
                         [f"the calibrated misfit guard of the deficit decision (s3m24, forces only), fitted by "
                          f"benchmarks/bench_decision_guard.py on {a.runs}", f"check: {guard.check}"],
                         float_format="%.8g")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
