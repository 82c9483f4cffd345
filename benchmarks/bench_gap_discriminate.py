#!/usr/bin/env python
"""Benchmark: do the proposed additional measurements raise the share of correct identifications? (issue 17, item 5)

Simulated cases come from the benchmark generator (:func:`neckstrength.gap.benchmark.generate_cases`, kept apart
from the diagnosis): individual strengths, one injected effect of clear size, log-normal noise. Each case is
diagnosed blind on the model's test directions (screen level: no pairs, no refinement, no calibration; the
identified effect is the best held-out score). For the cases whose leaders are close (bootstrap P(best) of the
best below ``gap.discriminate.p_best_below``) three diagnoses are compared:

(i)   the original directions only;
(ii)  plus the ``n`` measurements proposed by :mod:`neckstrength.gap.discriminate`, "measured" on the truth (the
      generator's strengths and effect) with the case's own noise level; a repeated test direction enters as the
      geometric mean of its trials, a new surface point as a new direction;
(iii) plus ``n`` measurements drawn at random (uniform, with replacement) from the same pool, measured likewise.

A second score (``fit_*``) asks whether the added measurements carry the discriminating information, whatever the
cross-validated diagnosis makes of them: among the top candidates of (i), with their effect parameters fixed, the
one whose strengths fit all measured forces best (least squares of the relative residuals).

A third (``pred_*``, the decision that matches the design): among the same top candidates, the one whose predictive
distribution (:func:`neckstrength.gap.discriminate.predictive_choice`: the Laplace predictive from the measured
directions, whose expected log Bayes factors the proposal maximises) gives the new trials the highest likelihood,
equal prior. For (ii) the new trials are the proposed ones, for (iii) the random ones. Random measurements are
drawn from the pool entries every compared candidate can produce (the proposal's own choice set).
``--no-rediagnose`` skips the cross-validated rediagnosis of (ii) and (iii) (the costly part for s3m24).

Prints and writes (``--out``, JSON + markdown) the share of correct identifications in (i), (ii), (iii), the number
of cases, the seed streams, the sizes and the machine load. All random draws derive from the config seed via
``derive_rng`` with named keys (``gap-discriminate/...``).

Run from the repository root::

    .venv/bin/python benchmarks/bench_gap_discriminate.py --model p2m7 --replicates 8 --out bench_disc
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd


def _best_fit(ctx, forces, top, thetas, fit_candidate, losses: dict | None = None) -> str:
    """Of the top candidates (effect parameters fixed at the original diagnosis's all-direction fit), the one whose
    strengths fit all measured forces best (least squares of relative residuals = maximum likelihood at a common
    noise level; the same free strengths for all, so no penalty)."""
    from neckstrength.gap.fit import FitSettings

    out = {c: fit_candidate(ctx, forces, c, thetas[c], FitSettings(max_iter=15))[1] for c in top}
    if losses is not None:
        losses.update(out)
    return min(out, key=out.get)


def _paired(df: pd.DataFrame, reading: str = "") -> dict:
    """Discordant cases between (ii) and (iii) and between (ii) and (i) for one reading (``''`` the
    cross-validated diagnosis, ``'fit_'``, ``'pred_'``), with an exact two-sided sign test (McNemar's exact
    test: under no difference each discordant case is a fair coin)."""
    from scipy.stats import binomtest

    out = {}
    for other in ("i", "iii"):
        if not len(df):
            continue
        b = int((df[f"{reading}correct_ii"] & ~df[f"{reading}correct_{other}"]).sum())
        c = int((~df[f"{reading}correct_ii"] & df[f"{reading}correct_{other}"]).sum())
        out[f"{reading}ii_vs_{other}_discordant"] = [b, c]
        out[f"{reading}ii_vs_{other}_sign_test_p"] = float(binomtest(b, b + c).pvalue) if b + c else 1.0
    return out


def _wilcoxon(diff: pd.Series) -> float:
    """Two-sided Wilcoxon signed-rank p-value of paired differences (zeros dropped), 1.0 if all are zero."""
    from scipy.stats import wilcoxon

    d = diff.to_numpy(float)
    d = d[np.abs(d) > 1e-12]
    return float(wilcoxon(d).pvalue) if d.size else 1.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--model", default="p2m7")
    ap.add_argument("--effects", default="cocontraction,kinematic,origin_offset,point_scale",
                    help="injected effects, also the diagnosis's candidates")
    ap.add_argument("--replicates", type=int, default=8, help="cases per injected effect")
    ap.add_argument("--noise", type=float, default=0.05, help="log-normal SD of the measurement noise")
    ap.add_argument("--size", default="0.6,1.0", help="injected size range (share of the way to the far bound)")
    ap.add_argument("--measurements", type=int, default=3)
    ap.add_argument("--candidates", type=int, default=0, help="top candidates compared (0 = gap.discriminate)")
    ap.add_argument("--objective", default="", help="saturating, min or sum (empty = gap.discriminate)")
    ap.add_argument("--grid-points", type=int, default=4)
    ap.add_argument("--folds", type=int, default=100, help="folds (>= directions: leave-one-out)")
    ap.add_argument("--bootstrap", type=int, default=200)
    ap.add_argument("--max-cases", type=int, default=0, help="at most this many close cases (0 = all)")
    ap.add_argument("--no-rediagnose", action="store_true",
                    help="skip the cross-validated rediagnosis of (ii) and (iii); fit and predictive choices only")
    ap.add_argument("--out", default="")
    a = ap.parse_args()

    from neckstrength.config import (
        build_directions,
        diagnosis_settings,
        discriminate_settings,
        gap_context,
        head_from_config,
        load_config,
    )
    from neckstrength.gap.benchmark import BenchmarkSettings, blind, generate_cases
    from neckstrength.gap.diagnose import BlindData, diagnose
    from neckstrength.gap.discriminate import (
        candidate_predictions,
        extended_context,
        fit_candidate,
        measurement_pool,
        predictive_choice,
        propose_measurements,
    )
    from neckstrength.gap.effects import EFFECTS, compose
    from neckstrength.gap.engine import CalibrationSettings
    from neckstrength.gap.fit import FitSettings, Simulator
    from neckstrength.seeds import derive_rng

    t0, l0 = time.perf_counter(), os.getloadavg()
    cfg = load_config(a.config)
    seed = int(cfg["seed"])
    directions = build_directions(cfg)
    ctx = gap_context(cfg, a.model, directions)
    head, bands = head_from_config(cfg), cfg["geometry"]["plane_bands"]
    dset = discriminate_settings(cfg)
    dset = replace(dset, measurements=a.measurements, candidates=a.candidates or dset.candidates,
                   objective=a.objective or dset.objective)
    effects = tuple(e.strip() for e in a.effects.split(",") if e.strip())
    lo, hi = (float(x) for x in a.size.split(","))
    bs = BenchmarkSettings(effects=effects, replicates=a.replicates, controls=0, noise_rel=a.noise,
                           clear_size=(lo, hi))
    ds = replace(diagnosis_settings(cfg, effects), grid_points=a.grid_points, folds=a.folds, pairs_top=0,
                 refine_iter=0, reach_samples=0, reach_iter=0, bootstrap=a.bootstrap, starts=1,
                 fit=FitSettings(max_iter=15), calibration=CalibrationSettings(replicates=0))

    def say(m):
        print(f"[{time.perf_counter() - t0:.0f} s] {m}", flush=True)

    cases = generate_cases(ctx, bs, derive_rng(seed, f"gap-discriminate/cases/{a.model}"))
    say(f"{len(cases)} cases ({a.model}, {ctx.K} directions; effects {', '.join(effects)}; noise {a.noise}; "
        f"sizes {lo}-{hi})")
    diags = {d.name: d for d in diagnose(ctx, blind(cases), ds)}
    say("(i) diagnosed on the original directions")
    pool = measurement_pool(ctx, head, dset, bands)
    rows = []
    close = [c for c in cases if float(diags[c.name].effects.sort_values("rank")["p_best"].iloc[0]) < dset.p_best_below]
    if a.max_cases:
        close = close[: a.max_cases]
    say(f"{len(close)} of {len(cases)} cases have close leaders (P(best) < {dset.p_best_below}); pool of "
        f"{len(pool)} measurements")

    def measure(case, idx, tag):
        """Data with the pool entries ``idx`` measured on the case's truth, with its noise (stream
        gap-discriminate/measure/...). A repeat of a test direction enters as the geometric mean of all trials of
        that direction (the data keep one force per direction: the cross-validation holds out directions, and a
        repeat in another fold than its twin would be predicted from itself); a new surface point becomes a new
        direction (two measurements of one new point: their geometric mean)."""
        chosen = pool.iloc[list(idx)]
        new_names = list(dict.fromkeys(chosen.loc[chosen["kind"] == "new", "name"]))
        extra = pool[pool["name"].isin(new_names)].set_index("name").loc[new_names].reset_index()
        ext = extended_context(ctx, extra)
        meas_pool = extended_context(ctx, chosen)
        effs = [EFFECTS[n](meas_pool) for n in case.theta]
        clean = Simulator(meas_pool, compose(meas_pool, effs, [case.theta[n] for n in case.theta])).forces(
            case.f_true[None])[0][ctx.K:]
        rng = derive_rng(seed, f"gap-discriminate/measure/{a.model}/{case.name}/{tag}")
        logs = np.log(clean) + rng.normal(0.0, case.noise, len(idx))
        names = list(ctx.directions["name"])
        trials = {n: [float(np.log(f))] for n, f in zip(names, case.forces)}
        trials.update({n: [] for n in new_names})
        for (kind, src, nm), lf in zip(chosen[["kind", "source", "name"]].itertuples(index=False), logs):
            trials[src if kind == "repeat" else nm].append(float(lf))
        f = np.array([np.exp(np.mean(trials[n])) for n in names + new_names])
        return ext, f, logs

    for k, c in enumerate(close):
        d0 = diags[c.name]
        top = list(d0.effects.sort_values("rank")["candidate"][: dset.candidates])
        preds, sigma, _ = candidate_predictions(ctx, c.forces, d0, dset, pool)
        _, info = propose_measurements(ctx, c.forces, d0, head, dset, bands, pool, preds)
        names = list(pool["name"])
        prop = [names.index(m) for m in info["measurements"]]
        usable = np.nonzero(np.all([np.isfinite(p.log_force[ctx.K:]) for p in preds], axis=0))[0]
        rnd = [int(usable[j]) for j in derive_rng(seed, f"gap-discriminate/random/{a.model}/{c.name}").integers(
            0, len(usable), len(prop))]
        res, lik, pch, ptruth = {}, {}, {}, {}
        thetas = {r.candidate: json.loads(r.theta_values) for r in d0.effects.itertuples()}
        loss0: dict = {}
        lik["original"] = _best_fit(ctx, c.forces, top, thetas, fit_candidate, loss0)
        # prior for the combined reading: the original data's likelihood of each compared candidate (its fit's
        # loss ~ sum of squared log residuals, at the predictive's noise level)
        lo0 = np.array([loss0.get(p.label, np.inf) for p in preds])
        prior0 = np.exp(-(lo0 - lo0.min()) / (2 * sigma ** 2))
        cch = {}
        for tag, idx in (("proposed", prop), ("random", rnd)):
            ext, f, logs = measure(c, idx, tag)
            pch[tag], w = predictive_choice(preds, ctx.K, idx, logs, sigma)
            cch[tag] = predictive_choice(preds, ctx.K, idx, logs, sigma, prior0 / prior0.sum())[0]
            labels = [p.label for p in preds]
            ptruth[tag] = float(w[labels.index(c.label)]) if c.label in labels else 0.0
            res[tag] = None if a.no_rediagnose else diagnose(ext, [BlindData(c.name, f)], ds)[0]
            lik[tag] = _best_fit(ext, f, top, thetas, fit_candidate)
        rows.append({"case": c.name, "injected": c.label, "size_share": c.size_share, "noise": c.noise,
                     "p_best_i": float(d0.effects.sort_values("rank")["p_best"].iloc[0]),
                     "truth_in_top": c.label in top, "top": "/".join(top),
                     "identified_i": d0.summary["chosen"],
                     "identified_ii": "-" if res["proposed"] is None else res["proposed"].summary["chosen"],
                     "identified_iii": "-" if res["random"] is None else res["random"].summary["chosen"],
                     "pred_choice_i": top[0], "pred_choice_ii": pch["proposed"], "pred_choice_iii": pch["random"],
                     "comb_choice_i": preds[int(np.argmax(prior0))].label, "comb_choice_ii": cch["proposed"],
                     "comb_choice_iii": cch["random"],
                     "p_truth_ii": ptruth["proposed"], "p_truth_iii": ptruth["random"],
                     "fit_choice_i": lik["original"], "fit_choice_ii": lik["proposed"],
                     "fit_choice_iii": lik["random"],
                     "proposed": ";".join(info["measurements"]),
                     "random": ";".join(str(pool["name"].iloc[j]) for j in rnd),
                     "elbf_min_pair": min((min(v) for v in info["expected_log_bf"].values()), default=np.nan),
                     "sigma": info["sigma"]})
        r = rows[-1]
        say(f"case {k + 1}/{len(close)} {c.name} ({c.label}; top {r['top']}): (i) {r['identified_i']}, "
            f"(ii) {r['identified_ii']} / predictive {r['pred_choice_ii']} [{r['proposed']}], (iii) "
            f"{r['identified_iii']} / predictive {r['pred_choice_iii']} [{r['random']}]")
    df = pd.DataFrame(rows)
    for t in ("i", "ii", "iii"):
        df[f"correct_{t}"] = df[f"identified_{t}"] == df["injected"]
        df[f"fit_correct_{t}"] = df[f"fit_choice_{t}"] == df["injected"]
        df[f"pred_correct_{t}"] = df[f"pred_choice_{t}"] == df["injected"]
        df[f"comb_correct_{t}"] = df[f"comb_choice_{t}"] == df["injected"]
    l1 = os.getloadavg()
    summ = {"model": a.model, "directions": ctx.K, "effects": list(effects), "replicates_per_effect": a.replicates,
            "cases": len(cases), "close_cases": len(df), "noise": a.noise, "size": [lo, hi],
            "measurements": a.measurements, "pool": len(pool), "objective": dset.objective,
            "candidates_compared": dset.candidates,
            "p_best_below": dset.p_best_below, "grid_points": a.grid_points, "folds": ds.folds,
            "bootstrap": a.bootstrap, "seed": seed, "streams": "gap-discriminate/{cases,measure,random}/...",
            "share_correct_i": float(df["correct_i"].mean()) if len(df) else None,
            "share_correct_ii": float(df["correct_ii"].mean()) if len(df) and not a.no_rediagnose else None,
            "share_correct_iii": float(df["correct_iii"].mean()) if len(df) and not a.no_rediagnose else None,
            "truth_in_top": float(df["truth_in_top"].mean()) if len(df) else None,
            **{f"share_{r}correct_{t}": float(df[f"{r}correct_{t}"].mean()) if len(df) else None
               for r in ("fit_", "pred_", "comb_") for t in ("i", "ii", "iii")},
            "mean_p_truth_ii": float(df["p_truth_ii"].mean()) if len(df) else None,
            "mean_p_truth_iii": float(df["p_truth_iii"].mean()) if len(df) else None,
            "p_truth_ii_vs_iii_wilcoxon_p": _wilcoxon(df["p_truth_ii"] - df["p_truth_iii"]) if len(df) else None,
            "truth_in_top_cases": int(df["truth_in_top"].sum()) if len(df) else 0,
            **{f"share_pred_correct_{t}_truth_in_top": float(df.loc[df["truth_in_top"], f"pred_correct_{t}"].mean())
               if len(df) and df["truth_in_top"].any() else None for t in ("i", "ii", "iii")},
            "rediagnosed": not a.no_rediagnose,
            **(_paired(df) if not a.no_rediagnose else {}), **_paired(df, "fit_"), **_paired(df, "pred_"),
            **_paired(df, "comb_"),
            "wall_s": time.perf_counter() - t0, "load_start": l0, "load_end": l1, "cpu_count": os.cpu_count()}
    by = (df.groupby("injected")[[f"{r}correct_{t}" for r in ("", "fit_", "pred_", "comb_")
                                  for t in ("i", "ii", "iii")]
                                 ].agg(["sum", "count"])
          if len(df) else pd.DataFrame())
    print(df.drop(columns=["proposed", "random"]).to_string(index=False))
    print(json.dumps(summ, indent=1))
    if a.out:
        out = Path(a.out)
        out.mkdir(parents=True, exist_ok=True)
        df.to_csv(out / "cases.csv", index=False)
        (out / "summary.json").write_text(json.dumps(summ, indent=1))
        (out / "by_effect.txt").write_text(by.to_string())


if __name__ == "__main__":
    main()
