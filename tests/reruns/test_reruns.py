"""Run-to-run distributions (issue 36): the printed precision, the central band per printed cell, the run-to-run
verdict and its chance rate (each can fail: a moved value flips it), Algorithm 4's members coincide while Table
6.1's differ, and the settings' defaults equal the schema's.

Fast: p2m7 only, Table 6.1 members at N_F = 2,000.
"""

import math
from dataclasses import fields
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from neckstrength.config import (abc_settings, build_directions, chapter6_settings, dataset_from_config,
                                 full_model_from_config, load_config, model_from_config, rerun_settings)
from neckstrength.pipeline.chapter6 import chapter6_dataset
from neckstrength.report.scorecard.distribution import (CONSISTENT, OUTSIDE, band_chance_rate, group_spread,
                                                         score_distribution)
from neckstrength.reruns import (RerunSettings, algorithm4_member, band_table, member_stream, printed_half_unit,
                                 sequential_member)

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("text, half", [("68", 0.5), ("0.23", 0.005), ("0.20", 0.005), ("30+", 0.5), ("255", 0.5),
                                        ("1.5e2", 5.0)])
def test_printed_half_unit(text, half):
    assert printed_half_unit(text) == pytest.approx(half)


def _members(values: dict, model="p2m7", ds="weak"):
    rows = []
    for (q, p), vals in values.items():
        rows += [{"model": model, "dataset": ds, "member": k, "quantity": q, "parameter": p, "value": v}
                 for k, v in enumerate(vals)]
    return pd.DataFrame(rows)


def _thesis(cells, model="p2m7", ds="weak"):
    return pd.DataFrame([{"model": model, "dataset": ds, "quantity": q, "group": g, "value": text,
                          "value_numeric": float(text.rstrip("+")), "censored": text.endswith("+")}
                         for q, g, text in cells])


def test_band_table_quantiles_sides_and_precision():
    vals = np.arange(10, 20, dtype=float)                      # 10 members: 10 ... 19
    m = _members({("f_c", "TC-E"): vals, ("f_c", "mf-R"): np.full(10, 57.0), ("D_fc", ""): np.full(10, 0.5)})
    t = _thesis([("f_c", "TC-E", "14"), ("f_c", "mf", "68"), ("D_fc", "", "0.50"), ("f_c", "CS-F", "9")])
    b = band_table(m, t, 0.9).set_index("group")
    lo, hi = np.quantile(vals, [0.05, 0.95])
    assert b.loc["TC-E", "band_low"] == pytest.approx(lo) and b.loc["TC-E", "band_high"] == pytest.approx(hi)
    assert b.loc["TC-E", "members"] == 10 and not b.loc["TC-E", "print_reproducible"]   # spread 4 > 0.5
    assert b.loc["mf", "parameter"] == "mf-R" and b.loc["mf", "print_reproducible"]     # the right side, spread 0
    assert b.loc["", "printed_half_unit"] == pytest.approx(0.005)
    assert "CS-F" not in b.index                                                          # no members: no row


def _bands(thesis_vals, lows, highs, texts=None, quantity="f_c", censored=None):
    n = len(thesis_vals)
    return pd.DataFrame({"chapter": "Chapter 5", "table": "Table 5.1", "model": "p2m7", "dataset": "weak",
                         "quantity": quantity, "group": [f"G{i}" for i in range(n)], "parameter": "",
                         "thesis_text": texts or [f"{v:g}" for v in thesis_vals], "thesis": thesis_vals,
                         "censored": censored or [False] * n, "members": 10, "band_low": lows, "band_high": highs,
                         "median": [(a + b) / 2 for a, b in zip(lows, highs)], "sd": 1.0, "min": lows, "max": highs,
                         "spread": [(b - a) / 2 for a, b in zip(lows, highs)], "printed_half_unit": 0.5,
                         "print_reproducible": [(b - a) / 2 <= 0.5 for a, b in zip(lows, highs)]})


