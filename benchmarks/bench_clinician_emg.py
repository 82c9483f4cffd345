#!/usr/bin/env python
"""Check: why surface EMG bounds drive P(deep-extensor deficit) towards 0 in the clinician study (docs/clinician.md).

One simulated s3m24 participant with mf at 25-50% of baseline (stream 'emg_check/truth'), forces with 5% log-normal
noise, EMG bounds on the surface-recorded groups (``chapter6.emg_groups``: true activation +- 0.05, as strategy
``joint_eig+emg``), 25 tests chosen by the joint EIG on the joint posterior. Printed:

1. whether the bounded LPs are degenerate: the truth's bounded maximum against its unbounded one in every
   direction, and the status and wrench of 500 strength vectors within 5% (log-normal) of the truth;
2. whether the sampler misses the truth or the posterior prefers another explanation: the truth's log prior and
   kernel log-likelihood against the candidates' (best log posterior density, mean log-likelihood);
3. the muscles whose posterior mean is furthest from the truth.

Run from the repository root::

    python benchmarks/bench_clinician_emg.py --n 8000
"""

from __future__ import annotations

import argparse
import os

import numpy as np


def main(argv=None) -> int:
    from neckstrength.config import (
        build_directions,
        deficit_definition,
        derive_rng,
        full_model_from_config,
        joint_settings,
        load_config,
        model_from_config,
    )
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.sequential.deficit import draw_participant
    from neckstrength.sequential.joint import JointPosterior
    from neckstrength.wrench import solve
    from neckstrength.wrench.batched import BasisCache

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--n", type=int, default=8000, help="candidates of the joint posterior")
    ap.add_argument("--participant", type=int, default=0)
    ap.add_argument("--seed", type=int, default=None, help="default: config seed")
    a = ap.parse_args(argv)
    cfg = load_config(a.config)
    seed = int(cfg["seed"] if a.seed is None else a.seed)
    model = model_from_config(full_model_from_config(cfg), cfg, "s3m24")
    d, U = model_directions_table(model, build_directions(cfg))
    names, dirs, fs = list(model.muscle_names), list(d["name"]), d["force_scale"].to_numpy(float)
    definition = deficit_definition(cfg)
    f0 = model.strengths
    rt = derive_rng(seed, "emg_check/truth", a.participant)
    fa = draw_participant(f0, 0.3, definition.indices(names), 0.25, 0.5, rt)
    w, alpha, _ = solve(model, fa[None], U)
    forces = w[0] * np.exp(0.05 * rt.standard_normal(len(dirs))) / fs
    base = [n[:-2] if n.endswith(("-R", "-L")) else n for n in names]
    mask = np.array([b in set(cfg["chapter6"]["emg_groups"]["s3m24"]) for b in base])
    lb, ub = np.zeros((len(dirs), model.m)), np.ones((len(dirs), model.m))
    lb[:, mask] = np.clip(alpha[0][:, mask] - 0.05, 0, 1)
    ub[:, mask] = np.clip(alpha[0][:, mask] + 0.05, 0, 1)
    groups = ", ".join(sorted({b for b, k in zip(base, mask) if k}))
    print(f"seed {seed}, participant {a.participant}: true mf ratio "
          f"{definition.ratio(fa[None], f0, names)[0]:.2f}; EMG-bounded groups: {groups}")
    wb, _, stb = solve(model, fa[None], U, lb, ub)
    print(f"1. truth: bounded / unbounded maximum {np.min(wb[0] / w[0]):.4f}-{np.max(wb[0] / w[0]):.4f} over the "
          f"{len(dirs)} directions, statuses {sorted(set(stb[0].tolist()))} (0 = optimal)")
    near = fa[None] * np.exp(0.05 * np.random.default_rng(seed).standard_normal((500, model.m)))
    wn, _, sn = solve(model, near, U, lb, ub)
    print(f"   500 strength vectors within 5% of the truth: {np.mean(sn == 0):.4f} of their bounded LPs optimal; "
          f"wrench / truth's median {np.median(wn / wb):.3f} (5-95%: {np.quantile(wn / wb, 0.05):.3f}-"
          f"{np.quantile(wn / wb, 0.95):.3f})")
    post = JointPosterior(model, dirs, U, fs, f0, joint_settings(cfg, n_candidates=a.n),
                          derive_rng(seed, "emg_check/candidates", a.participant), cache=BasisCache(),
                          n_threads=os.cpu_count() or 1)
    prng = derive_rng(seed, "emg_check/propose", a.participant)
    for _ in range(len(dirs)):
        dd, _ = post.propose("joint_eig", prng)
        k = dirs.index(dd)
        post.update(dd, float(forces[k]), (lb[k], ub[k]))
    wts = post.weights()
    ll_truth = sum(float(post._test_loglik(wb[0, [x["i"]]], x["w_meas"])[0]) for x in post.tests)
    lp_truth = float(post.log_prior(fa[None])[0])
    lpost = post.log_prior(post.F) + post.loglik
    p_def = definition.probability(post.F, wts, f0, names)
    print(f"2. after {len(post.tests)} tests (N {a.n}): P(deficit) {p_def:.3f}; "
          f"truth: log prior {lp_truth:.1f}, kernel log-likelihood {ll_truth:.2f}, "
          f"log posterior {lp_truth + ll_truth:.1f}; "
          f"best candidate log posterior {lpost.max():.1f}; candidates' mean log prior "
          f"{float(wts @ post.log_prior(post.F)):.1f}, mean log-likelihood {float(wts @ post.loglik):.2f}")
    E = wts @ post.F
    print("3. muscle   truth   posterior mean   baseline   (EMG-bounded)")
    for j in np.argsort(-np.abs(E / fa - 1))[:8]:
        print(f"   {names[j]:<10} {fa[j]:7.1f} {E[j]:10.1f} {f0[j]:12.1f}   {'yes' if mask[j] else ''}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
