"""The run-to-run target on the reduced pipeline (session fixture): member 0 is the pipeline's own run, Algorithm
4's members coincide, every Chapter 5 / 6 printed cell has a run-to-run verdict beside its scorecard verdict, and
the attribution names its variants.
"""

import numpy as np
import pandas as pd
import pytest

from neckstrength.report.scorecard.distribution import ATTRIBUTION_COLUMNS, RUN_VERDICTS, SUMMARY_COLUMNS


def read(path):
    return pd.read_csv(path, comment="#", keep_default_na=False, na_values=[""])


@pytest.fixture(scope="module")
def done(repo_copy, ci_pipeline):
    assert ci_pipeline.returncode == 0, ci_pipeline.stdout[-3000:] + ci_pipeline.stderr[-3000:]
    return repo_copy


def test_member_zero_is_the_pipelines_run(done):
    for ds in ("norm", "weak", "S005"):
        m = read(done / f"results/reruns/chapter5/p2m7/{ds}/members.csv")
        est = read(done / f"results/chapter5/p2m7/{ds}/estimate.csv").groupby("parameter").first()
        f = m[m["quantity"] == "f_c"]
        m0 = f[f["member"] == 0].set_index("parameter")["value"]
        np.testing.assert_allclose(m0.to_numpy(), est.loc[m0.index, "f_c"].to_numpy(), rtol=1e-5)
        spread = f.groupby("parameter")["value"].agg(lambda v: v.max() - v.min())
        assert m["member"].nunique() == 2 and float(spread.max()) == 0.0       # Algorithm 4 draws nothing
    for ds in ("Sim", "S005"):
        m = read(done / f"results/reruns/chapter6/p2m7/{ds}/members.csv")
        est = read(done / f"results/chapter6/p2m7/{ds}/estimate.csv").set_index("muscle")
        m0 = m[(m["member"] == 0) & (m["quantity"] == "f_c")].set_index("parameter")["value"]
        np.testing.assert_allclose(m0.to_numpy(), est.loc[m0.index, "f_c"].to_numpy(), rtol=1e-5)
        f = m[m["quantity"] == "f_c"].groupby("parameter")["value"]
        assert m["member"].nunique() == 3 and float((f.max() - f.min()).max()) > 0    # Table 6.1 does


def test_every_printed_cell_has_a_run_to_run_verdict(done):
    d = read(done / "results/report/scorecard_distribution.csv")
    assert set(d["verdict"]) <= set(RUN_VERDICTS) and (d["verdict"] == RUN_VERDICTS[1]).any()
    assert d.groupby("source").size().to_dict() == {"Table 5.1 (p2m7)": 48, "Table 6.1 (p2m7)": 30}
    assert (d["scorecard_verdict"] != "").all() and (d["scorecard_kind"] != "").all()      # joined to the scorecard
    ch5 = d[d["source"] == "Table 5.1 (p2m7)"]
    assert (ch5["spread"] == 0).all() and (ch5["precision"].isna()).all()
    s = read(done / "results/report/scorecard_distribution_summary.csv")
    assert list(s.columns) == SUMMARY_COLUMNS and s["chance_rate"].between(0, 1).all()
    sp = read(done / "results/report/scorecard_distribution_spread.csv")
    assert set(sp["group"]) == {"TC-E", "TC-F", "TS-B", "TS-E", "TS-F", "CS-E", "CS-F"}


def test_attribution_lists_each_variant(done):
    s = read(done / "results/reruns/chapter5/p2m7/attribution_summary.csv")
    # the reduced config's list replaces the full config's (a --configfile merges maps but replaces lists)
    assert list(s.columns) == ATTRIBUTION_COLUMNS and list(s["variant"]) == ["baseline", "unprinted_osim"]
    assert (s["items"] == 48).all() and s.loc[0, "moved_onto"] == 0
