"""Chapter 6 analysis of one sequential run: Algorithm 7 with the entropy-reducing selection, the order
analysis, and the tables the thesis's figures read (posteriors per iteration, Fig. 6.4/6.5; expected entropy
reduction, Fig. 6.8; order entropies, Fig. 6.7; subsets; grid sensitivity).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.estimation.datasets import Dataset
from neckstrength.sequential.algorithms import (
    SequentialSettings,
    SequentialState,
    SimulatedSet,
    joint_ess,
    pdf_entropy,
    posterior_from_loglik,
    run_sequence,
)
from neckstrength.sequential.orders import order_entropies, subset_table
from neckstrength.seeds import generator


def measure_from(data: Dataset):
    """A ``measure(direction) -> (force, activation bounds or None)`` reading a data set (Algorithm 7's test)."""
    def measure(direction: str):
        i = data.directions.index(direction)
        b = None if data.alpha_lb is None else (data.alpha_lb[i], data.alpha_ub[i])
        return float(data.forces[i]), b
    return measure


def analyse(model, data: Dataset, sim: SimulatedSet, settings: SequentialSettings, seed_propose, gamma,
             n_orders: int, order_seed, progress=None, alpha_cache: dict | None = None) -> dict:
    """Algorithm 7 with the entropy-reducing selection, then the order analysis from the per-test factors."""
    state = SequentialState(model, sim, data.force_scale, settings, alpha_cache=alpha_cache)
    props, it = run_sequence(state, measure_from(data), generator(seed_propose), gamma, progress=progress)
    K = sim.K
    order_sel = np.array([sim.directions.index(s.direction) for s in state.steps])
    loglik = np.zeros((K, sim.m, sim.grid.n_bins))
    for s in state.steps:
        loglik[sim.directions.index(s.direction)] = s.loglik
    log_prior = state.log_prior
    subsets = None
    if K <= 12:
        subsets = subset_table(log_prior, loglik, sim.grid)
        orders, H = order_entropies(subsets["H"], K)
    else:  # sampled orders: entropies along each order's prefixes
        rng = generator(order_seed)
        orders = np.array([rng.permutation(K) for _ in range(n_orders)] + [order_sel])
        H = np.zeros((len(orders), K + 1))
        H[:, 0] = pdf_entropy(sim.prior_pdf, sim.grid).mean()
        for o_i, o in enumerate(orders):
            cum = np.cumsum(loglik[o], axis=0)
            H[o_i, 1:] = pdf_entropy(posterior_from_loglik(log_prior[None], cum), sim.grid).mean(axis=1)
    is_sel = np.all(orders == order_sel[None, :], axis=1)
    return {"state": state, "proposals": props, "iterations": it, "order": order_sel, "loglik": loglik,
            "subsets": subsets, "orders": orders, "H_orders": H, "is_selected": is_sel}


def posterior_table(state: SequentialState, sim: SimulatedSet, names: Sequence[str]) -> tuple[pd.DataFrame, list]:
    """Posterior density per N of every muscle after every iteration, and the joint ESS share per iteration."""
    rows = []
    cum = np.zeros_like(state.log_prior)
    pdfs = [posterior_from_loglik(state.log_prior, cum)]
    for s in state.steps:
        cum = cum + s.loglik
        pdfs.append(posterior_from_loglik(state.log_prior, cum))
    c_ = sim.grid.centres
    h = sim.grid.widths
    ess = [joint_ess(sim, p) for p in pdfs]
    for t, p in enumerate(pdfs):
        for j, n in enumerate(names):
            rows.append(pd.DataFrame({"iteration": t, "direction": "" if t == 0 else state.steps[t - 1].direction,
                                      "muscle": n, "f": c_[j], "density": p[j] / h[j]}))
    return pd.concat(rows, ignore_index=True), ess


def expected_gain_table(proposals, names: Sequence[str], dindex: dict) -> pd.DataFrame:
    """Eq. 6.6 expected entropy reduction per iteration, direction and muscle, with the Eq. 6.7/6.8 score."""
    rows = []
    for t, p in enumerate(proposals, start=1):
        tab = p.table()
        for _, r in tab.iterrows():
            for n in names:
                rows.append({"iteration": t, "direction": r["direction"], "direction_index": dindex[r["direction"]],
                             "muscle": n, "dS": r[n], "score": r["score"], "selected": bool(r["selected"])})
    return pd.DataFrame(rows)


def order_summary_table(H: np.ndarray, is_sel: np.ndarray) -> pd.DataFrame:
    """The selected order's entropy per iteration beside the distribution over the other orders."""
    K = H.shape[1] - 1
    sel_H = H[is_sel][0]
    others = H[~is_sel]
    summ = []
    for t in range(K + 1):
        o = others[:, t]
        summ.append({"iteration": t, "selected": sel_H[t], "min": o.min(), "q25": np.percentile(o, 25),
                     "median": np.median(o), "q75": np.percentile(o, 75), "max": o.max(),
                     "share_of_orders_lower": float((o < sel_H[t] - 1e-12).mean())})
    return pd.DataFrame(summ)


def subset_rows(sub: dict | None, directions: Sequence[str], names: Sequence[str]) -> pd.DataFrame:
    """Posterior mean, variance and entropy after every subset of tested directions (bit i = direction i + 1)."""
    K = len(directions)
    exact = sub is not None
    if exact:
        rows = []
        for s_ in range(1 << K):
            tested = [directions[i] for i in range(K) if s_ >> i & 1]
            for j, n in enumerate(names):
                rows.append({"subset": s_, "n_tested": len(tested), "tested": ";".join(tested), "muscle": n,
                             "f_c": sub["E"][s_, j], "v_c": sub["V"][s_, j], "entropy": sub["H"][s_, j]})
        subs = pd.DataFrame(rows)
    else:
        subs = pd.DataFrame(columns=["subset", "n_tested", "tested", "muscle", "f_c", "v_c", "entropy"])
    return subs


def bins_table(res: dict, names: Sequence[str], est: pd.DataFrame) -> pd.DataFrame:
    """Grid sensitivity: the estimate on other strength grids beside the main one."""
    rows = []
    for nb, r in res.items():
        e = r["state"].estimate()
        for j, n in enumerate(names):
            rows.append({"n_bins": nb, "muscle": n, "f_c": e["f_c"][j], "v_c": e["v_c"][j], "entropy": e["entropy"][j],
                         "order": "-".join(str(i + 1) for i in r["order"]),
                         "rel_diff_f_c_vs_main": e["f_c"][j] / est["f_c"][j] - 1.0,
                         "rel_diff_sd_c_vs_main": np.sqrt(e["v_c"][j] / est["v_c"][j]) - 1.0})
    bins = pd.DataFrame(rows)
    return bins
