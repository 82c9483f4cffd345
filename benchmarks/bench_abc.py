"""Benchmark: the thesis's s3m24 run of Algorithm 4 (3^12 candidates x 25 directions per iteration).

Runs ``--iterations`` iterations on one data set (default S003, no EMG bounds, as in the default config) and
prints seconds per iteration and the extrapolation to 20 iterations (the thesis's maxIter for s3m24).
Usage: .venv/bin/python benchmarks/bench_abc.py [--dataset S003] [--iterations 3] [--threads 2]
"""

import argparse
import resource
import time

from neckstrength.abc.algorithm4 import ABCSettings, estimate_strengths
from neckstrength.config import build_directions, dataset_from_config, full_model_from_config, load_config, model_from_config
from neckstrength.estimation.scaling import bootstrap_prior


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", default="S003")
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--config", default="config/config.yaml")
    a = ap.parse_args()
    cfg = load_config(a.config)
    full = full_model_from_config(cfg)
    model = model_from_config(full, cfg, "s3m24")
    d = build_directions(cfg)
    c = cfg["chapter5"]
    data = dataset_from_config(cfg, "chapter5", model, d, a.dataset)
    f0, scale = bootstrap_prior(model, data, "back")
    times = []
    t_last = [time.time()]

    def progress(msg):
        now = time.time()
        times.append(now - t_last[0])
        t_last[0] = now
        print(msg, flush=True)

    t0 = time.time()
    estimate_strengths(model, data, ABCSettings(sigma0=0.2, max_iter=a.iterations, tie_sides=True), f0, scale,
                       progress=progress, n_threads=a.threads)
    total = time.time() - t0
    per_it = total / a.iterations
    print(f"s3m24/{a.dataset}: {a.iterations} iterations in {total:.1f} s ({per_it:.1f} s per iteration, "
          f"{531441 * 25 / per_it / 1e6:.2f} M LPs/s incl. activations of the accepted 10%); "
          f"extrapolated 20 iterations: {20 * per_it:.0f} s; threads {a.threads}; "
          f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
