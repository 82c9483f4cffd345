"""Cross-check: our ABC-SMC vs pyABC's ABC-SMC on the same simulator, distance, prior, population and budget.

Needs the optional extra ``crosscheck`` (pyabc). For each case (model/data set) it runs both samplers on the
simulated data set (the thesis f_a, exact forces), with the prior point estimate f_0 from the bootstrap scaling
(Eq. 5.3), and writes a per-muscle CSV and a markdown table (for docs/calibration.md) to ``--out``.
Usage: python benchmarks/bench_pyabc_crosscheck.py [--cases p2m7/weak s3m24/weak] [--particles 300 200]
       [--budget 5000 2000] [--out results/calibration/crosscheck]
"""

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

from neckstrength.abc.smc import SMCSettings
from neckstrength.calibration.crosscheck import compare, comparison_table
from neckstrength.config import (build_directions, dataset_from_config, full_model_from_config, load_config,
                                 model_from_config, seed_sequence)
from neckstrength.estimation.scaling import bootstrap_prior


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", nargs="+", default=["p2m7/weak", "s3m24/weak"])
    ap.add_argument("--particles", nargs="+", type=int, default=[300, 200])
    ap.add_argument("--budget", nargs="+", type=int, default=[5000, 2000])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--out", default="results/calibration/crosscheck")
    a = ap.parse_args()
    cfg = load_config(a.config)
    full = full_model_from_config(cfg)
    d = build_directions(cfg)
    c = cfg["chapter5"]
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    md = [f"machine: {platform.machine()}, {os.cpu_count()} cores, load average at start "
          f"{os.getloadavg()[0]:.1f} (shared machine); seed {cfg['seed']} (stream 'crosscheck/<case>')", ""]
    for case, n_part, budget in zip(a.cases, a.particles, a.budget):
        model_name, dataset = case.split("/")
        model = model_from_config(full, cfg, model_name)
        data = dataset_from_config(cfg, "chapter5", model, d, dataset)
        f0, _ = bootstrap_prior(model, data, c["bootstrap_direction"])
        settings = SMCSettings(n_particles=n_part, budget=budget, prior_sigma=c["smc"]["prior_sigma"],
                               quantile=c["smc"]["quantile"], epsilon=c["epsilon"])
        t0 = time.time()
        df = compare(model, data, f0, settings, seed_sequence(cfg["seed"], f"crosscheck/{case}"))
        tag = case.replace("/", "_")
        df.to_csv(out / f"{tag}_particles.csv", index=False)
        tab = comparison_table(df)
        tab.to_csv(out / f"{tag}_table.csv", index=False)
        runs = df.groupby("sampler", sort=False)[["n_sim", "generations", "final_tolerance", "seconds"]].first()
        md += [f"### {case}: {n_part} particles, budget {budget} simulations, prior log-normal(log f_0, "
               f"{settings.prior_sigma}), tolerance quantile {settings.quantile}, epsilon {settings.epsilon}; "
               f"load average {os.getloadavg()[0]:.1f} at end ({time.time() - t0:.0f} s)", "",
               "| sampler | simulations | generations | final tolerance (1 - D) | seconds |", "|---|---|---|---|---|"]
        md += [f"| {s} | {int(r.n_sim)} | {int(r.generations)} | {r.final_tolerance:.4f} | {r.seconds:.0f} |"
               for s, r in runs.iterrows()]
        md += ["", "| muscle | f_a | f_0 | mean ours | mean pyABC | 90% width ours | 90% width pyABC | "
               "mean diff (rel) | width ratio |", "|---|---|---|---|---|---|---|---|---|"]
        md += [f"| {r.muscle} | {r.truth:.0f} | {r.f0:.0f} | {r.ours_mean:.0f} | {r.pyabc_mean:.0f} | "
               f"{r.ours_width90:.0f} | {r.pyabc_width90:.0f} | {r.mean_diff_rel:+.2f} | {r.width_ratio:.2f} |"
               for r in tab.itertuples()]
        md += ["", f"median |mean diff| {np.median(np.abs(tab['mean_diff_rel'])):.3f}, median width ratio "
               f"{np.median(tab['width_ratio']):.2f}", ""]
        print("\n".join(md[-(len(tab) + 12):]), flush=True)
    (out / "crosscheck.md").write_text("\n".join(md) + "\n")


if __name__ == "__main__":
    main()
