"""The joint sequential estimator on one data set, as a stage that returns its result
==================================================================================

:func:`run_joint_estimate` -> :class:`JointEstimate` (per criterion: the iterations, the final estimate beside the
truth of a simulated data set, the order and timing); :func:`write_joint_estimate` writes its three files. The
pipeline (rule ``chapter6_joint``) and ``neckstrength estimate --method joint`` call both.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from neckstrength.estimation.datasets import Dataset
from neckstrength.io import atomic_write_csv
from neckstrength.model.reduction import ReducedModel
from neckstrength.sequential.algorithms import scaled_baseline
from neckstrength.sequential.analysis import measure_from
from neckstrength.sequential.joint import JointPosterior, JointSettings, run_joint
from neckstrength.seeds import generator


def _print(s: str) -> None:
    print(s, flush=True)


@dataclass
class JointEstimate:
    """``iterations`` and ``estimate`` of every criterion (column ``criterion``); ``summary``: a JSON-ready dict
    (model, data set, seed and its stream key, settings, EMG use, ``a``, per-criterion order and timing)."""

    model_name: str
    dataset: str
    iterations: pd.DataFrame
    estimate: pd.DataFrame
    summary: dict


def run_joint_estimate(model: ReducedModel, data: Dataset, settings: JointSettings, criteria: Sequence[str],
                       use_emg: bool, seed: int, seed_key: str, seeds: np.random.SeedSequence,
                       progress: Callable[[str], None] = _print) -> JointEstimate:
    """The joint estimator with each of ``criteria`` in turn from the same prior candidates (``seeds`` spawns the
    candidates' and the proposals' streams; ``seed``/``seed_key`` are recorded). ``use_emg``: the data set's EMG
    activation bounds are used (else forces only)."""
    from neckstrength.wrench.batched import BasisCache

    t_start = time.time()
    f0, a, _ = scaled_baseline(model, data)
    ss_cand, ss_prop = seeds.spawn(2)
    measure = measure_from(data)
    if not use_emg:
        measure = (lambda m: (lambda dn: (m(dn)[0], None)))(measure)
    progress(f"joint sequential estimator, {model.name} / {data.name}: {model.m} muscles, {len(data.directions)} "
             f"directions, f_0 = {a:.4f} f'_base; {settings}; EMG bounds {'used' if use_emg else 'not used'}")
    cache = BasisCache()
    parts, finals, info = [], [], {}
    for crit in criteria:
        t0 = time.time()
        post = JointPosterior(model, data.directions, data.U, data.force_scale, f0, settings,
                              generator(ss_cand), progress=progress, cache=cache)
        it = run_joint(post, measure, crit, generator(ss_prop), f_true=data.f_true, progress=progress)
        it.insert(0, "criterion", crit)
        parts.append(it)
        est = post.estimate()
        est.insert(0, "criterion", crit)
        est["f_true"] = data.f_true if data.f_true is not None else np.nan
        est["rel_diff_true"] = (est["f_c"] - est["f_true"]) / est["f_true"]
        finals.append(est)
        info[crit] = {"order": post.tested, "seconds": round(time.time() - t0, 2), "resamples": post.n_resamples,
                      "final_ess_share": post.ess_share(), "lps_solved": int(post.n_lps)}
        progress(f"[{crit}] order {post.tested}; {post.n_resamples} resamples, {post.n_lps} LPs, "
                 f"{time.time() - t0:.1f} s")
    summary = {"model": model.name, "dataset": data.name, "seed": int(seed), "seed_key": seed_key,
               "settings": {f.name: getattr(settings, f.name) for f in fields(settings)}, "use_emg": use_emg,
               "a": a, "criteria": info, "seconds": round(time.time() - t_start, 2)}
    return JointEstimate(model.name, data.name, pd.concat(parts, ignore_index=True),
                         pd.concat(finals, ignore_index=True), summary)


def write_joint_estimate(res: JointEstimate, out_iterations: str | Path, out_estimate: str | Path,
                         out_summary: str | Path) -> None:
    tag = f"{res.model_name} / {res.dataset}"
    atomic_write_csv(res.iterations, out_iterations, [f"joint sequential estimator (beyond the thesis), {tag}",
                                                      "iteration 0 = prior; entropy = marginal differential entropy "
                                                      "(nats) on the Chapter 6 grid; ess_share = ESS / N of the "
                                                      "weighted candidates"],
                     float_format="%.6g")
    atomic_write_csv(res.estimate, out_estimate, [f"joint sequential estimator: final estimate after all tests, "
                                                  f"{tag}; f_true = f_a of a simulated data set (NaN for "
                                                  "participants)",
                                                  "sd_c: calibrated on simulated p2m7 data (docs/calibration.md); NOT "
                                                  "on s3m24 at the sizes checked, and not under model misfit "
                                                  "(participants): there it understates the uncertainty"],
                     float_format="%.6g")
    tmp = Path(str(out_summary) + ".tmp")
    tmp.write_text(json.dumps(res.summary, indent=2))
    tmp.replace(out_summary)
