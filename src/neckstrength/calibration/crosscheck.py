"""Cross-check of our ABC-SMC against an established implementation: pyABC's ABC-SMC (optional extra ``crosscheck``).

Both samplers get the same simulator (:func:`neckstrength.wrench.solve`), the same distance ``1 - D(f)`` (Eq. 5.5/5.6,
:func:`neckstrength.abc.smc._distance`), the same prior (independent normal priors on ``log f`` around ``f_0`` with
sd ``prior_sigma``), the same population size, the same adaptive tolerance rule (median of the previous
generation's distances) and the same total number of simulations. They differ in everything else (pyABC: its own
perturbation kernel, weights, acceptance loop, storage), which is the point of the comparison.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.abc.smc import SMCSettings, _distance, abc_smc
from neckstrength.calibration.sbc import weighted_quantiles
from neckstrength.estimation.datasets import Dataset
from neckstrength.model.reduction import ReducedModel
from neckstrength.seeds import generator, seed_numpy_global


def pyabc_available() -> bool:
    try:
        import pyabc  # noqa: F401
    except ImportError:
        return False
    return True


def run_pyabc(model: ReducedModel, data: Dataset, f0: np.ndarray, settings: SMCSettings,
              stream: np.random.SeedSequence,
              db_dir: str | Path | None = None) -> dict:
    """pyABC ABC-SMC on ``data``; returns particles (strengths), weights, simulations used, generations, seconds."""
    import logging

    import pyabc

    from neckstrength.wrench.batched import BasisCache

    for name in ("ABC", "Epsilon", "Distance", "Sampler", "History", "Acceptor", "Transition"):
        logging.getLogger(name).setLevel(logging.WARNING)
    m = len(f0)
    mu = np.log(np.asarray(f0, float))
    keys = [f"x{j:02d}" for j in range(m)]
    prior = pyabc.Distribution(**{k: pyabc.RV("norm", mu[j], settings.prior_sigma) for j, k in enumerate(keys)})
    cache = BasisCache()

    def simulate(par):
        x = np.array([par[k] for k in keys])
        return {"d": float(_distance(model, np.exp(x)[None, :], data, settings.epsilon, cache)[0])}

    def distance(x, x0):  # the simulation already holds the distance to the observed data
        return x["d"]

    seed_numpy_global(stream)  # pyABC draws from numpy's global state
    abc = pyabc.ABCSMC(simulate, prior, distance, population_size=settings.n_particles,
                       sampler=pyabc.sampler.SingleCoreSampler(),
                       eps=pyabc.epsilon.QuantileEpsilon(alpha=settings.quantile))
    with tempfile.TemporaryDirectory(dir=db_dir) as tmp:
        abc.new("sqlite:///" + str(Path(tmp) / "pyabc.db"), {"d": 0.0})
        t0 = time.time()
        h = abc.run(minimum_epsilon=0.0, max_total_nr_simulations=settings.budget)
        sec = time.time() - t0
        df, w = h.get_distribution(m=0, t=h.max_t)
        pops = h.get_all_populations()
        n_sim = int(h.total_nr_simulations)
        eps = float(pops["epsilon"].iloc[-1])
        n_gen = int(h.max_t) + 1
    X = np.exp(df[keys].to_numpy(float))
    return {"particles": X, "weights": np.asarray(w, float), "n_sim": n_sim, "generations": n_gen,
            "tolerance": eps, "seconds": sec}


def run_ours(model: ReducedModel, data: Dataset, f0: np.ndarray, settings: SMCSettings,
             stream: np.random.SeedSequence) -> dict:
    t0 = time.time()
    res = abc_smc(model, data, f0, settings, generator(stream))
    sec = time.time() - t0
    g = res.generations
    return {"particles": res.particles, "weights": res.weights, "n_sim": int(res.n_simulations),
            "generations": int(len(g)), "tolerance": float(g["tolerance"].iloc[-1]), "seconds": sec}


def compare(model: ReducedModel, data: Dataset, f0: np.ndarray, settings: SMCSettings,
            stream: np.random.SeedSequence) -> pd.DataFrame:
    """Both samplers on the stream ``stream`` (:func:`neckstrength.seeds.seed_sequence`). One row per sampler and muscle: posterior mean, 5-95% interval and width, truth, simulations used."""
    rows = []
    for sampler, fn in (("neckstrength abc_smc", run_ours), ("pyABC ABCSMC", run_pyabc)):
        r = fn(model, data, f0, settings, stream)
        mean = np.average(r["particles"], axis=0, weights=r["weights"])
        q = weighted_quantiles(r["particles"], r["weights"], (0.05, 0.95))
        for j, name in enumerate(model.muscle_names):
            rows.append({"sampler": sampler, "model": model.name, "dataset": data.name, "muscle": name,
                         "truth": np.nan if data.f_true is None else float(data.f_true[j]), "f0": float(f0[j]),
                         "mean": mean[j], "q05": q[0, j], "q95": q[1, j], "width90": q[1, j] - q[0, j],
                         "n_sim": r["n_sim"], "generations": r["generations"], "final_tolerance": r["tolerance"],
                         "seconds": r["seconds"]})
    return pd.DataFrame(rows)


def comparison_table(df: pd.DataFrame) -> pd.DataFrame:
    """Wide table per muscle: both samplers' mean and 90% width, their relative differences."""
    a = df[df["sampler"] == "neckstrength abc_smc"].set_index("muscle")
    b = df[df["sampler"] == "pyABC ABCSMC"].set_index("muscle")
    out = pd.DataFrame({"truth": a["truth"], "f0": a["f0"], "ours_mean": a["mean"], "pyabc_mean": b["mean"],
                        "ours_width90": a["width90"], "pyabc_width90": b["width90"]})
    out["mean_diff_rel"] = (out["ours_mean"] - out["pyabc_mean"]) / out["pyabc_mean"]
    out["width_ratio"] = out["ours_width90"] / out["pyabc_width90"]
    return out.reset_index()
