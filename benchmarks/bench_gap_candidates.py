"""How the Bayes evidence's decision depends on the candidate set (issue 32): each candidate left out in turn.

Reads the rows of ``bench_gap_oracle.py --families diagnosis`` (their stored log evidence per explanation, one row
per case and strength SD) and decides again without one candidate: the prior of "no effect" unchanged, the
effects' share spread over those left. Prints, per left-out candidate, the detectable effect cases named correctly
and the controls with an effect named, and for each truth whose candidate is left out how often another effect is
named instead (the misattribution a user risks when the cause is not a candidate).

The rows keep the chi-square fit check of the most probable effect only: where leaving a candidate out makes another
effect the most probable one, its fit is not known here and the case counts as named (stated as "fit check not
recomputed"). With every candidate the script reproduces the run's own figures (a check it prints).

    .venv/bin/python benchmarks/bench_gap_candidates.py --rows results/gap/s3m24/oracle_top_20261123/oracle_rows.csv \
        results/gap/s3m24/oracle_top_20261128/oracle_rows.csv
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd
from scipy.special import logsumexp

NO_EFFECT = ("none", "none_elements")


def decide(ll: np.ndarray, names: list[str], keep: list[str], prior_no_effect: float) -> tuple[float, str]:
    """P(no effect) and the most probable effect from log evidences ``ll`` (per ``names``) over ``keep``."""
    effs = [n for n in keep if n not in NO_EFFECT]
    idx = [names.index(n) for n in (*NO_EFFECT, *effs)]
    lp = np.r_[np.full(len(NO_EFFECT), np.log(prior_no_effect / len(NO_EFFECT))),
               np.full(len(effs), np.log((1 - prior_no_effect) / len(effs)))]
    a = ll[idx] + lp
    post = np.exp(a - logsumexp(a))
    return float(post[:len(NO_EFFECT)].sum()), effs[int(np.argmax(post[len(NO_EFFECT):]))]


def leave_one_out(rows: pd.DataFrame, threshold: float, fit_alpha: float, prior_no_effect: float) -> tuple:
    names = [c[3:] for c in rows.columns if c.startswith("ll_")]
    effects = [n for n in names if n not in NO_EFFECT]
    ll = rows[[f"ll_{n}" for n in names]].to_numpy(float)
    ctrl = (rows["target"] == "none").to_numpy()
    det = (~ctrl) & rows["detectable"].astype(bool).to_numpy()
    fit_ok = rows["fit_p_best_effect"].to_numpy(float) >= fit_alpha
    full = [decide(v, names, names, prior_no_effect) for v in ll]
    table, mis = [], []
    for drop in [None, *effects]:
        keep = [n for n in names if n != drop]
        named, unknown = [], 0
        for v, (p0_all, best_all), ok in zip(ll, full, fit_ok):
            p0, best = decide(v, names, keep, prior_no_effect)
            if p0 >= threshold:
                named.append("none")
            elif best == best_all:
                named.append(best if ok else "none")
            else:
                named.append(best)
                unknown += 1
        named = np.array(named)
        table.append({"left_out": drop or "(none: every candidate)", "named_correctly": int((named == rows["target"]
                                                                                           .to_numpy())[det].sum()),
                      "detectable": int(det.sum()), "false_alarms": int((named != "none")[ctrl].sum()),
                      "controls": int(ctrl.sum()), "fit_check_not_recomputed": unknown})
        if drop is not None:
            own = det & (rows["target"].to_numpy() == drop)
            if own.any():
                other = [b for v, o in zip(ll, own) if o for p0, b in [decide(v, names, keep, prior_no_effect)]
                         if p0 < threshold]
                mis.append({"truth_candidate": drop, "detectable": int(own.sum()), "named_another": len(other),
                            "instead": other})
    return pd.DataFrame(table), pd.DataFrame(mis)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rows", nargs="+", required=True, help="oracle_rows.csv of bench_gap_oracle.py "
                                                              "--families diagnosis (one per design)")
    ap.add_argument("--strength-sd", type=float, default=0.3)
    ap.add_argument("--threshold", type=float, default=0.05)
    ap.add_argument("--fit-alpha", type=float, default=0.001)
    ap.add_argument("--prior-no-effect", type=float, default=0.5)
    ap.add_argument("--out", default=None, help="CSV of the leave-one-out table (optional)")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    tabs, miss = [], []
    for path in a.rows:
        r = pd.read_csv(path)
        r = r[np.isclose(r["strength_sd"], a.strength_sd)].reset_index(drop=True)
        if r.empty:
            raise SystemExit(f"{path}: no rows with strength_sd {a.strength_sd}")
        tab, mis = leave_one_out(r, a.threshold, a.fit_alpha, a.prior_no_effect)
        tab.insert(0, "rows", path)
        tabs.append(tab)
        miss.append(mis)
        print(f"{path}: P(no effect) < {a.threshold:g}, fit p >= {a.fit_alpha:g}, prior P(no effect) "
              f"{a.prior_no_effect:g}, strength SD {a.strength_sd:g}")
        print(tab.drop(columns="rows").to_string(index=False))
    tab = pd.concat(tabs)
    both = tab.groupby("left_out", sort=False)[["named_correctly", "detectable", "false_alarms", "controls",
                                                "fit_check_not_recomputed"]].sum().reset_index()
    print("\nall designs together:")
    print(both.to_string(index=False))
    mis = pd.concat(miss)
    mis_all = mis.groupby("truth_candidate")[["detectable", "named_another"]].sum().reset_index()
    mis_all["instead"] = [", ".join(f"{k} {n}" for k, n in pd.Series(
        [x for lst in mis.loc[mis["truth_candidate"] == t, "instead"] for x in lst], dtype=object).value_counts()
        .items()) for t in mis_all["truth_candidate"]]
    print("\nthe truth's own candidate left out: detectable cases of that truth named as another effect "
          "(before the fit check):")
    print(mis_all.to_string(index=False))
    if a.out:
        both.to_csv(a.out, index=False)
    print(f"\n{time.perf_counter() - t0:.1f} s")
    return {"table": both, "misattribution": mis_all}


if __name__ == "__main__":
    main()
