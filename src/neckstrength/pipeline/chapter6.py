"""Pipeline stages of ``workflow/rules/chapter6.smk``: Algorithms 7-9, the joint estimator, criteria,
order comparison, Table 6.1 and figures."""

from __future__ import annotations

import json
import time
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from neckstrength.config import (
    chapter6_settings,
    dataset_from_config,
    full_model_from_config,
    joint_settings,
    model_from_config,
    seed_sequence,
)
from neckstrength.estimation.datasets import (
    Dataset,
    simulated_dataset,
    thesis_f_actual,
    thesis_result_table,
)
from neckstrength.io import atomic_write_csv, atomic_write_text
from neckstrength.pipeline.common import load_directions
from neckstrength.sequential.algorithms import (
    SequentialState,
    SimulatedSet,
    StrengthGrid,
    fit_point_estimate,
    run_sequence,
    sample_prior,
    scaled_baseline,
    stop_by_expected_gain,
)
from neckstrength.sequential.analysis import (
    analyse,
    bins_table,
    expected_gain_table,
    measure_from,
    order_summary_table,
    posterior_table,
    subset_rows,
)
from neckstrength.sequential.joint import JointPosterior, run_joint
from neckstrength.sequential.joint_estimate import run_joint_estimate, write_joint_estimate
from neckstrength.sequential.orders import stop_iteration
from neckstrength.sequential.plots import (
    fig_criteria_curves,
    fig_expected_dS,
    fig_iterations,
    fig_order_entropy,
    fig_posteriors,
    fig_radar_sagittal,
)
from neckstrength.wrench import solve
from neckstrength.seeds import generator

RUN_OUTPUTS = ("estimate", "iterations", "posteriors", "expected_dS", "orders", "order_summary", "subsets", "fit",
               "bins", "summary")


def chapter6_dataset(model, directions: pd.DataFrame, dataset: str, config: Mapping) -> Dataset:
    """'Sim' (f_a from Table 6.1, measurements M(f_a, u_i), Sec. 6.5.1) or a participant (Table A.2)."""
    c = config["chapter6"]
    thesis_dir = config["data"]["thesis_dir"]
    sim_tables = c.get("simulated", {})
    if dataset in sim_tables:
        fa = thesis_f_actual(model, thesis_dir, dataset, table=sim_tables[dataset])
        groups = c.get("emg_groups", {}).get(model.name, []) if c.get("simulated_emg", True) else []
        return simulated_dataset(model, directions, dataset, fa, groups, c.get("simulated_emg_band", 0.05))
    return dataset_from_config(config, "chapter6", model, directions, dataset)


def _seeds(config: Mapping, key: str) -> tuple[np.random.SeedSequence, ...]:
    ss = seed_sequence(config["seed"], key)
    return tuple(ss.spawn(2))


def _gamma(config: Mapping, model) -> np.ndarray | None:
    g = config["chapter6"].get("gamma")
    if not g:
        return None
    return np.array([float(g.get(n, 0.0)) for n in model.muscle_names])


