"""The trial-to-trial scatter estimated from the valid repeats (trials.noise) and its noise table."""

import numpy as np
import pandas as pd
import pytest

from neckstrength.io import DataValidationError
from neckstrength.trials import import_trials, write_import
from neckstrength.trials.importer import default_outputs
from neckstrength.trials.noise import pooled_log_sd, read_noise_table
from neckstrength.trials.synthetic import generate_example


def test_pooled_log_sd_formula():
    g = [np.array([100.0, 110.0]), np.array([50.0, 45.0, 55.0]), np.array([80.0])]   # the single trial: no df
    v = [np.log(x) for x in g[:2]]
    ss = sum(((x - x.mean()) ** 2).sum() for x in v)
    s, df, lo, hi = pooled_log_sd(g)
    assert df == 3 and s == pytest.approx(np.sqrt(ss / 3))
    assert lo < s < hi
    assert pooled_log_sd([np.array([5.0])]) [1] == 0


def test_pooled_interval_coverage_by_simulation():
    # 25 directions x 2 or 3 trials at a known log SD: the 95% interval covers it in about 95% of 2000 data sets
    rng = np.random.default_rng(20261127)
    sigma, cover = 0.07, 0
    for _ in range(2000):
        groups = [np.exp(rng.normal(np.log(200), 0.5) + rng.normal(0, sigma, n)) for n in rng.integers(2, 4, 25)]
        _, _, lo, hi = pooled_log_sd(groups)
        cover += lo <= sigma <= hi
    assert 0.93 <= cover / 2000 <= 0.97


@pytest.fixture(scope="module")
def synthetic_noise(config, directions, tmp_path_factory):
    """The example-lab generator with a known trial-to-trial log SD (0.06 and 0.15), imported."""
    out = {}
    for sd in (0.06, 0.15):
        trials, _ = generate_example(config, seed=20261127, repeat_sd=sd)
        p = tmp_path_factory.mktemp(f"noise{sd}") / "trials.csv"
        trials.to_csv(p, index=False)
        out[sd] = (import_trials(p, directions), p.parent)
    return out


def test_import_noise_covers_the_true_sd(synthetic_noise, directions):
    for sd, (res, _) in synthetic_noise.items():
        nz = res.noise.set_index("participant")
        assert list(nz.index) == ["P01", "P02", "P03"]
        for p, r in nz.iterrows():
            # every test direction measured at least twice; about one trial in six falls outside the window
            assert len(directions) - 2 <= r["n_directions"] <= len(directions)
            assert r["n_directions_with_repeats"] >= 15 and r["df"] >= r["n_directions_with_repeats"]
            assert r["ci_low"] <= sd <= r["ci_high"], (sd, p, r.to_dict())
            assert r["ci_high"] / r["ci_low"] < 2.2
        assert res.summary["noise_log_sd"]["P01"] == pytest.approx(nz.loc["P01", "noise_log_sd"])
    # the estimate follows the scatter: the two settings' intervals do not overlap
    lo = synthetic_noise[0.06][0].noise["ci_high"].max()
    hi = synthetic_noise[0.15][0].noise["ci_low"].min()
    assert lo < hi


def test_noise_table_written_and_read_back(synthetic_noise, tmp_path):
    res, _ = synthetic_noise[0.06]
    outputs = default_outputs(tmp_path)
    write_import(res, outputs)
    assert outputs["noise"].name == "noise.csv"
    table = read_noise_table(outputs["noise"])
    assert set(table) == {"P01", "P02", "P03"}
    assert table["P02"]["noise_log_sd"] == pytest.approx(res.noise.set_index("participant").loc["P02",
                                                                                               "noise_log_sd"],
                                                         rel=1e-4)


def test_noise_table_without_repeats_and_bad_rows(tmp_path):
    p = tmp_path / "noise.csv"
    pd.DataFrame({"participant": ["A", "B"], "noise_log_sd": [0.05, np.nan], "df": [20, 0],
                  "ci_low": [0.04, np.nan], "ci_high": [0.07, np.nan]}).to_csv(p, index=False)
    assert set(read_noise_table(p)) == {"A"}                       # df 0: no repeats, no value
    pd.DataFrame({"participant": ["A"], "noise_log_sd": [-0.05], "df": [20], "ci_low": [0.04],
                  "ci_high": [0.07]}).to_csv(p, index=False)
    with pytest.raises(DataValidationError, match=r"noise.csv, row 1, field 'noise_log_sd'"):
        read_noise_table(p)
    pd.DataFrame({"participant": ["A"], "noise_log_sd": [0.05], "df": [20]}).to_csv(p, index=False)
    with pytest.raises(DataValidationError, match="missing column 'ci_low'"):
        read_noise_table(p)
    with pytest.raises(DataValidationError, match="not found"):
        read_noise_table(tmp_path / "absent.csv")
