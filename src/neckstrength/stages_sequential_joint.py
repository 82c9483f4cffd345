"""Pipeline stages of the joint sequential estimator (beyond the thesis; :mod:`neckstrength.sequential_joint`).

- :func:`stage_joint_run`: one data set, every configured criterion, the joint posterior with importance
  resampling (s3m24 x 25 directions: the thesis's stated future work).
- :func:`stage_criteria_comparison`: the thesis's criterion (Algorithms 7-9 on the marginal scheme), Eq. 6.7 on
  the joint posterior, joint expected information gain and random orders, averaged over simulated participants
  and judged by one yardstick (the joint posterior after t tests).
"""

from __future__ import annotations

import json
import time
import zlib
from dataclasses import fields
from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from .datasets import simulated_dataset
from .sequential import SequentialState, SimulatedSet, StrengthGrid, run_sequence, sample_prior, scaled_baseline
from .sequential_joint import JointPosterior, JointSettings, run_joint
from .stages import atomic_write_csv, full_model_from_config, load_directions, model_from_config
from .stages_sequential import _measure_fn, chapter6_dataset, chapter6_settings

__all__ = ["joint_settings", "stage_joint_run", "stage_criteria_comparison"]


def joint_settings(config: Mapping, **over) -> JointSettings:
    """``chapter6.joint`` (keys of :class:`JointSettings`; others ignored), with the Chapter 6 grid."""
    c = config["chapter6"]
    j = dict(c.get("joint", {}))
    names = {f.name for f in fields(JointSettings)}
    kw = {k: v for k, v in j.items() if k in names}
    kw.setdefault("prior_sd_rel", float(c.get("prior_sd_rel", 0.3)))
    kw.setdefault("n_bins", int(c.get("n_bins", 50)))
    kw.setdefault("bin_range_sd", float(c.get("bin_range_sd", 4.0)))
    kw.setdefault("emg_band", float(c.get("emg_band", 0.05)))
    kw.update(over)
    return JointSettings(**kw)


def _seed(config: Mapping, key: str) -> np.random.SeedSequence:
    return np.random.SeedSequence([int(config["seed"]), zlib.crc32(key.encode())])


def _print(s: str) -> None:
    print(s, flush=True)


# --------------------------------------------------------------------------- one data set

def stage_joint_run(config: Mapping, model_name: str, dataset: str, directions_csv, out_iterations, out_estimate,
                    out_summary) -> pd.DataFrame:
    """The joint sequential estimator on one data set with every criterion of ``chapter6.joint.criteria``.

    Outputs: iterations (criterion, iteration, direction, muscle, E, Var, entropy, ESS share, resamples),
    the final estimate per criterion beside the truth (simulated data sets) and a summary with seeds and timing.
    """
    from .batched import BasisCache

    t_start = time.time()
    c = config["chapter6"]
    jc = c.get("joint", {})
    model = model_from_config(full_model_from_config(config), config, model_name)
    d = load_directions(directions_csv)
    data = chapter6_dataset(model, d, dataset, config)
    settings = joint_settings(config)
    use_emg = bool(jc.get("use_emg", False))
    f0, a, _ = scaled_baseline(model, data)
    key = f"chapter6/joint/{model_name}/{dataset}"
    ss_cand, ss_prop = _seed(config, key).spawn(2)
    measure = _measure_fn(data)
    if not use_emg:
        measure = (lambda m: (lambda dn: (m(dn)[0], None)))(measure)
    _print(f"joint sequential estimator, {model_name} / {dataset}: {model.m} muscles, {len(data.directions)} "
           f"directions, f_0 = {a:.4f} f'_base; {settings}; EMG bounds {'used' if use_emg else 'not used'}")
    cache = BasisCache()
    parts, finals, info = [], [], {}
    for crit in jc.get("criteria", ["joint_eig", "marginal_entropy"]):
        t0 = time.time()
        post = JointPosterior(model, data.directions, data.U, data.force_scale, f0, settings,
                              np.random.default_rng(ss_cand), progress=_print, cache=cache)
        it = run_joint(post, measure, crit, np.random.default_rng(ss_prop), f_true=data.f_true, progress=_print)
        it.insert(0, "criterion", crit)
        parts.append(it)
        est = post.estimate()
        est.insert(0, "criterion", crit)
        est["f_true"] = data.f_true if data.f_true is not None else np.nan
        est["rel_diff_true"] = (est["f_c"] - est["f_true"]) / est["f_true"]
        finals.append(est)
        info[crit] = {"order": post.tested, "seconds": round(time.time() - t0, 2), "resamples": post.n_resamples,
                      "final_ess_share": post.ess_share(), "lps_solved": int(post.n_lps)}
        _print(f"[{crit}] order {post.tested}; {post.n_resamples} resamples, {post.n_lps} LPs, "
               f"{time.time() - t0:.1f} s")
    it = pd.concat(parts, ignore_index=True)
    atomic_write_csv(it, out_iterations, [f"joint sequential estimator (beyond the thesis), {model_name} / {dataset}",
                                          "iteration 0 = prior; entropy = marginal differential entropy (nats) on "
                                          "the Chapter 6 grid; ess_share = ESS / N of the weighted candidates"],
                     float_format="%.6g")
    est = pd.concat(finals, ignore_index=True)
    atomic_write_csv(est, out_estimate, [f"joint sequential estimator: final estimate after all tests, {model_name} "
                                         f"/ {dataset}; f_true = f_a of a simulated data set (NaN for participants)"],
                     float_format="%.6g")
    summary = {"model": model_name, "dataset": dataset, "seed": int(config["seed"]), "seed_key": key,
               "settings": {f.name: getattr(settings, f.name) for f in fields(settings)}, "use_emg": use_emg,
               "a": a, "criteria": info, "seconds": round(time.time() - t_start, 2)}
    tmp = Path(str(out_summary) + ".tmp")
    tmp.write_text(json.dumps(summary, indent=2))
    tmp.replace(out_summary)
    return it