def test_verdict_flips_when_the_value_leaves_the_band():
    b = _bands([100.0, 200.0, 300.0, 400.0], [95.0, 190.0, 290.0, 390.0], [105.0, 210.0, 310.0, 410.0])
    table, summary = score_distribution(b, None, seed=1, n_permutations=200)
    assert list(table["verdict"]) == [CONSISTENT] * 4
    b2 = b.copy()
    b2.loc[0, "thesis"] = 106.0                               # 0.5 beyond the band + half unit: outside
    b2.loc[1, "thesis"] = 210.5                               # at the band's edge + half unit: inside
    v = list(score_distribution(b2, None, seed=1, n_permutations=200)[0]["verdict"])
    assert v[0] == OUTSIDE and v[1] == CONSISTENT
    s = summary.set_index("quantity").loc["all"]
    assert s["items"] == 4 and s["consistent"] == 4 and s["share_consistent"] == 1.0
    assert "not reproducible by any implementation" in table.loc[0, "precision"]      # spread 5 > 0.5


def test_chance_rate_small_for_separated_bands_large_for_overlapping_ones():
    sep = _bands([100.0, 200.0, 300.0, 400.0], [95.0, 190.0, 290.0, 390.0], [105.0, 210.0, 310.0, 410.0])
    wide = _bands([100.0, 200.0, 300.0, 400.0], [50.0] * 4, [450.0] * 4)
    c_sep, c_wide = band_chance_rate(sep, 1, 500), band_chance_rate(wide, 1, 500)
    assert c_sep == pytest.approx(0.25, abs=0.05)              # only the identity permutation lands inside
    assert c_wide == 1.0
    assert band_chance_rate(sep, 1, 500) == c_sep              # seeded


def test_censored_count_is_consistent_only_if_a_member_hit_the_cap():
    b = _bands([30.0, 30.0], [12.0, 12.0], [30.0, 20.0], texts=["30+", "30+"], quantity="iters",
               censored=[True, True])
    b["group"] = ""
    b["dataset"] = ["S003", "S004"]
    v = list(score_distribution(b, None, seed=1, n_permutations=50)[0]["verdict"])
    assert v == [CONSISTENT, OUTSIDE]


def test_group_spread_relative_to_median():
    b = _bands([100.0, 200.0], [90.0, 200.0], [110.0, 200.0])
    g = group_spread(b).set_index("group")
    assert g.loc["G0", "median_rel_spread"] == pytest.approx(0.1) and g.loc["G1", "max_rel_spread"] == 0.0


@pytest.fixture(scope="module")
def ci():
    cfg = load_config(ROOT / "config" / "config.ci.yaml")
    cfg["data"] = {k: str(ROOT / v) if isinstance(v, str) else v for k, v in cfg["data"].items()}
    cfg["geometry"]["test_point_spec"] = str(ROOT / cfg["geometry"]["test_point_spec"])
    model = model_from_config(full_model_from_config(cfg), cfg, "p2m7")
    return cfg, model, build_directions(cfg)


def test_algorithm4_members_coincide(ci):
    """Algorithm 4 draws nothing at random (Sec. 5.2.2.2): two streams give bit-identical estimates."""
    cfg, model, d = ci
    c = cfg["chapter5"]
    data = dataset_from_config(cfg, "chapter5", model, d, "weak")
    out = [algorithm4_member(model, data, abc_settings(cfg, "p2m7"), c["bootstrap_direction"],
                             np.random.default_rng(member_stream(cfg["seed"], "chapter5", "p2m7", "weak", k)[0]))
           for k in (0, 1)]
    assert out[0]["value"].tolist() == out[1]["value"].tolist()
    assert set(out[0]["quantity"]) == {"f_c", "sigma_c", "D_fc", "iters", "converged"}


