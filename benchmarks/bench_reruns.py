"""Benchmark: the cost of one member of the run-to-run distributions (issue 36), per model x data set.

Times one Algorithm 4 run (Chapter 5) and one Table 6.1 posterior (Chapter 6) per model x data set on the full
config, to choose K (``reruns.<chapter>.members``) so that the ``reruns`` target fits its budget; prints the
CPU and wall seconds per member (CPU time is the guide on a shared machine), and, as the reference timed in the
same run, one p2m7 'norm' member of Algorithm 4 (every row's ratio is against it, so rows from loaded and quiet
machines compare).
Usage: .venv/bin/python benchmarks/bench_reruns.py [--models p2m7 p3m12 s3m24] [--chapter6] [--datasets ...]
       [--identical N]   (members 0 and 1 of Algorithm 4 for N iterations: bit-identical or not)
"""

import argparse
import time

import numpy as np

from neckstrength.config import (abc_settings, build_directions, chapter6_settings, dataset_from_config,
                                 full_model_from_config, load_config, model_from_config)
from neckstrength.pipeline.chapter6 import chapter6_dataset
from neckstrength.reruns.runs import algorithm4_member, member_stream, sequential_member


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--models", nargs="*", default=["p2m7", "p3m12", "s3m24"])
    ap.add_argument("--datasets", nargs="+", default=None, help="Chapter 5 data sets (default: chapter5.datasets)")
    ap.add_argument("--chapter6", action="store_true", help="also one Table 6.1 member per data set (p2m7)")
    ap.add_argument("--identical", type=int, metavar="N", default=0,
                    help="instead: run members 0 and 1 of Algorithm 4 for N iterations per model on each data set and "
                         "print whether they are bit-identical (it draws nothing at random)")
    a = ap.parse_args()
    cfg = load_config(a.config)
    full = full_model_from_config(cfg)
    d = build_directions(cfg)
    c = cfg["chapter5"]

    def alg4(model_name, ds):
        model = model_from_config(full, cfg, model_name)
        data = dataset_from_config(cfg, "chapter5", model, d, ds)
        stream, _ = member_stream(cfg["seed"], "chapter5", model_name, ds, 0)
        t0, c0 = time.time(), time.process_time()
        m = algorithm4_member(model, data, abc_settings(cfg, model_name), c["bootstrap_direction"],
                              np.random.default_rng(stream))
        return time.process_time() - c0, time.time() - t0, int(m.loc[m["quantity"] == "iters", "value"].iloc[0])

    if a.identical:
        import dataclasses

        print("model, dataset, iterations, members 0 and 1 identical, CPU seconds of the two")
        for model_name in a.models:
            model = model_from_config(full, cfg, model_name)
            st = dataclasses.replace(abc_settings(cfg, model_name), max_iter=a.identical)
            for ds in a.datasets or c["datasets"]:
                data = dataset_from_config(cfg, "chapter5", model, d, ds)
                c0 = time.process_time()
                out = [algorithm4_member(model, data, st, c["bootstrap_direction"],
                                         np.random.default_rng(member_stream(cfg["seed"], "chapter5", model_name, ds,
                                                                             k)[0])) for k in (0, 1)]
                same = out[0]["value"].tolist() == out[1]["value"].tolist()
                print(f"{model_name}, {ds}, {a.identical}, {same}, {time.process_time() - c0:.1f}", flush=True)
        return

    alg4("p2m7", "norm")  # warm-up (imports, first solves)
    ref, ref_wall, _ = alg4("p2m7", "norm")
    print(f"reference: Algorithm 4, p2m7/norm: {ref:.2f} s CPU ({ref_wall:.2f} s wall)")
    print("chapter, model, dataset, iterations, CPU seconds, wall seconds, CPU ratio to reference")
    for model_name in a.models:
        for ds in a.datasets or c["datasets"]:
            s, w, it = alg4(model_name, ds)
            print(f"chapter5, {model_name}, {ds}, {it}, {s:.1f}, {w:.1f}, {s / ref:.1f}", flush=True)
    if a.chapter6:
        model = model_from_config(full, cfg, "p2m7")
        st = chapter6_settings(cfg, "p2m7")
        for ds in cfg["chapter6"]["datasets"]:
            data = chapter6_dataset(model, d, ds, cfg)
            stream, _ = member_stream(cfg["seed"], "chapter6", "p2m7", ds, 0)
            t0, c0 = time.time(), time.process_time()
            sequential_member(model, data, st, stream)
            s, w = time.process_time() - c0, time.time() - t0
            print(f"chapter6, p2m7, {ds}, -, {s:.1f}, {w:.1f}, {s / ref:.1f}", flush=True)


if __name__ == "__main__":
    main()