# --------------------------------------------------------------------------- criteria over simulated participants

def stage_criteria_comparison(config: Mapping, model_name: str, directions_csv, out_table, out_summary,
                              out_fig) -> pd.DataFrame:
    """Criteria compared over simulated participants, all judged on the joint posterior after t tests.

    Participants ``f_a = scale f'_base (1 + noise_sd_rel z)`` (Sec. 6.5.1's recipe), forces only (no EMG bounds:
    the same information for every criterion). Per participant the same initial candidates serve every
    criterion; the thesis's criterion ('thesis (Alg. 7-9)') picks its order on the marginal scheme
    (:mod:`neckstrength.sequential`, its own N_F candidates) and that order is replayed on the joint posterior.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .batched import BasisCache

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
        rng = np.random.default_rng(s_truth)
        f_scale = cc.get("scale", 1.5) * model.strengths          # the recipe's centre: error scale per muscle
        fa = sample_prior(f_scale, cc.get("noise_sd_rel", 0.4), 1, rng)[0]
        try:
            data = simulated_dataset(model, d, f"P{p_i + 1}", fa)
        except ValueError as e:             # f_a that cannot produce every direction: redraw is not seeded here
            _print(f"participant {p_i + 1}: skipped ({e})")
            continue
        f0, _, _ = scaled_baseline(model, data)
        measure = _measure_fn(data)
        runs = [(crit, crit, None) for crit in criteria]
        prop_rngs = {crit: np.random.default_rng(s_prop) for crit in criteria}
        for r in range(n_random):
            runs.append(("random", f"random #{r + 1}", None))
        if thesis:
            F = sample_prior(f0, th_settings.prior_sd_rel, th_settings.n_candidates, np.random.default_rng(s_thesis))
            grid = StrengthGrid.around(f0, th_settings.prior_sd_rel, th_settings.n_bins, th_settings.bin_range_sd)
            sim, = SimulatedSet.build(model, data.directions, data.U, F, [grid], th_settings.n_wbins, cache=cache)
            state = SequentialState(model, sim, data.force_scale, th_settings)
            run_sequence(state, measure, np.random.default_rng(s_thesis), n_max=n_max)
            runs.append(("thesis (Alg. 7-9)", "thesis (Alg. 7-9)", state.tested))
        rnd = np.random.default_rng(s_prop.spawn(1)[0])
        for crit, label, order in runs:
            post = JointPosterior(model, data.directions, data.U, data.force_scale, f0, settings,
                                  np.random.default_rng(s_cand), cache=cache)
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
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for crit, g in agg.groupby("criterion", sort=False):
        axes[0].plot(g["t"], g["entropy"], "-o", ms=3, label=crit)
        axes[1].plot(g["t"], 100 * g["rel_error"], "-o", ms=3, label=crit)
    axes[0].set_ylabel("mean marginal entropy (nats)")
    axes[1].set_ylabel("mean |E - f_a| / f_a (%)")
    for ax in axes:
        ax.set_xlabel("number of measurements")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"Test-selection criteria on the joint posterior, mean over {df['participant'].nunique()} simulated "
                 f"participants ({model_name})", fontsize=10)
    fig.tight_layout()
    Path(out_fig).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_fig, dpi=120)
    plt.close(fig)
    return agg