def test_algorithm4_members_coincide_on_p3m12():
    """Table 5.2 runs the same deterministic sampler: two streams give bit-identical first two iterations of p3m12
    (a full member takes about 30 s; s3m24, 2 min a member, is checked by ``benchmarks/bench_reruns.py
    --identical`` and by the full config's K = 2 members)."""
    name, max_iter = "p3m12", 2
    import dataclasses

    cfg = load_config(ROOT / "config" / "config.yaml")
    cfg["data"] = {k: str(ROOT / v) if isinstance(v, str) else v for k, v in cfg["data"].items()}
    cfg["geometry"]["test_point_spec"] = str(ROOT / cfg["geometry"]["test_point_spec"])
    model = model_from_config(full_model_from_config(cfg), cfg, name)
    data = dataset_from_config(cfg, "chapter5", model, build_directions(cfg), "weak")
    st = dataclasses.replace(abc_settings(cfg, name), max_iter=max_iter)
    out = [algorithm4_member(model, data, st, cfg["chapter5"]["bootstrap_direction"],
                             np.random.default_rng(member_stream(cfg["seed"], "chapter5", name, "weak", k)[0]))
           for k in (0, 1)]
    assert out[0]["value"].tolist() == out[1]["value"].tolist()
    assert int(out[0].loc[out[0]["quantity"] == "iters", "value"].iloc[0]) == max_iter


def test_sequential_members_differ_and_repeat(ci):
    """Table 6.1's estimate depends on the N_F prior draws: two streams differ, the same stream repeats."""
    cfg, model, d = ci
    data = chapter6_dataset(model, d, "Sim", cfg)
    st = chapter6_settings(cfg, "p2m7", n_candidates=2000)
    s0, s1 = (member_stream(cfg["seed"], "chapter6", "p2m7", "Sim", k)[0] for k in (0, 1))
    a, b, a2 = (sequential_member(model, data, st, s) for s in (s0, s1, member_stream(cfg["seed"], "chapter6",
                                                                                     "p2m7", "Sim", 0)[0]))
    fa, fb = (x[x["quantity"] == "f_c"]["value"].to_numpy() for x in (a, b))
    assert not np.allclose(fa, fb, rtol=1e-3) and a["value"].tolist() == a2["value"].tolist()
    assert np.all(fa > 0) and 0 <= float(a.loc[a["quantity"] == "D_fc", "value"].iloc[0]) <= 1


def test_member_streams_are_distinct_and_keyed():
    s = [member_stream(20261123, "chapter6", "p2m7", "Sim", k) for k in range(3)]
    assert "key 'chapter6/p2m7/Sim'" in s[0][1] and "reruns/chapter6/p2m7/Sim', 2" in s[2][1]
    draws = [np.random.default_rng(x[0]).random() for x in s]
    assert len(set(draws)) == 3
    with pytest.raises(ValueError):
        member_stream(1, "chapter6", "p2m7", "Sim", -1)


def test_settings_defaults_equal_the_schema():
    schema = yaml.safe_load((ROOT / "workflow" / "schemas" / "config.schema.yaml").read_text())
    r = schema["properties"]["reruns"]["properties"]
    default = {f.name: f.default for f in fields(RerunSettings)}
    assert default == {"members": r["chapter5"]["properties"]["members"]["default"],
                       "level": r["level"]["default"],
                       "n_candidates": r["chapter6"]["properties"]["n_candidates"]["default"]}
    assert r["chapter6"]["properties"]["members"]["default"] == default["members"]
    cfg = load_config(ROOT / "config" / "config.yaml")
    assert rerun_settings(cfg, "chapter5", "s3m24").members == cfg["reruns"]["chapter5"]["model_members"]["s3m24"]
    assert rerun_settings(cfg, "chapter5", "p2m7").members == cfg["reruns"]["chapter5"]["members"]
    with pytest.raises(ValueError, match="members must be >= 2"):
        RerunSettings(members=1)
    with pytest.raises(ValueError, match="unknown chapter"):
        rerun_settings(cfg, "chapter7", "p2m7")
    assert math.isclose(RerunSettings().level, 0.9)