def chapter6_run(config: Mapping, model_name: str, dataset: str, directions_csv: str | Path,
                         outputs: Mapping[str, str | Path]) -> None:
    t_start = time.time()
    c = config["chapter6"]
    model = model_from_config(full_model_from_config(config), config, model_name)
    d = load_directions(directions_csv)
    data = chapter6_dataset(model, d, dataset, config)
    settings = chapter6_settings(config, model_name)
    gamma = _gamma(config, model)
    f0, a, a_i = scaled_baseline(model, data)
    key = f"chapter6/{model_name}/{dataset}"
    ss_prior, ss_prop = _seeds(config, key)
    print(f"model {model_name}, data set {dataset}: {model.m} muscles, {len(data.directions)} directions; "
          f"f_0 = a f'_base with a = {a:.4f} (mean of {np.round(a_i, 4).tolist()}); settings {settings}", flush=True)
    F = sample_prior(f0, settings.prior_sd_rel, settings.n_candidates, generator(ss_prior))
    bin_list = [settings.n_bins] + [int(b) for b in c.get("bins_sensitivity", []) if int(b) != settings.n_bins]
    grids = [StrengthGrid.around(f0, settings.prior_sd_rel, nb, settings.bin_range_sd) for nb in bin_list]
    sims = SimulatedSet.build(model, data.directions, data.U, F, grids, settings.n_wbins,
                              progress=lambda s: print(s, flush=True))
    n_orders = int(c.get("n_orders_sampled", 2000))
    res = {}
    alpha_cache = {}     # same candidates on every grid: the accepted candidates' activations are solved once
    for nb, sim in zip(bin_list, sims):
        t0 = time.time()
        st = replace(settings, n_bins=nb)
        res[nb] = analyse(model, data, sim, st, ss_prop, gamma, n_orders, ss_prop,
                           progress=(lambda s: print(s, flush=True)) if nb == settings.n_bins else None,
                           alpha_cache=alpha_cache)
        print(f"n_bins {nb}: order {[data.directions[i] for i in res[nb]['order']]} in {time.time() - t0:.1f} s",
              flush=True)
    main = res[settings.n_bins]
    sim = sims[0]
    state = main["state"]
    names = list(model.muscle_names)
    truth = data.f_true if data.f_true is not None else np.full(model.m, np.nan)
    dindex = {n: i + 1 for i, n in enumerate(data.directions)}
    hdr = [f"Chapter 6 sequential estimate (Algorithms 7-9): model {model_name}, data set {dataset}",
           f"N_F {settings.n_candidates}, N_S {settings.n_sim}, bins {settings.n_bins}, likelihood {settings.likelihood}, "
           f"predictive {settings.predictive}; seed {config['seed']} + crc32('{key}')"]

    # estimate (Table 6.1 row) and per-iteration trajectory (Figs. 6.4b / 6.5b / 6.10)
    est = state.estimate()
    est.insert(1, "f_base", model.strengths)
    est.insert(2, "f_0", f0)
    est["f_actual"] = truth
    D_fc, fit = fit_point_estimate(model, data, est["f_c"].to_numpy(), settings.epsilon)
    D_fc_free, fit_free = fit_point_estimate(model, replace(data, alpha_lb=None, alpha_ub=None),
                                             est["f_c"].to_numpy(), settings.epsilon)
    atomic_write_csv(est, outputs["estimate"], hdr + [f"D(f_c) = {D_fc:.4f}; v_c = posterior variance (N^2)"],
                     float_format="%.6g")
    it = main["iterations"].copy()
    it.insert(2, "direction_index", [dindex.get(x, 0) for x in it["direction"]])
    it["f_actual"] = np.tile(truth, len(it) // model.m)
    atomic_write_csv(it, outputs["iterations"], hdr, float_format="%.6g")

    # posterior PDFs per iteration (density per N)
    posteriors, ess = posterior_table(state, sim, names)
    atomic_write_csv(posteriors, outputs["posteriors"], hdr, float_format="%.6g")

    # expected entropy reduction per iteration, direction and muscle (Fig. 6.8)
    dS = expected_gain_table(main["proposals"], names, dindex)
    atomic_write_csv(dS, outputs["expected_dS"], hdr + ["dS = Eq. 6.6 expected entropy reduction (nats); score = "
                                                        "Eq. 6.7/6.8"], float_format="%.6g")

    # orders (Fig. 6.7)
    K = sim.K
    orders, H, is_sel = main["orders"], main["H_orders"], main["is_selected"]
    od = pd.DataFrame(H, columns=[f"H_{t}" for t in range(K + 1)])
    od.insert(0, "order", ["-".join(str(i + 1) for i in o) for o in orders])
    od.insert(1, "selected", is_sel)
    exact = main["subsets"] is not None
    atomic_write_csv(od, outputs["orders"], hdr + [("all K! orders (exact, from the 2^K subsets)" if exact else
                                                    f"{len(orders) - 1} sampled orders + the selected one") +
                                                   "; H_t = mean over muscles of the posterior entropy after t tests"],
                     float_format="%.6g")
    order_summary = order_summary_table(H, is_sel)
    atomic_write_csv(order_summary, outputs["order_summary"], hdr, float_format="%.6g")

    # subsets (exact permutation analysis)
    subs = subset_rows(main["subsets"], data.directions, names)
    atomic_write_csv(subs, outputs["subsets"], hdr + ["posterior after every subset of tested directions (bit i = "
                                                      "direction i + 1)" if exact else "K > 12: not tabulated"],
                     float_format="%.6g")

    # fit of the point estimate (within the data set's activation bounds, as D(f_c); and without) and of the
    # baselines (Fig. 6.6; no activation bounds)
    fit["simulated_no_emg_N"] = fit_free["simulated_N"]
    wb, _, _ = solve(model, np.vstack([model.strengths, f0]), data.U)
    fit["baseline_N"] = wb[0] / data.force_scale
    fit["scaled_baseline_N"] = wb[1] / data.force_scale
    fit.insert(1, "direction_index", [dindex[x] for x in fit["direction"]])
    atomic_write_csv(fit, outputs["fit"], hdr + [f"D(f_c) = {D_fc:.4f} (Eqs. 5.5/5.6, epsilon {settings.epsilon}, "
                                                 f"within the data set's activation bounds); without bounds "
                                                 f"{D_fc_free:.4f}"], float_format="%.6g")

    # bin sensitivity
    bins = bins_table(res, names, est)
    atomic_write_csv(bins, outputs["bins"], hdr + ["same candidates, simulations and random draws on other strength "
                                                   "grids; order = selected direction indices"], float_format="%.6g")

    # stop criteria, estimate jumps
    E_it = it.pivot(index="iteration", columns="muscle", values="f_c")[names].to_numpy()
    scores = [float(p.table()["score"].max()) for p in main["proposals"]]
    sc = c.get("stop", {})
    t_retro = stop_iteration(E_it, sc.get("rel_tol", 0.05))
    t_gain = stop_by_expected_gain(scores, sc.get("gain_frac", 0.2))
    tc = min(int(c.get("compare_after", 4)), K)
    rel_tc = (E_it[tc] - E_it[K]) / E_it[K]
    jumps = np.diff(E_it, axis=0) / E_it[:-1]
    summary = {
        "model": model_name, "dataset": dataset, "f0": f0.tolist(), "scale_a": a, "scale_a_per_direction": a_i.tolist(),
        "D_fc": D_fc, "D_fc_no_emg": D_fc_free, "order": [data.directions[i] for i in main["order"]],
        "order_index": [int(i) + 1 for i in main["order"]], "scores": scores,
        "stop_retrospective": t_retro, "stop_expected_gain": t_gain, "stop_rel_tol": sc.get("rel_tol", 0.05),
        "stop_gain_frac": sc.get("gain_frac", 0.2), "compare_after": tc,
        "rel_change_after_compare": dict(zip(names, rel_tc.tolist())),
        "max_abs_jump": dict(zip(names, np.abs(jumps).max(axis=0).tolist())),
        "max_abs_jump_after_compare": dict(zip(names, (np.abs(jumps[tc:]).max(axis=0) if tc < K
                                                       else np.zeros(model.m)).tolist())),
        "bins_max_rel_diff_f_c": float(bins["rel_diff_f_c_vs_main"].abs().max()),
        "bins_orders": {str(nb): "-".join(str(i + 1) for i in r["order"]) for nb, r in res.items()},
        "order_exact": exact, "n_orders": int(len(orders)),
        "ess_share_by_iteration": ess,
        "settings": asdict(settings), "gamma": None if gamma is None else gamma.tolist(),
        "seed": config["seed"], "seed_key": key, "sim": sim.meta, "seconds": time.time() - t_start,
    }
    atomic_write_text(json.dumps(summary, indent=2, default=float), outputs["summary"])
    print(f"done in {time.time() - t_start:.1f} s; D(f_c) = {D_fc:.3f}; stop {t_retro} (retrospective), "
          f"{t_gain} (expected gain)", flush=True)


def chapter6_figures(config: Mapping, model_name: str, dataset: str, directions_csv,
                             inputs: Mapping[str, str], outputs: Mapping[str, str]) -> None:
    from neckstrength.plotting import radar_grid_series

    est = pd.read_csv(inputs["estimate"], comment="#")
    it = pd.read_csv(inputs["iterations"], comment="#")
    post = pd.read_csv(inputs["posteriors"], comment="#")
    dS = pd.read_csv(inputs["expected_dS"], comment="#")
    orders = pd.read_csv(inputs["orders"], comment="#")
    fit = pd.read_csv(inputs["fit"], comment="#")
    summ = json.loads(Path(inputs["summary"]).read_text())
    K = len(fit)
    tag = f"{model_name}, {dataset}"
    seq = " ".join(str(i) for i in summ["order_index"])
    fig_posteriors(post, est, outputs["posteriors"], f"Posterior PDFs after each measurement ({tag}); order {seq}")
    fig_iterations(it, outputs["iterations"], f"Expected value (black) and variance (blue) per iteration ({tag}); "
                   "x: direction index tested")
    fig_order_entropy(orders, outputs["orders"], f"Mean posterior entropy: entropy-reducing order {seq} (red) vs "
                      f"{len(orders) - 1} other orders ({tag})")
    fig_expected_dS(dS, K, outputs["expected_dS"], f"Expected entropy reduction (Eq. 6.6) per direction and muscle "
                    f"({tag}); selected index green, tested grey")
    tc = int(summ["compare_after"])
    T = int(post["iteration"].max())
    fig_posteriors(post, est, outputs["stop"], f"Posterior after {tc} (blue) vs after {T} measurements (black), "
                   f"prior green ({tag})", iterations=[0, tc, T],
                   styles={tc: {"color": "blue", "lw": 1.5, "label": f"after {tc}"},
                           T: {"color": "black", "lw": 1.5, "label": f"after {T}"}})
    d = load_directions(directions_csv)
    d = d[d["name"].isin(fit["direction"])]
    f = fit.set_index("direction")
    series = [("measured", f["measured_N"], {"color": "red", "ls": "--", "lw": 1.5}),
              ("model at f_c", f["simulated_N"], {"color": "black", "lw": 2}),
              ("baseline f'_base", f["baseline_N"], {"color": "blue", "lw": 1}),
              ("scaled baseline f_0", f["scaled_baseline_N"], {"color": "green", "lw": 1})]
    if "simulated_no_emg_N" in f and not np.allclose(f["simulated_no_emg_N"], f["simulated_N"], rtol=1e-6):
        series.insert(2, ("model at f_c, no EMG bounds", f["simulated_no_emg_N"], {"color": "grey", "ls": ":",
                                                                                    "lw": 1.5}))
    title = f"Fit of the final estimate ({tag}); D(f_c) = {summ['D_fc']:.2f}"
    if bool(d["sagittal"].all()):
        fig_radar_sagittal(d, series, outputs["radar"], title)
    else:
        radar_grid_series(d, series, outputs["radar"], title, rlabel="N")


def chapter6_table(config: Mapping, model_name: str, datasets: Sequence[str], estimates: Sequence[str],
                           summaries: Sequence[str], out_table: str | Path, out_stop: str | Path) -> pd.DataFrame:
    """Table 6.1 regenerated (f_c, v_c, D(f_c), f_a) beside the thesis; stop points and late jumps per data set."""
    c = config["chapter6"]
    table = c.get("thesis_table", "table_6_1_p2m7_sequential.csv")
    thesis = thesis_result_table(config["data"]["thesis_dir"], model_name, table=table) if model_name == "p2m7" \
        else pd.DataFrame(columns=["dataset", "quantity", "group", "value_numeric"])
    rows, stop_rows = [], []
    for ds, e_path, s_path in zip(datasets, estimates, summaries):
        est = pd.read_csv(e_path, comment="#").set_index("muscle")
        meta = json.loads(Path(s_path).read_text())
        t = thesis[thesis["dataset"] == ds]
        for q, col in (("f_a", "f_actual"), ("f_c", "f_c"), ("v_c", "v_c")):
            for n in est.index:
                tr = t[(t["quantity"] == q) & (t["group"] == n)]
                th = float(tr["value_numeric"].iloc[0]) if len(tr) else np.nan
                ours = float(est.loc[n, col])
                if q == "f_a" and not np.isfinite(ours) and not len(tr):
                    continue
                rows.append({"dataset": ds, "quantity": q, "muscle": n, "thesis": th, "ours": ours,
                             "difference": ours - th, "rel_difference": (ours - th) / th if th else np.nan})
        tr = t[t["quantity"] == "D_fc"]
        th = float(tr["value_numeric"].iloc[0]) if len(tr) else np.nan
        rows.append({"dataset": ds, "quantity": "D_fc", "muscle": "", "thesis": th, "ours": meta["D_fc"],
                     "difference": meta["D_fc"] - th, "rel_difference": np.nan})
        if "D_fc_no_emg" in meta:  # differs from D_fc only where the data set bounds activations (simulated EMG)
            rows.append({"dataset": ds, "quantity": "D_fc_no_emg", "muscle": "", "thesis": np.nan,
                         "ours": meta["D_fc_no_emg"], "difference": np.nan, "rel_difference": np.nan})
        # the pattern of the variances across muscles (thesis: TC-E low, TS-E high): Spearman rank correlation
        vc = pd.DataFrame([r for r in rows if r["dataset"] == ds and r["quantity"] == "v_c"])
        if len(vc) > 2 and vc["thesis"].notna().all():
            rho = float(vc["ours"].rank().corr(vc["thesis"].rank()))
            rows.append({"dataset": ds, "quantity": "v_c_rank_correlation", "muscle": "", "thesis": np.nan,
                         "ours": rho, "difference": np.nan, "rel_difference": np.nan,
                         "note": "Spearman correlation of v_c across the muscles, ours vs thesis"})
        rel = meta["rel_change_after_compare"]
        worst = max(rel, key=lambda k: abs(rel[k]))
        jumps = meta["max_abs_jump_after_compare"]
        wj = max(jumps, key=lambda k: jumps[k])
        stop_rows.append({"dataset": ds, "order": " ".join(str(i) for i in meta["order_index"]),
                          "stop_retrospective": meta["stop_retrospective"],
                          "stop_expected_gain": meta["stop_expected_gain"], "compare_after": meta["compare_after"],
                          "max_rel_change_after_compare": rel[worst], "muscle_max_rel_change": worst,
                          "max_jump_after_compare": jumps[wj], "muscle_max_jump": wj,
                          "bins_max_rel_diff_f_c": meta["bins_max_rel_diff_f_c"],
                          "thesis_note": {"S005": "thesis: estimate unchanged after 4 of 7 measurements (Figs. 6.8/6.9)",
                                          "S006": "thesis: TC-E >33% lower after 4 than after 7 (Fig. 6.10)"}.get(ds, "")})
    df = pd.DataFrame(rows)
    atomic_write_csv(df, out_table, [f"Table 6.1 regenerated ({model_name}): ours beside the thesis; difference = "
                                     "ours - thesis; v_c = posterior variance (N^2)",
                                     "participants: our test-point geometry is a reconstruction, so values are not "
                                     "expected to match digit for digit"], float_format="%.4g")
    atomic_write_csv(pd.DataFrame(stop_rows), out_stop,
                     [f"Stop points ({model_name}): stop_retrospective = first t from which every later estimate stays "
                      f"within rel_tol of the final one; stop_expected_gain = measurements after which the best "
                      "remaining Eq. 6.7 score < gain_frac x the first one",
                      "max_rel_change_after_compare = (E_after_compare - E_final) / E_final, largest |.| over muscles; "
                      "max_jump_after_compare = largest one-step relative change of an estimate after that"],
                     float_format="%.4g")
    return df


def chapter6_order_comparison(config: Mapping, directions_csv, out_csv: str | Path, out_fig: str | Path) -> pd.DataFrame:
    """Beyond the thesis: entropy-reducing order vs all other orders, averaged over simulated participants.

    Participants: ``f_a = scale f'_base (1 + noise_sd_rel z)`` (Sec. 6.5.1's recipe). Per participant and
    number of tests t: mean posterior entropy and mean relative error |E - f_a| / f_a of the entropy-reducing
    order (Eq. 6.7 with the prior predictive, as printed), of the same with the posterior predictive, of the
    average order (all K! orders via the subsets) and of the best order in hindsight.
    """

    c = config["chapter6"]
    oc = c["order_comparison"]
    model = model_from_config(full_model_from_config(config), config, oc.get("model", "p2m7"))
    d = load_directions(directions_csv)
    base_settings = chapter6_settings(config, model.name, n_candidates=int(oc["n_candidates"]))
    ss = seed_sequence(config["seed"], "chapter6/order_comparison")
    groups = c.get("emg_groups", {}).get(model.name, []) if c.get("simulated_emg", True) else []
    rows = []
    for p_i, child in enumerate(ss.spawn(int(oc["n_participants"]))):
        s_truth, s_prior, s_prop = child.spawn(3)
        rng = generator(s_truth)
        fa = sample_prior(oc.get("scale", 1.5) * model.strengths, oc.get("noise_sd_rel", 0.4), 1, rng)[0]
        data = simulated_dataset(model, d, f"P{p_i + 1}", fa, groups, c.get("simulated_emg_band", 0.05))
        f0, _, _ = scaled_baseline(model, data)
        F = sample_prior(f0, base_settings.prior_sd_rel, base_settings.n_candidates, generator(s_prior))
        grid = StrengthGrid.around(f0, base_settings.prior_sd_rel, base_settings.n_bins, base_settings.bin_range_sd)
        sim, = SimulatedSet.build(model, data.directions, data.U, F, [grid], base_settings.n_wbins)
        res = {}
        cache = {}
        for crit, st in (("entropy-reducing (prior predictive)", base_settings),
                         ("entropy-reducing (posterior predictive)", replace(base_settings, predictive="posterior"))):
            res[crit] = analyse(model, data, sim, st, s_prop, None, 0, s_prop, alpha_cache=cache)
        r0 = next(iter(res.values()))
        sub = r0["subsets"]
        K = sim.K
        err_sub = np.abs(sub["E"] - fa[None, :]) / fa[None, :]                # (2^K, m)
        Hm = sub["H"].mean(axis=1)
        em = err_sub.mean(axis=1)
        orders = r0["orders"]
        masks = np.column_stack([np.zeros(len(orders), dtype=np.int64), np.cumsum(np.left_shift(1, orders), axis=1)])
        for t in range(K + 1):
            Ht, et = Hm[masks[:, t]], em[masks[:, t]]
            rows.append({"participant": p_i + 1, "t": t, "criterion": "random order (mean of all K!)",
                         "entropy": Ht.mean(), "rel_error": et.mean(), "entropy_rank": np.nan})
            rows.append({"participant": p_i + 1, "t": t, "criterion": "best order in hindsight (entropy)",
                         "entropy": Ht.min(), "rel_error": et[np.argmin(Ht)], "entropy_rank": 0.0})
            for crit, r in res.items():
                mask = int(np.sum(np.left_shift(1, r["order"][:t]))) if t else 0
                rows.append({"participant": p_i + 1, "t": t, "criterion": crit, "entropy": Hm[mask],
                             "rel_error": em[mask], "entropy_rank": float((Ht < Hm[mask] - 1e-12).mean())})
    df = pd.DataFrame(rows)
    atomic_write_csv(df, out_csv, ["Chapter 6 beyond the thesis: entropy-reducing order vs random orders over "
                                   f"{oc['n_participants']} simulated participants ({model.name}, N_F "
                                   f"{oc['n_candidates']}, N_S {base_settings.n_sim})",
                                   "entropy = mean posterior entropy over muscles (nats); rel_error = mean |E - f_a| / "
                                   "f_a; entropy_rank = share of all K! orders with lower entropy after t tests"],
                     float_format="%.5g")
    curves = df.groupby(["criterion", "t"], sort=False)[["entropy", "rel_error"]].mean().reset_index()
    fig_criteria_curves(curves, "mean posterior entropy (nats)",
                        f"Entropy-reducing vs random orders, mean over {oc['n_participants']} simulated participants "
                        f"({model.name})", out_fig)
    return df


def _seed(config: Mapping, key: str) -> np.random.SeedSequence:
    return seed_sequence(config["seed"], key)


def _print(s: str) -> None:
    print(s, flush=True)


def chapter6_joint(config: Mapping, model_name: str, dataset: str, directions_csv, out_iterations, out_estimate,
                    out_summary) -> pd.DataFrame:
    """The joint sequential estimator on one data set with every criterion of ``chapter6.joint.criteria``.

    Outputs: iterations (criterion, iteration, direction, muscle, E, Var, entropy, ESS share, resamples),
    the final estimate per criterion beside the truth (simulated data sets) and a summary with seeds and timing.
    """
    jc = config["chapter6"].get("joint", {})
    model = model_from_config(full_model_from_config(config), config, model_name)
    data = chapter6_dataset(model, load_directions(directions_csv), dataset, config)
    key = f"chapter6/joint/{model_name}/{dataset}"
    res = run_joint_estimate(model, data, joint_settings(config), jc.get("criteria", ["joint_eig", "marginal_entropy"]),
                             bool(jc.get("use_emg", False)), int(config["seed"]), key, _seed(config, key))
    write_joint_estimate(res, out_iterations, out_estimate, out_summary)
    return res.iterations


def chapter6_criteria(config: Mapping, model_name: str, directions_csv, out_table, out_summary,
                              out_fig) -> pd.DataFrame:
    """Criteria compared over simulated participants, all judged on the joint posterior after t tests.

    Participants ``f_a = scale f'_base (1 + noise_sd_rel z)`` (Sec. 6.5.1's recipe), forces only (no EMG bounds:
    the same information for every criterion). Per participant the same initial candidates serve every
    criterion; the thesis's criterion ('thesis (Alg. 7-9)') picks its order on the marginal scheme
    (:mod:`neckstrength.sequential`, its own N_F candidates) and that order is replayed on the joint posterior.
    """
    import matplotlib

    matplotlib.use("Agg")

    from neckstrength.wrench.batched import BasisCache

    c = config["chapter6"]
    cc = dict(c["criteria_comparison"])
    cc.update(cc.pop("model_settings", {}).get(model_name, {}))
    model = model_from_config(full_model_from_config(config), config, model_name)
    d = load_directions(directions_csv)
    n_cand = int(cc.get("n_candidates", 50_000))
    settings = joint_settings(config, n_candidates=n_cand)
    th_settings = chapter6_settings(config, model_name, n_candidates=n_cand)
    n_max = cc.get("n_max")
    criteria = list(cc.get("criteria", ["joint_eig", "marginal_entropy"]))
    n_random = int(cc.get("n_random", 5))
    thesis = bool(cc.get("thesis_criterion", True))
    ss = _seed(config, f"chapter6/criteria/{model_name}")
    cache = BasisCache()
    rows = []
    t_start = time.time()
    for p_i, child in enumerate(ss.spawn(int(cc["n_participants"]))):
        s_truth, s_cand, s_prop, s_thesis = child.spawn(4)
        rng = generator(s_truth)
        f_scale = cc.get("scale", 1.5) * model.strengths          # the recipe's centre: error scale per muscle
        fa = sample_prior(f_scale, cc.get("noise_sd_rel", 0.4), 1, rng)[0]
        try:
            data = simulated_dataset(model, d, f"P{p_i + 1}", fa)
        except ValueError as e:             # f_a that cannot produce every direction: redraw is not seeded here
            _print(f"participant {p_i + 1}: skipped ({e})")
            continue
        f0, _, _ = scaled_baseline(model, data)
        measure = measure_from(data)
        runs = [(crit, crit, None) for crit in criteria]
        prop_rngs = {crit: generator(s_prop) for crit in criteria}
        for r in range(n_random):
            runs.append(("random", f"random #{r + 1}", None))
        if thesis:
            F = sample_prior(f0, th_settings.prior_sd_rel, th_settings.n_candidates, generator(s_thesis))
            grid = StrengthGrid.around(f0, th_settings.prior_sd_rel, th_settings.n_bins, th_settings.bin_range_sd)
            sim, = SimulatedSet.build(model, data.directions, data.U, F, [grid], th_settings.n_wbins, cache=cache)
            state = SequentialState(model, sim, data.force_scale, th_settings)
            run_sequence(state, measure, generator(s_thesis), n_max=n_max)
            runs.append(("thesis (Alg. 7-9)", "thesis (Alg. 7-9)", state.tested))
        rnd = generator(s_prop.spawn(1)[0])
        for crit, label, order in runs:
            post = JointPosterior(model, data.directions, data.U, data.force_scale, f0, settings,
                                  generator(s_cand), cache=cache)
            it = run_joint(post, measure, crit if order is None else "fixed order",
                           prop_rngs.get(crit, rnd), order=order, f_true=fa, n_max=n_max)
            g = it.groupby("iteration", sort=True)
            for t, gi in g:
                rows.append({"participant": p_i + 1, "criterion": "random" if crit == "random" else label,
                             "run": label, "t": int(t), "direction": gi["direction"].iloc[0],
                             "entropy": gi["entropy"].mean(), "rel_error": gi["rel_error"].mean(),
                             "scaled_error": float(np.mean(np.abs(gi["f_c"].to_numpy() - fa) / f_scale)),
                             "ess_share": gi["ess_share"].iloc[0], "n_resamples": int(gi["n_resamples"].iloc[0])})
        _print(f"participant {p_i + 1}/{cc['n_participants']} done ({time.time() - t_start:.0f} s)")
    df = pd.DataFrame(rows)
    if df.empty:
        raise RuntimeError(f"criteria comparison ({model_name}): no simulated participant could produce every "
                           "direction")
    note = [f"Chapter 6 beyond the thesis: test-selection criteria over {df['participant'].nunique()} simulated "
            f"participants ({model_name}, N {n_cand}, noise_rel {settings.noise_rel}); yardstick = joint posterior "
            f"after t tests (forces only); seed {config['seed']}",
            "entropy = mean marginal entropy over muscles (nats); rel_error = mean |E - f_a| / f_a; scaled_error = "
            "mean |E - f_a| / (scale f'_base) (not dominated by muscles whose f_a is near 0)"]
    atomic_write_csv(df, out_table, note, float_format="%.6g")
    # per participant: random = mean over its random orders; then mean and standard error over participants
    cols = ["entropy", "rel_error", "scaled_error"]
    per = df.groupby(["participant", "criterion", "t"], as_index=False)[cols].mean()
    rand = per[per["criterion"] == "random"].set_index(["participant", "t"])
    per = per.join(rand[cols], on=["participant", "t"], rsuffix="_random")
    for c in cols:
        per[f"d_{c}_vs_random"] = per[c] - per[f"{c}_random"]
    agg = per.groupby(["criterion", "t"], sort=False).agg(
        n=("entropy", "size"), entropy=("entropy", "mean"), rel_error=("rel_error", "mean"),
        d_entropy_vs_random=("d_entropy_vs_random", "mean"), d_entropy_se=("d_entropy_vs_random", "sem"),
        d_rel_error_vs_random=("d_rel_error_vs_random", "mean"), d_rel_error_se=("d_rel_error_vs_random", "sem"),
        scaled_error=("scaled_error", "mean"), d_scaled_error_vs_random=("d_scaled_error_vs_random", "mean"),
        d_scaled_error_se=("d_scaled_error_vs_random", "sem"),
    ).reset_index()
    atomic_write_csv(agg, out_summary, note + ["d_*_vs_random: criterion minus the mean of the random orders of the "
                                               "same participant (negative = better), mean and standard error over "
                                               "participants"], float_format="%.5g")
    fig_criteria_curves(agg, "mean marginal entropy (nats)",
                        f"Test-selection criteria on the joint posterior, mean over {df['participant'].nunique()} "
                        f"simulated participants ({model_name})", out_fig, dpi=120)
    return agg
