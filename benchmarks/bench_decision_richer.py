"""The deficit decision on data from a richer truth (issue 31 item 4): how much worse does it decide when the forces
come from something the decision's model is not?

The first ``--n`` deficit and normal patients of the decision study (participants 0..n-1 and 100..100+n-1 of
`clinician_decision` in the full config: the same group strengths, drawn by the study's stream), whose forces are
made by the gap benchmark's truth generator (:mod:`neckstrength.gap.truths`, code apart from the decision):

- ``rich96``: 96 muscle elements at the model's joints, each element's strength = its group's strength x
  exp(N(0, 0.3^2)) (the finer truth the reduced model lumps);
- ``direction_error``: the model's own muscles, but every push off its intended direction by an angle drawn within
  a 5-15 deg cone (as a real push wanders);

then 5% log-normal noise (stream ``bench_decision_richer/noise``). Shipped decision settings, run with the model's
own P (as the study's runs), tests in ``decision_eig`` order, up to 25; the stopping rule is read afterwards from
log BF with the model's P and with the shipped recalibration (``clinician.decision.calibration``), "model misfit"
first. Compared with the same patients' runs of the study's ``decision_runs.csv`` (the model's own truth). Reports
the ROC area of log BF, the rule's outcome (deficit / no deficit / undecided / model misfit) and the median
best-fit RMS.

    python benchmarks/bench_decision_richer.py --n 20 [--start 0] [--truths rich96 direction_error] [--out runs.csv]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
import pandas as pd


def main() -> int:
    from neckstrength.config import (build_directions, decision_settings, decision_study_settings, derive_rng,
                                     full_model_from_config, joint_settings, load_config, model_from_config)
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.gap.forked import fork_map
    from neckstrength.gap.truths import CaseSettings, TruthForces, TruthSetup, draw_params, make_forces
    from neckstrength.sequential.cohort import simulate_participant
    from neckstrength.sequential.decision import DeficitDecision
    from neckstrength.sequential.decision_study import roc_auc
    from neckstrength.wrench import BasisCache

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--n", type=int, default=20, help="deficit and normal patients each")
    ap.add_argument("--start", type=int, default=0, help="skip the first this many of each kind (a second process)")
    ap.add_argument("--truths", nargs="+", default=["rich96", "direction_error"])
    ap.add_argument("--runs", default="results/clinician/s3m24/decision_runs.csv", help="the study's runs")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default=None, help="CSV of the runs (written as patients finish)")
    a = ap.parse_args()
    cfg = load_config(a.config)
    seed = int(cfg["seed"])
    full = full_model_from_config(cfg)
    model = model_from_config(full, cfg, "s3m24")
    dtab = build_directions(cfg)
    d, U = model_directions_table(model, dtab)
    dirs, fs = list(d["name"]), d["force_scale"].to_numpy(float)
    study, n_cand = decision_study_settings(cfg, "s3m24")
    dec_s = decision_settings(cfg, n_candidates=n_cand, calibration=None)
    cal = decision_settings(cfg).calibration
    joint = joint_settings(cfg)
    f0 = model.strengths
    setup = TruthSetup(full, model, d, np.asarray(cfg["geometry"]["head"]["centre"], float))
    cs = CaseSettings()
    grp = np.argmax(model.S, axis=1)
    n_def = study.cohort.n_deficit
    idx = [j for k in range(a.start, a.n) for j in (k, n_def + k)]
    print(f"bench_decision_richer: s3m24, {a.n} deficit + {a.n} normal patients of the study, truths {a.truths}; "
          f"{dec_s.label()}; seed {seed}; {platform.node()}, load {os.getloadavg()[0]:.1f}; "
          f"{time.strftime('%Y-%m-%d %H:%M:%S')} UTC", flush=True)

    def one(i):
        kind = "deficit" if i < n_def else "normal"
        f, forces_model, _ = simulate_participant(model, U, fs, f0, dec_s.group, kind == "deficit", study.cohort,
                                                  derive_rng(seed, "decision/s3m24/truth", i), cache=BasisCache())
        gidx = dec_s.group_indices(model.muscle_names)
        ratio = float(f[gidx].sum() / f0[gidx].sum())
        fc = TruthForces(setup)
        rows = []
        for truth in a.truths:
            rng = derive_rng(seed, f"bench_decision_richer/{truth}", i)
            ef = None
            if truth == "rich96":
                ef = full.strengths * (f / np.where(f0 > 0, f0, 1.0))[grp] * np.exp(
                    rng.normal(0.0, cs.element_spread, full.m))
            params = draw_params(setup, truth, cs, rng, fc)
            clean = make_forces(setup, truth, f, params, fc, ef)
            noise = np.exp(study.cohort.noise * derive_rng(seed, "bench_decision_richer/noise", i).standard_normal(
                len(clean)))
            forces = clean * noise
            t0 = time.time()
            dec = DeficitDecision(model, dirs, U, fs, f0, dec_s, joint, derive_rng(seed, "decision/s3m24/candidates", i))
            info = {"participant": i, "kind": kind, "true_ratio": ratio, "protocol": truth}
            rows.append({**info, **dec.history[-1]})
            for _ in range(min(study.n_max, len(dirs))):
                dn, _ = dec.propose()
                k = dirs.index(dn)
                if not np.isfinite(forces[k]) or forces[k] <= 0:
                    raise RuntimeError(f"participant {i}, {truth}: test {dn} not producible")
                dec.push(dn, float(forces[k]))
                rows.append({**info, **dec.history[-1]})
            h = dec.history[-1]
            print(f"participant {i} ({kind}, mf at {ratio:.0%}) {truth}: {h['decision']}, P {h['p_deficit']:.2f}, "
                  f"log BF {h['log_bf']:+.1f}, best fit {h['misfit_rms']:.1%} RMS; {time.time() - t0:.0f} s",
                  flush=True)
        return pd.DataFrame(rows)

    t0 = time.time()
    done = []
    for _, r in fork_map(one, idx, a.workers):
        done.append(r)
        if a.out:
            pd.concat(done, ignore_index=True).to_csv(a.out, index=False)
    runs = pd.concat(done, ignore_index=True)
    print(f"{len(idx)} patients in {time.time() - t0:.0f} s", flush=True)
    ref = pd.read_csv(a.runs, comment="#")
    ref = ref[ref["participant"].isin(idx)].copy()
    ref["protocol"] = "model's own truth (study)"
    both = pd.concat([ref, runs], ignore_index=True)
    out = []
    for protocol, g in both.groupby("protocol", sort=False):
        last = g.sort_values("t").groupby("participant").tail(1)
        row = {"truth": protocol}
        for t in (5, 10, 25):
            gt = g[g["t"] == t]
            row[f"auc_t{t}"] = roc_auc(gt.loc[gt["kind"] == "deficit", "log_bf"], gt.loc[gt["kind"] == "normal", "log_bf"])
        # the stopping rule read from log BF (min_tests, p_decide), "model misfit" (the run's own) first
        for name, to_p in (("model P", lambda x: 1 / (1 + np.exp(-x))),
                           ("recalibrated P", lambda x: 1 / (1 + np.exp(-np.array([cal.log_lr(v) for v in x], float))))):
            for kind in ("deficit", "normal"):
                per = []
                for _, gp in g[g["kind"] == kind].groupby("participant"):
                    gp = gp.sort_values("t")
                    gp = gp[gp["t"] >= dec_s.min_tests]
                    p = to_p(gp["log_bf"].to_numpy(float))
                    dd = np.where(gp["decision"].to_numpy() == "model misfit", "model misfit",
                                  np.where(p >= dec_s.p_decide, "deficit",
                                           np.where(p <= 1 - dec_s.p_decide, "no deficit", "undecided")))
                    hit = dd[dd != "undecided"]
                    per.append(hit[0] if len(hit) else "undecided")
                per = pd.Series(per)
                row[f"{name}, {kind}"] = " / ".join(f"{int((per == x).sum())}" for x in
                                                    ("deficit", "no deficit", "undecided", "model misfit"))
        row["median best-fit RMS after 25"] = (float(last["misfit_rms"].median()) if "misfit_rms" in last
                                               else float("nan"))
        out.append(row)
    pd.set_option("display.width", 250)
    print("rule outcomes: deficit / no deficit / undecided / model misfit")
    print(pd.DataFrame(out).to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