def test_apply_variant_changes_one_input_and_refuses_unknown_keys():
    from neckstrength.reruns.attribution import apply_variant

    cfg = {"chapter5": {"q": 90.0, "settings": {"p2m7": {"sigma0": 0.3}}}, "model": {"unprinted_strengths": "x"}}
    out = apply_variant(cfg, "q_80", {"chapter5.q": 80.0})
    assert out["chapter5"]["q"] == 80.0 and cfg["chapter5"]["q"] == 90.0           # a copy
    with pytest.raises(KeyError, match="variants.bad: unknown setting 'chapter5.qq'"):
        apply_variant(cfg, "bad", {"chapter5.qq": 1})
    with pytest.raises(KeyError, match="unknown setting 'chapterX'"):
        apply_variant(cfg, "bad", {"chapterX.q": 1})


def test_attribution_summary_names_the_items_a_change_moves():
    from neckstrength.report.scorecard.distribution import attribution_summary, within_tolerance

    assert within_tolerance("f_c", 68.0, 62.0) and not within_tolerance("f_c", 68.0, 57.0)   # 10 % of 68 N
    assert within_tolerance("iters", 30.0, 30.0, censored=True) and not within_tolerance("iters", 30.0, 12.0, True)
    base = _bands([68.0, 0.20], [57.0, 0.2], [57.0, 0.2])
    base["quantity"] = ["f_c", "sigma_c"]
    moved = base.copy()
    moved.loc[0, ["band_low", "band_high", "median"]] = 67.8
    runs = pd.concat([base.assign(variant="baseline"), moved.assign(variant="x")], ignore_index=True)
    items, summary = attribution_summary(runs, {"x": '{"chapter5.q": 80}'})
    s = summary.set_index("variant")
    assert s.loc["baseline", "within_tolerance"] == 1 and s.loc["x", "within_tolerance"] == 2
    assert s.loc["x", "moved_onto"] == 1 and "G0 f_c" in s.loc["x", "moved_onto_items"]
    assert s.loc["x", "on_print"] == 2 and s.loc["x", "moved_off"] == 0                   # 67.8 is 68 on the print


def test_chapter6_attribution_gives_each_variant_its_own_band(tmp_path):
    """Table 6.1 with one input changed: K members per variant (the same streams), a band per printed cell, and the
    summary's counts; a change of q moves our members (so the check can fail), an unknown key is an error."""
    import copy

    from neckstrength.config import ConfigError
    from neckstrength.pipeline.reruns import reruns_attribution_chapter6
    from neckstrength.report.scorecard.distribution import ATTRIBUTION_COLUMNS

    cfg = copy.deepcopy(load_config(ROOT / "config/config.ci.yaml"))
    cfg["reruns"]["chapter6"]["n_candidates"] = 2000
    cfg["reruns"]["attribution"]["chapter6"] = {"datasets": ["S005"], "members": 2,
                                                "variants": [{"name": "q_50", "set": {"chapter6.q": 50.0}}]}
    s = reruns_attribution_chapter6(cfg, "p2m7", tmp_path / "a.csv", tmp_path / "s.csv")
    assert list(s.columns) == ATTRIBUTION_COLUMNS and list(s["variant"]) == ["baseline", "q_50"]
    assert (s["members"] == 2).all() and (s["items"] == 15).all()           # S005: 7 f_c, 7 v_c, D(f_c)
    items = pd.read_csv(tmp_path / "a.csv", comment="#")
    base, q50 = (items[items["variant"] == v].set_index("item")["ours"] for v in ("baseline", "q_50"))
    assert (base - q50).abs().max() > 0                                      # the change moves our values
    assert (items["band_low"] <= items["ours"]).all() and (items["ours"] <= items["band_high"]).all()
    cfg["reruns"]["attribution"]["chapter6"]["variants"] = [{"name": "bad", "set": {"chapter6.nope": 1}}]
    with pytest.raises(ConfigError, match="bad"):
        reruns_attribution_chapter6(cfg, "p2m7", tmp_path / "a.csv", tmp_path / "s.csv")
