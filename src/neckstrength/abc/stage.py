"""Chapter 5's stages as functions that return results, and their writers
=======================================================================

- :func:`run_alg4` -> :class:`Alg4Run`: Algorithm 4 on one data set from the Eq. 5.3 bootstrap prior (the estimate
  table, the :class:`~neckstrength.abc.algorithm4.ABCResult`, ``f_0`` and ``a``); :func:`write_alg4` writes its
  tables and summary.
- :func:`alg4_figures`: Figs. 5.4-5.9 of one run (traces, D_k, d_ik, parallel coordinates, fit radar) from its
  tables (in memory, or read back from the files :func:`write_alg4` wrote).
- :func:`run_smc_comparison` -> :class:`SMCComparison`: ABC-SMC with every muscle free beside Algorithm 4 at equal
  simulation budget (beyond the thesis); :func:`write_smc_comparison`.

The pipeline (rules ``chapter5_estimate``, ``chapter5_figures``, ``chapter5_smc``) and ``neckstrength estimate`` call
these, so both give one answer per question.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
import pandas as pd

from neckstrength.abc.algorithm4 import ABCResult, ABCSettings, estimate_strengths
from neckstrength.abc.smc import SMCResult, SMCSettings, abc_smc
from neckstrength.estimation.datasets import Dataset, thesis_f_actual
from neckstrength.estimation.parameters import free_parameters
from neckstrength.estimation.scaling import bootstrap_prior
from neckstrength.io import atomic_write_csv, atomic_write_text
from neckstrength.model.reduction import ReducedModel

#: groups holding the deep cervical extensors in each named model (s3m24, p3m12, p2m7)
DEEP_EXTENSOR_GROUPS = ("mf", "multif", "TC-E")

#: the tables of one Algorithm 4 run (files of rule chapter5_estimate, besides its summary)
ALG4_TABLES = ("estimate", "history", "scores", "dk_hist", "d_by_direction", "fit", "candidates")


def _print(s: str) -> None:
    print(s, flush=True)


@dataclass
class Alg4Run:
    """One Algorithm 4 run: ``estimate`` (one row per muscle: parameter, f_base, f_0, f_c, sigma_c, f_actual)."""

    model_name: str
    dataset: str
    result: ABCResult
    estimate: pd.DataFrame
    f0: np.ndarray
    a: float
    seed: int

    def header(self) -> list[str]:
        res = self.result
        return [f"Chapter 5 ABC estimate (Algorithm 4): model {self.model_name}, data set {self.dataset}",
                f"iterations {res.iterations}, converged {res.converged}, D(f_c) = {res.D_fc:.4f}, "
                f"scale a = {self.a:.4f}",
                f"settings {json.dumps(res.settings)}; seed {self.seed} (only subsamples stored candidates)",
                "sigma_c is a HEURISTIC sampling width (Eq. 5.12), not a posterior sd: f_c (1 +- sigma_c) covers the "
                "truth far less often than a 68% interval would (docs/calibration.md)"]

    def summary(self) -> dict:
        res = self.result
        return {"model": self.model_name, "dataset": self.dataset, "iterations": res.iterations,
                "converged": res.converged, "D_fc": res.D_fc, "scale_a": self.a, "settings": res.settings,
                "seed": self.seed}

    def tables(self) -> dict[str, pd.DataFrame]:
        """Every table of :data:`ALG4_TABLES` by name."""
        res = self.result
        return {"estimate": self.estimate, "history": res.history, "scores": res.scores, "dk_hist": res.dk_hist,
                "d_by_direction": res.d_final, "fit": res.fit, "candidates": res.candidates}


def run_alg4(model: ReducedModel, data: Dataset, settings: ABCSettings, bootstrap_direction: str,
             rng: np.random.Generator, seed: int, checkpoint: str | Path | None = None,
             progress: Callable[[str], None] = _print, n_threads: int = 1) -> Alg4Run:
    """Algorithm 4 on ``data`` from ``f_0 = a f'_base`` (Eq. 5.3, scaled in ``bootstrap_direction``).

    ``rng`` only subsamples the stored candidates; ``seed`` is recorded with the result. ``checkpoint``: see
    :func:`~neckstrength.abc.algorithm4.estimate_strengths`.
    """
    f0, a = bootstrap_prior(model, data, bootstrap_direction)
    progress(f"model {model.name}, data set {data.name}: {model.m} muscles, {len(data.directions)} directions; "
             f"Eq. 5.3 scale a = {a:.4f} in '{bootstrap_direction}'; settings {settings}")
    res = estimate_strengths(model, data, settings, f0, a, rng=rng, checkpoint=checkpoint, progress=progress,
                             n_threads=n_threads)
    pidx = {p: i for i, p in enumerate(res.param_names)}
    rows = []
    for j, mname in enumerate(model.muscle_names):
        p = mname[:-2] if (settings.tie_sides and mname.endswith(("-R", "-L"))) else mname
        k = pidx[p]
        rows.append({"muscle": mname, "parameter": p, "f_base": model.strengths[j], "f_0": f0[j],
                     "f_c": res.f_c[k], "sigma_c": res.sigma_c[k],
                     "f_actual": np.nan if data.f_true is None else data.f_true[j]})
    return Alg4Run(model.name, data.name, res, pd.DataFrame(rows), f0, a, seed)


def write_alg4(run: Alg4Run, outputs: Mapping[str, str | Path]) -> None:
    """The tables of :data:`ALG4_TABLES` (CSV, each under its name in ``outputs``) and ``outputs['summary']`` (JSON)."""
    hdr = run.header()
    atomic_write_csv(run.estimate, outputs["estimate"], hdr, float_format="%.6g")
    for name, df in run.tables().items():
        if name != "estimate":
            atomic_write_csv(df, outputs[name], hdr[:2], float_format="%.6g")
    atomic_write_text(json.dumps(run.summary(), indent=2, default=float), outputs["summary"])


def alg4_figures(tables: Mapping[str, pd.DataFrame], directions: pd.DataFrame, model_name: str, dataset: str,
                 outputs: Mapping[str, str | Path], summary: Mapping | None = None) -> None:
    """Figs. 5.4-5.9 of one run from its tables (:meth:`Alg4Run.tables`, or the files :func:`write_alg4` wrote);
    ``outputs``: traces, dk_hist, d_dir, parallel, radar."""
    from neckstrength.abc.plots import abc_traces, d_by_direction_plot, dk_histograms, parallel_coordinates
    from neckstrength.plotting import radar_grid_series

    est, fit = tables["estimate"], tables["fit"]
    truth = est.groupby("parameter")["f_actual"].first()
    base = est.groupby("parameter")["f_base"].first()
    tag = f"{model_name}, {dataset}"
    run = dict(summary or {})      # :meth:`Alg4Run.summary`: the traces' title says whether the run converged
    abc_traces(tables["history"], truth, base, outputs["traces"], f"Estimate per iteration of Algorithm 4 ({tag})",
               converged=run.get("converged"), iterations=run.get("iterations"), D_fc=run.get("D_fc"),
               eps_D=(run.get("settings") or {}).get("eps_D"))
    dk_histograms(tables["dk_hist"], outputs["dk_hist"], f"Composite scores D_k per iteration ({tag})")
    d_by_direction_plot(tables["d_by_direction"], outputs["d_dir"], f"Scores d_ik by direction, last iteration ({tag})")
    parallel_coordinates(tables["candidates"], truth, outputs["parallel"],
                         f"Candidates coloured by D_k percentile ({tag})")
    radar_grid_series(directions, [("measured", fit.set_index("direction")["measured_N"],
                                    {"color": "blue", "ls": "--"}),
                                   ("model at f_c", fit.set_index("direction")["simulated_N"],
                                    {"color": "black", "lw": 2})],
                      outputs["radar"], f"Fit of the final estimate ({tag}) (N)")


@dataclass
class SMCComparison:
    """ABC-SMC beside Algorithm 4: ``table`` (one row per muscle), ``result`` (the SMC run), ``header`` lines."""

    table: pd.DataFrame
    result: SMCResult
    header: list[str]


def run_smc_comparison(model: ReducedModel, data: Dataset, alg4: pd.DataFrame, alg4_iterations: int,
                       abc: ABCSettings, smc: SMCSettings, bootstrap_direction: str, thesis_dir: str | Path,
                       rng: np.random.Generator, seed: int, progress: Callable[[str], None] = _print) -> SMCComparison:
    """ABC-SMC with all muscles free vs Algorithm 4 at equal simulation budget.

    ``alg4``: Algorithm 4's estimate table (muscle, f_c, sigma_c); ``alg4_iterations``: its iterations, so its
    budget is iterations x 3^m'; ``smc.budget`` caps SMC's (config ``chapter5.smc.max_budget``). ``thesis_dir``: the
    healthy 'norm' f_a that "estimated weak" is judged against.
    """
    _, pnames = free_parameters(model, abc.tie_sides)
    alg4_budget = int(alg4_iterations) * 3 ** len(pnames)
    cap = smc.budget
    budget = int(min(alg4_budget, cap))
    f0, _ = bootstrap_prior(model, data, bootstrap_direction)
    progress(f"Algorithm 4 used {alg4_budget} candidate evaluations ({alg4_iterations} iterations x "
             f"3^{len(pnames)}); ABC-SMC budget {budget} (cap {cap})")
    res = abc_smc(model, data, f0, replace(smc, budget=budget), rng, progress=progress)
    est = alg4.set_index("muscle")
    q = res.quantiles((0.05, 0.5, 0.95))
    mean = res.mean()
    rows = []
    for j, mname in enumerate(model.muscle_names):
        truth = data.f_true[j] if data.f_true is not None else np.nan
        a4 = float(est.loc[mname, "f_c"])
        rows.append({"muscle": mname, "truth": truth, "alg4_f_c": a4, "alg4_sigma_c": float(est.loc[mname, "sigma_c"]),
                     "smc_mean": mean[j], "smc_q05": q[0, j], "smc_median": q[1, j], "smc_q95": q[2, j],
                     "alg4_rel_error": (a4 - truth) / truth, "smc_rel_error": (mean[j] - truth) / truth,
                     "smc_covers_truth": bool(q[0, j] <= truth <= q[2, j]) if np.isfinite(truth) else None})
    df = pd.DataFrame(rows)
    deep = [i for i, n in enumerate(model.muscle_names)
            if n in DEEP_EXTENSOR_GROUPS or n.rsplit("-", 1)[0] in DEEP_EXTENSOR_GROUPS]
    ref = thesis_f_actual(model, thesis_dir, "norm")
    hdr = [f"ABC-SMC (all {model.m} muscles free) vs Algorithm 4 ({'tied sides' if abc.tie_sides else 'free'}), "
           f"{model.name}/{data.name}; budget {res.n_simulations} vs {alg4_budget} candidate evaluations",
           "deep extensors estimated weak (< 50% of the healthy 'norm' f_a): "
           + "; ".join(f"{model.muscle_names[i]}: alg4 {bool(est.loc[model.muscle_names[i], 'f_c'] < 0.5 * ref[i])}, "
                       f"smc {bool(mean[i] < 0.5 * ref[i])}" for i in deep),
           f"mean |relative error| alg4 {np.nanmean(np.abs(df['alg4_rel_error'])):.3f}, "
           f"smc {np.nanmean(np.abs(df['smc_rel_error'])):.3f}; seed {seed}"]
    for h in hdr:
        progress(h)
    return SMCComparison(df, res, hdr)


def write_smc_comparison(cmp: SMCComparison, out_csv: str | Path, out_generations: str | Path) -> None:
    atomic_write_csv(cmp.table, out_csv, cmp.header, float_format="%.5g")
    atomic_write_csv(cmp.result.generations, out_generations, cmp.header[:1], float_format="%.5g")
