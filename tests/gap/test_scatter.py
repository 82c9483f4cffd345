"""Aiming scatter (gap.scatter, issue 32 item 1): direction sensitivity and the permutation test of its shape."""

import numpy as np
import pytest

from neckstrength.gap.scatter import ScatterSettings, direction_sensitivity, scatter_test


def test_scatter_test_finds_residuals_that_grow_with_sensitivity_and_not_plain_noise():
    rng = np.random.default_rng(0)
    v = rng.uniform(0.0, 0.02, 25)
    s = ScatterSettings(permutations=999)
    # aim uniform in a 12 deg cone, ring at 10 deg: E[r^2] = sigma^2 + v c^2 / (2 a^2)
    c, a = 12.0, s.ring_deg
    hits_aim = hits_noise = 0
    for _ in range(40):
        aim = rng.normal(0, np.sqrt(v * c ** 2 / (2 * a ** 2)))
        hits_aim += scatter_test(rng.normal(0, 0.04, 25) + aim, v, rng, s)["p"] <= 0.05
        hits_noise += scatter_test(rng.normal(0, 0.04, 25), v, rng, s)["p"] <= 0.05
    assert hits_aim >= 20      # power about 0.65 at this size (25 tests); >= 20 of 40 by chance alone: < 1e-9
    assert hits_noise <= 6             # level 0.05: 2 expected of 40, 6 or more has chance < 0.02


def test_scatter_test_cone_estimate_and_degenerate_input():
    v = np.linspace(0.001, 0.03, 200)
    r = np.sqrt(0.04 ** 2 + v * 12.0 ** 2 / (2 * 10.0 ** 2))          # exactly the expected squares
    t = scatter_test(r, v, np.random.default_rng(1), ScatterSettings(permutations=199))
    assert t["cone_deg"] == pytest.approx(12.0, rel=1e-6) and t["p"] <= 0.01
    assert np.isnan(scatter_test(np.ones(5), np.zeros(5), np.random.default_rng(1))["p"])


def test_direction_sensitivity_is_zero_on_a_zero_ring_and_grows_with_it(ctx_s3):
    d = ctx_s3.directions
    P, N = d[["px", "py", "pz"]].to_numpy(float), d[["nx", "ny", "nz"]].to_numpy(float)
    f = ctx_s3.model.strengths
    assert np.allclose(direction_sensitivity(ctx_s3.model, f, P[:4], N[:4], ScatterSettings(ring_deg=0.0)), 0.0)
    v5 = direction_sensitivity(ctx_s3.model, f, P[:4], N[:4], ScatterSettings(ring_deg=5.0))
    v15 = direction_sensitivity(ctx_s3.model, f, P[:4], N[:4], ScatterSettings(ring_deg=15.0))
    assert np.all(v5 > 0) and np.all(v15 > v5)


def test_scatter_power_benchmark_runs_and_reports_every_statistic():
    """benchmarks/bench_gap_scatter_power.py (the shape test's power with the true strengths) on two cases: every
    statistic's power and noise-alone share are reported as shares of the cases."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_gap_scatter_power.py"
    spec = importlib.util.spec_from_file_location("bench_gap_scatter_power", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = mod.main(["--cases", "2", "--permutations", "19"])
    assert set(out["stats"]) == {"slope_r2", "slope_abs", "spearman_abs", "logv_r2", "sqrtv_abs"}
    for v in out["stats"].values():
        assert set(v) == {"aim_01", "aim_05", "noise_01", "noise_05"}
        assert all(x in (0.0, 0.5, 1.0) for x in v.values())
        assert v["aim_01"] <= v["aim_05"] and v["noise_01"] <= v["noise_05"]
