#!/usr/bin/env python
"""What the user benchmark's truths do to the forces, against what the candidates can produce (issue 32, 2026-11-28).

Made with the truths' own code (:mod:`neckstrength.gap.truths`) and the individual's true strengths (no fit, no
diagnosis), for the three largest failures of the user-facing benchmark:

1. ``direction_error`` (a push direction per test, uniform in a cone): the per-test log change of the force
   against the target's, and what a mean-changing candidate predicts at the same cone: the largest force over
   the cone (the window hypothesis of ``direction_tolerance``, sampled) and the mean over the cone.
2. The aiming-scatter shape test (:func:`neckstrength.gap.scatter.scatter_test`) on those log changes plus
   measurement noise (noise only as the reference), with the individual's direction sensitivity.
3. ``posture_drift`` (per test along the demanded torque): the share of the force change that comes from the
   posture's moment arms and joint axes against its force-length strength factors, and the sagittal angle per
   test (a single-angle sagittal candidate drifts every test the same way).
4. ``rich96`` controls: the net left/right strength ratio the 96 independent elements make (the fit ties sides).

    .venv/bin/python benchmarks/bench_gap_truth_signatures.py --cases 6
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

import numpy as np


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--cases", type=int, default=6, help="cases per truth")
    ap.add_argument("--cone-samples", type=int, default=40, help="sampled directions per test for the cone's max/mean")
    ap.add_argument("--seed", type=int, default=20261128)
    a = ap.parse_args(argv)

    from neckstrength.config import gap_truth_setup, load_config
    from neckstrength.gap import truths as T
    from neckstrength.gap.scatter import ScatterSettings, direction_sensitivity, scatter_test
    from neckstrength.postures.model import posture_full_model, reduce_in_posture

    t0 = time.perf_counter()
    model, _, setup = gap_truth_setup(load_config(a.config))
    fc = T.TruthForces(setup)
    m, full = setup.model, setup.full
    rng = np.random.default_rng(a.seed)
    s = T.CaseSettings()
    ss = ScatterSettings(permutations=1999)
    print(f"{model}, seed {a.seed}, {a.cases} cases per truth, load {os.getloadavg()[0]:.1f}")

    def strengths():
        return m.strengths * np.exp(rng.normal(0.0, s.strength_spread, m.m))

    print("\n1-2. direction_error: log(F(aim) / F(target)) per test; the cone's max and mean; shape test p "
          "(with noise 0.03-0.06, 3 trials, largest kept) and on noise alone")
    out = {"direction": [], "drift": [], "asym": []}
    for _ in range(a.cases):
        f = strengths()
        p = T.draw_params(setup, "direction_error", s, rng, fc)
        base = fc.base(f)
        lr = np.log(T.make_forces(setup, "direction_error", f, p, fc) / base)
        cone = np.radians(p["cone_deg"])
        mx, mn = [], []
        for k, n in enumerate(fc.N):
            D = []
            for _ in range(a.cone_samples):
                ax = T._rot(T._perp(n), n, rng.uniform(0, 2 * np.pi))
                D.append(T._rot(n, ax, cone * np.sqrt(rng.random())))
            F = fc.along(m, f, np.repeat(fc.P[k:k + 1], len(D), 0), np.array(D))
            mx.append(F.max())
            mn.append(F.mean())
        mx, mn = np.log(np.array(mx) / base), np.log(np.array(mn) / base)
        nz = rng.uniform(*s.noise)
        noise = np.log(np.exp(rng.normal(0, nz, (len(lr), s.repeats))).max(axis=1))
        v = direction_sensitivity(m, f, fc.P, fc.N, ss)
        r_aim = lr + noise
        p_aim = scatter_test(r_aim - r_aim.mean(), v, rng, ss)["p"]
        p_noise = scatter_test(noise - noise.mean(), v, rng, ss)["p"]
        row = {"cone": p["cone_deg"], "mean": lr.mean(), "sd": lr.std(), "lower": np.mean(lr < 0),
               "max_mean": mx.mean(), "corr_max": np.corrcoef(lr, mx)[0, 1], "mean_sd": mn.std(),
               "corr_mean": np.corrcoef(lr, mn)[0, 1], "p_aim": p_aim, "p_noise": p_noise}
        out["direction"].append(row)
        print(f"  cone {row['cone']:4.1f} deg: mean {row['mean']:+.3f}, SD {row['sd']:.3f}, {row['lower']:.0%} lower | "
              f"cone max {row['max_mean']:+.3f} (corr {row['corr_max']:+.2f}) | cone mean SD {row['mean_sd']:.3f} "
              f"(corr {row['corr_mean']:+.2f}) | shape test p {p_aim:.4f}, noise alone {p_noise:.4f}")

    print("\n3. posture_drift along the demanded torque: SD of the per-test log change, total / strength factors only "
          "/ moment arms and axes only (correlation with the total), sagittal angle per test")
    axes = [c.rsplit("_", 1)[1] for c in m.coordinates]
    U = m.task_direction(np.hstack([np.cross(fc.P, fc.N), fc.N]))
    U = U / np.linalg.norm(U, axis=1, keepdims=True)
    for _ in range(a.cases):
        f = strengths()
        drift = float(rng.uniform(*s.drift_deg))
        base = fc.base(f)
        tot, fl, geo, sag = (np.zeros(len(U)) for _ in range(4))
        for k in range(len(U)):
            w = T.drift_weights(axes, m.JT @ U[k], drift)
            tab = T._interp_posture(setup.postures, w)
            mq = reduce_in_posture(posture_full_model(full, tab), m, tab, "drift")
            rho = np.where(m.strengths > 0, mq.strengths / np.where(m.strengths > 0, m.strengths, 1.0), 0.0)
            Pk, Nk = fc.P[k:k + 1], fc.N[k:k + 1]
            tot[k] = fc.along(mq, f * rho, Pk, Nk)[0]
            fl[k] = fc.along(m, f * rho, Pk, Nk)[0]
            geo[k] = fc.along(replace(mq, strengths=m.strengths), f, Pk, Nk)[0]
            sag[k] = 20.0 * (w.get("flex20", 0.0) - w.get("ext20", 0.0))
        lt, lf, lg = (np.log(x / base) for x in (tot, fl, geo))
        row = {"drift": drift, "sd": lt.std(), "sd_fl": lf.std(), "corr_fl": np.corrcoef(lt, lf)[0, 1],
               "sd_geo": lg.std(), "corr_geo": np.corrcoef(lt, lg)[0, 1], "sag_min": sag.min(), "sag_max": sag.max()}
        out["drift"].append(row)
        print(f"  drift {drift:4.1f} deg: SD {row['sd']:.3f} | strength factors {row['sd_fl']:.3f} "
              f"(corr {row['corr_fl']:+.2f}) | moment arms and axes {row['sd_geo']:.3f} (corr {row['corr_geo']:+.2f}) "
              f"| sagittal angle {row['sag_min']:+.1f} to {row['sag_max']:+.1f} deg")

    print("\n4. rich96: net |log(left / right)| of the element strengths (strength-weighted), 2000 draws")
    left = np.array([n.endswith(" L") for n in full.names])
    q = []
    for _ in range(2000):
        e = full.strengths * np.exp(rng.normal(0.0, s.element_spread, full.m))
        q.append(abs(np.log((e[left].sum() / full.strengths[left].sum())
                            / (e[~left].sum() / full.strengths[~left].sum()))))
    out["asym"] = np.percentile(q, [50, 90, 99]).tolist()
    print(f"  median {out['asym'][0]:.3f}, 90th percentile {out['asym'][1]:.3f}, 99th {out['asym'][2]:.3f} "
          f"(the asymmetry truth injects 0.3-0.7)")
    print(f"\n{time.perf_counter() - t0:.0f} s wall, {time.process_time():.0f} s CPU, load {os.getloadavg()[0]:.1f}")
    return out


if __name__ == "__main__":
    main()
