"""The scorecard's honesty checks: every conclusion test can fail (a perturbed result flips its verdict), a test
that agrees by chance too often is not used, censored iteration counts are compared as censored, the degrees of
freedom of the B.3-recovered strengths are counted as calibrated items, the Chapter 4 claim about unproducible
directions is evaluated for every variant with both outcomes possible, items that match by construction (erratum
cells placed by our derivation, D(f_c) at the noise-free ceiling, sigma_c at a clip limit, censored iteration counts)
are their own kind, and a scorer error is 'not evaluated' with its reason.

Fast: no pipeline run (synthetic rows and small synthetic tables in a temporary directory).
"""

import math
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from neckstrength.report.scorecard import (BY_CONSTRUCTION, CALIBRATED, CONCLUSION_TESTS, DIFFERS, INDEPENDENT,
                                           MATCHES, NOT_EVALUATED, SAME_CONCLUSION, _row, build_scorecard,
                                           ScorecardSettings, chance_rates, summarize, tolerance_table, tolerances)

CONFIG = ScorecardSettings(seed=20261123)
N = 8


def _items(key):
    """(thesis, ours, aux, perturbed ours) for N items of one conclusion test: ours is off the printed number
    (outside any tolerance) but reaches the same conclusion; the perturbed copy changes item 0 so that the
    conclusion differs."""
    t = np.arange(N, 0, -1, dtype=float) * 10.0
    aux = [(math.nan, math.nan)] * N
    if key in ("group_strength_rank", "table_3_2_rank", "relative_strength_rank"):
        o = t * 1.7
        p = o.copy()
        p[0], p[1] = o[1], o[0]  # two groups swap rank
    elif key in ("moment_arm_sign", "loa_sign"):
        t = t * np.where(np.arange(N) % 2, 1, -1) * 1e-3
        o = t * 3
        p = o.copy()
        p[0] = -p[0]
        aux = [(1e-5, math.nan)] * N
    elif key == "icc_class":
        t = np.array([0.95, 0.8, 0.6, 0.3, 0.92, 0.78, 0.55, 0.1])
        o = t + np.array([0.02, 0.05, 0.05, 0.1, 0.03, 0.05, 0.05, 0.1])
        p = o.copy()
        p[0] = 0.4  # excellent -> poor
    elif key in ("f_significance", "convergence"):
        t = np.array([1, 0, 1, 0, 1, 0, 1, 0], float)
        o = t.copy()
        p = o.copy()
        p[0] = 1 - p[0]
    elif key == "pairwise_significance":
        t = np.array([1, -1, 0, 1, -1, 0, 1, -1], float)
        o = t.copy()
        p = o.copy()
        p[0] = -1.0  # significant, reversed direction
    elif key == "recovers_f_a":
        f_true = np.full(N, 100.0)
        t = np.array([105, 130, 70, 98, 140, 60, 102, 125], float)
        o = np.array([95, 150, 50, 108, 120, 80, 91, 115], float)
        p = o.copy()
        p[0] = 200.0  # recovers -> above
        aux = [(100.0, 0.10)] * N
        assert np.all(np.abs(t - f_true) > 0) and np.all(np.abs(o - t) > 0.5)
    elif key == "identification":
        t = np.array([0.05, 0.2, 0.03, 0.25, 0.08, 0.3, 0.01, 0.15])
        o = np.array([0.09, 0.3, 0.06, 0.15, 0.02, 0.2, 0.04, 0.28])
        p = o.copy()
        p[0] = 0.3
        aux = [(0.1, math.nan)] * N
    elif key == "D_fc_same_fit":
        t = np.array([0.23, 0.5, 0.97, 0.4, 0.99, 0.1, 0.6, 0.96])
        o = np.array([0.3, 0.45, 0.999, 0.32, 0.95, 0.18, 0.55, 0.999])
        p = o.copy()
        p[0] = 0.69  # the example: 0.23 vs 0.69, same side of 0.95, not the same fit
        aux = [(0.1, 0.95)] * N
    else:
        raise AssertionError(f"no perturbation defined for conclusion test {key!r}")
    return t, o, aux, p


def _rows(key, ours):
    t, _, aux, _ = _items(key)
    return [_row("Chapter 5", "synthetic", f"{key} item {i}", f"{t[i]:g}", f"{ours[i]:g}", ours[i] - t[i], False,
                 "outside tolerance by construction", key, ("random",), "synthetic.csv", test=key, tv=t[i],
                 ov=ours[i], aux=aux[i]) for i in range(N)]


@pytest.mark.parametrize("key", sorted(CONCLUSION_TESTS))
def test_every_conclusion_test_can_fail(key):
    """Used (chance threshold lifted), the unperturbed result reaches the same conclusion and the perturbed one
    differs on the perturbed item: the verdict flips."""
    _, o, _, p = _items(key)
    lifted = {"conclusion_chance_max": 1.0}
    before, _ = build_like(key, o, lifted)
    after, _ = build_like(key, p, lifted)
    assert (before["verdict"] == SAME_CONCLUSION).all(), before[["item", "verdict", "conclusion"]]
    assert after.loc[after["item"] == f"{key} item 0", "verdict"].item() == DIFFERS
    flipped = (before["verdict"] != after["verdict"]).sum()
    assert flipped >= 1


def build_like(key, ours, overrides=None):
    from neckstrength.report.scorecard import score_rows

    return score_rows(_rows(key, ours), CONFIG, overrides)


@pytest.mark.parametrize("key", sorted(CONCLUSION_TESTS))
def test_conclusion_test_used_only_if_chance_is_small(key):
    """With the default threshold (20 %), a row gets 'same conclusion' only from a test whose chance rate on these
    items is at most 0.2; the chance rate is reported per row and in the tolerance table."""
    _, o, _, _ = _items(key)
    sc, _ = build_like(key, o)
    c = sc["chance_rate"].iloc[0]
    assert 0.0 <= c <= 1.0
    if c > 0.2:
        assert (sc["verdict"] == DIFFERS).all()
        assert sc["conclusion"].str.contains("not a conclusion test").all()
    else:
        assert (sc["verdict"] == SAME_CONCLUSION).all()
    tab = tolerance_table(tolerances(), sc.attrs["chance"]).set_index("key")
    assert tab.loc[key, "chance_rate"] == pytest.approx(c, abs=1e-3)
    assert tab.loc[key, "beside"] in tab.index


def test_chance_rate_of_a_coin_flip_is_about_one_half():
    """Two balanced classes: permuting ours agrees about half the time; a rank over 8 groups about 1/8."""
    t, o, aux, _ = _items("f_significance")
    df = pd.DataFrame(_rows("f_significance", o) + _rows("group_strength_rank", _items("group_strength_rank")[1]))
    ch = chance_rates(df, seed=1).set_index("test")
    assert 0.35 < ch.loc["f_significance", "chance_rate"] < 0.65
    assert 0.05 < ch.loc["group_strength_rank", "chance_rate"] < 0.2


# --------------------------------------------------------------------------- censored iteration counts

def _ch5_table(tmp_path, iters_rows):
    d = tmp_path / "results" / "chapter5" / "p2m7"
    d.mkdir(parents=True)
    lines = ["dataset,quantity,muscle,thesis,ours,difference,rel_difference,note"]
    for ds, th, ours, note in iters_rows:
        lines.append(f"{ds},iters,,{th},{ours},{ours - th},,{note}")
    (d / "table_vs_thesis.csv").write_text("\n".join(lines) + "\n")
    return d / "table_vs_thesis.csv"


def test_censored_iterations_compared_as_censored(tmp_path):
    path = _ch5_table(tmp_path, [
        ("A", 30, 30, "thesis did not converge; ours did not converge"),   # both '30+'
        ("B", 30, 29, "thesis did not converge"),                           # ours converged at 29: not '30+'
        ("C", 11, 30, "ours did not converge"),                             # thesis converged
        ("D", 11, 12, ""),                                                  # both converged, within 20 %
    ])
    cfg = ScorecardSettings(seed=1, thesis_dir=str(tmp_path / "none"))
    sc, _ = build_scorecard([str(path)], cfg)
    v = dict(zip(sc["item"], sc["verdict"]))
    assert v["A: iters"] == MATCHES
    assert v["B: iters"] != MATCHES and v["C: iters"] != MATCHES
    assert v["D: iters"] == MATCHES
    th = dict(zip(sc["item"], sc["thesis"]))
    assert th["A: iters"] == "30+" and th["D: iters"] == "11"


# --------------------------------------------------------------------------- degrees of freedom (Table B.3)

def _b3_fixture(tmp_path):
    """A two-group 'Table B.3': group g1 has 2 recovered strengths among 3 members, g2 none."""
    model_dir = tmp_path / "data" / "model"
    model_dir.mkdir(parents=True)
    (model_dir / "b3_implied_strengths.csv").write_text(
        "index,name,b3_group,implied_strength_N,se_N,n_equations,max_abs_residual_rounding_sd,model_unscaled_N\n"
        "1,m1,g,10,0.1,10,1,9\n2,m2,g,20,0.1,10,1,19\n")
    d = tmp_path / "results" / "model" / "s3m24"
    d.mkdir(parents=True)
    (d / "groups.csv").write_text("group,n_members,members\ng1-R,3,m1; m2; m3\ng2-R,1,m4\n")
    lines = ["group,quantity,thesis,ours,difference,note"]
    for g in ("g1-R", "g2-R"):
        lines.append(f"{g},strength_N,50.0,50.01,0.01,")
        for j, (t, o) in enumerate([(0.0100, 0.01001), (0.0200, 0.02003), (-0.0300, -0.03002), (0.0400, 0.04)]):
            lines.append(f"{g},C{j}_pitch (m),{t},{o},{o - t},")
    (d / "parameters_vs_thesis.csv").write_text("\n".join(lines) + "\n")
    return d / "parameters_vs_thesis.csv", model_dir


@pytest.mark.parametrize("source,expect_calibrated", [("b3_implied", 2), ("osim", 0)])
def test_recovered_strengths_count_as_calibrated_items(tmp_path, source, expect_calibrated):
    path, model_dir = _b3_fixture(tmp_path)
    cfg = ScorecardSettings(seed=1, model_dir=str(model_dir), thesis_dir=str(tmp_path / "none"),
                            unprinted_strengths=source, grouping_supplements=False)
    sc, _ = build_scorecard([str(path)], cfg)
    g1 = sc[sc["item"].str.startswith("g1-R")]
    g2 = sc[sc["item"].str.startswith("g2-R")]
    assert (g1["kind"] == CALIBRATED).sum() == expect_calibrated
    assert (g2["kind"] == INDEPENDENT).all()
    if expect_calibrated:
        # the strength and the best-fitting moment arm are the calibrated ones; the rest over-determined
        cal = g1[g1["kind"] == CALIBRATED]
        assert "g1-R strength (N)" in set(cal["item"]) and "g1-R C3 pitch moment arm (m)" in set(cal["item"])
        assert g1.loc[g1["kind"] == INDEPENDENT, "basis"].str.contains("over-determined").all()
        assert g1["basis"].str.contains("print units").all()
    summ = summarize(sc).set_index(["chapter", "kind"])
    assert summ.loc[("all", CALIBRATED), "items"] == expect_calibrated
    assert summ.loc[("all", INDEPENDENT), "items"] == len(sc) - expect_calibrated


# --------------------------------------------------------------------------- Chapter 4: both outcomes possible

def _surface(directions, status, muscles):
    from neckstrength.surfaces.surfaces import Surface

    st = pd.DataFrame({"direction": directions, "factor": 1.0, "wrench": 0.0,
                       "force_N": [100.0 if s == "optimal" else 0.0 for s in status], "status": status})
    act = pd.DataFrame([{"direction": d, "factor": 1.0, "muscle": m, "alpha": 0.5}
                        for d in directions for m in muscles])
    return Surface(st, act)


@pytest.mark.parametrize("variant,n_muscles,status,holds", [
    ("p2-anatomical", 7, ["optimal", "optimal", "optimal"], True),        # m >= 2n: produces every direction
    ("p2-anatomical", 7, ["optimal", "infeasible", "optimal"], False),
    ("s7-anatomical", 24, ["optimal", "infeasible", "optimal"], True),   # m < 2n: cannot produce some
    ("s7-anatomical", 24, ["optimal", "optimal", "optimal"], False),
])
def test_unproducible_direction_claim_can_fail(variant, n_muscles, status, holds):
    from neckstrength.surfaces.claims import evaluate_claims

    dirs = ["front", "back", "left"]
    d = pd.DataFrame({"name": dirs, "azimuth_deg": [0.0, 180.0, 90.0], "sagittal": [True, True, False]})
    surf = _surface(dirs, status, [f"g{i}" for i in range(n_muscles)])
    claims = evaluate_claims({variant: surf}, d, "s3-anatomical", None)
    row = claims[claims["variants"] == variant]
    assert len(row) == 1
    assert bool(row["holds"].item()) is holds
    assert row["verdict"].item() == ("holds" if holds else "does not hold")


# --------------------------------------------------------------------------- matches by construction

def _b1_fixture(tmp_path, errata=True):
    """A three-cell 'Table B.1' comparison: row 11 C4-C5 pitch placed by the erratum because it equals our derived
    value, row 33 C0-C1 pitch relocated on the evidence of Table B.3, row 5 as printed."""
    thesis = tmp_path / "data" / "thesis"
    thesis.mkdir(parents=True)
    (thesis / "errata_B1.csv").write_text(
        "# units: printed=m; corrected=m\nindex,name,field,printed,corrected,evidence\n"
        "11,sternohyoid,C0-C1_pitch,-0.0509,,printed triple equals the derived C4-C5 triple\n"
        "11,sternohyoid,C4-C5_pitch,,-0.0509,printed under C0-C1 (derived -0.050926)\n"
        "11,sternohyoid,C6-C7_pitch,,-0.0453,not printed in the seed; OpenSim-derived value rounded to 4 decimals\n"
        "33,long cap sklc4,C0-C1_pitch,,-0.0120,B.3 Lcap-R C0-C1 pitch\n")
    d = tmp_path / "results" / "model"
    d.mkdir(parents=True)
    (d / "momentarm_vs_B1.csv").write_text(
        "index,name,joint,axis,thesis_B1,derived,difference,rel_difference\n"
        "5,m5,strength,,100,100,0,0\n"
        "5,m5,C2-C3,pitch,0.0100,0.01002,2e-05,0.002\n"
        "11,sternohyoid,C4-C5,pitch,-0.0509,-0.050926,-2.6e-05,-0.0005\n"
        "11,sternohyoid,C6-C7,pitch,-0.0453,-0.045290,1e-05,0.0002\n"
        "33,long cap sklc4,C0-C1,pitch,-0.0120,-0.012010,-1e-05,-0.0008\n")
    cfg = ScorecardSettings(seed=1, thesis_dir=str(thesis), apply_b1_errata=errata)
    return d / "momentarm_vs_B1.csv", cfg


def test_b1_cells_placed_by_the_erratum_from_our_derivation_are_by_construction(tmp_path):
    path, cfg = _b1_fixture(tmp_path)
    sc, _ = build_scorecard([str(path)], cfg)
    kind = {r["item"].split(":")[0] + " " + r["item"].split(": ")[1].split()[0]: r["kind"]
            for r in sc.to_dict("records")}
    assert kind == {"row 5 m5 C2-C3": INDEPENDENT, "row 11 sternohyoid C4-C5": BY_CONSTRUCTION,
                    "row 11 sternohyoid C6-C7": BY_CONSTRUCTION, "row 33 long cap sklc4 C0-C1": INDEPENDENT}
    assert (sc["verdict"] == MATCHES).all()  # shown with its verdict ...
    bc = sc[sc["kind"] == BY_CONSTRUCTION]
    assert bc["basis"].str.contains("erratum").all() and not bc["basis"].str.contains("nothing fitted").any()
    assert bc["reason"].str.contains("never counted as reproduced").all()
    assert not sc.loc[sc["kind"] == INDEPENDENT, "reason"].str.contains("by construction").any()
    summ = summarize(sc).set_index(["chapter", "kind"])
    # ... but not counted among the independent matches
    assert summ.loc[("all", INDEPENDENT), "matches"] == 2 and summ.loc[("all", BY_CONSTRUCTION), "items"] == 2
    # without the erratum the cells are as printed: nothing was placed by our derivation
    path2, cfg2 = _b1_fixture(tmp_path / "plain", errata=False)
    sc2, _ = build_scorecard([str(path2)], cfg2)
    assert (sc2["kind"] == INDEPENDENT).all()


def _estimates_table(tmp_path, rows, model="p2m7"):
    """A Chapter 5 comparison table (dataset, quantity, muscle, thesis, ours, note) under results/chapter5/."""
    d = tmp_path / "results" / "chapter5" / model
    d.mkdir(parents=True)
    lines = ["dataset,quantity,muscle,thesis,ours,difference,rel_difference,note"]
    for ds, q, m, th, ours, note in rows:
        lines.append(f"{ds},{q},{m},{th},{ours},{ours - th},,{note}")
    (d / "table_vs_thesis.csv").write_text("\n".join(lines) + "\n")
    return d / "table_vs_thesis.csv"


def _kinds(sc):
    return dict(zip(sc["item"], sc["kind"])), dict(zip(sc["item"], sc["verdict"]))


def test_d_fc_at_the_noise_free_ceiling_is_by_construction(tmp_path):
    path = _estimates_table(tmp_path, [
        ("norm", "f_a", "TC-E", 100, 100, ""),       # 'norm' is simulated (f_a printed)
        ("weak", "f_a", "TC-E", 50, 50, ""),
        ("norm", "D_fc", "", 1.00, 0.998, ""),        # both at the ceiling of noise-free data
        ("weak", "D_fc", "", 0.99, 0.96, ""),         # ours below it: a real difference
        ("S005", "D_fc", "", 0.995, 0.999, ""),       # a participant's data are not noise-free
    ])
    sc, _ = build_scorecard([str(path)], ScorecardSettings(seed=1, thesis_dir=str(tmp_path / "none")))
    kind, verdict = _kinds(sc)
    assert kind == {"norm: D_fc": BY_CONSTRUCTION, "weak: D_fc": INDEPENDENT, "S005: D_fc": INDEPENDENT}
    assert verdict["norm: D_fc"] == MATCHES and verdict["weak: D_fc"] != MATCHES
    assert "ceiling" in sc.loc[sc["item"] == "norm: D_fc", "basis"].item()


def test_sigma_c_at_a_clip_limit_on_both_sides_is_by_construction(tmp_path):
    path = _estimates_table(tmp_path, [
        ("S005", "sigma_c", "TC-E", 0.30, 0.3, ""),    # both at the upper clip limit
        ("S005", "sigma_c", "TS-B", 0.01, 0.01, ""),   # both at the lower one
        ("S005", "sigma_c", "TC-F", 0.30, 0.28, ""),   # ours below the limit: matches, and that is evidence
        ("S005", "sigma_c", "TS-F", 0.12, 0.12, ""),   # inside the range
    ])
    cfg = ScorecardSettings(seed=1, thesis_dir=str(tmp_path / "none"), sigma_clip=(0.01, 0.3))
    sc, _ = build_scorecard([str(path)], cfg)
    kind, verdict = _kinds(sc)
    assert kind == {"S005: TC-E sigma_c": BY_CONSTRUCTION, "S005: TS-B sigma_c": BY_CONSTRUCTION,
                    "S005: TC-F sigma_c": INDEPENDENT, "S005: TS-F sigma_c": INDEPENDENT}
    assert set(verdict.values()) == {MATCHES}
    # the limits come from the config: with another clip range the same numbers are independent
    cfg = replace(cfg, sigma_clip=(0.02, 0.5))
    sc2, _ = build_scorecard([str(path)], cfg)
    assert (sc2["kind"] == INDEPENDENT).all()


def test_censored_iteration_counts_on_both_sides_are_by_construction(tmp_path):
    path = _ch5_table(tmp_path, [
        ("A", 30, 30, "thesis did not converge; ours did not converge"),
        ("B", 30, 29, "thesis did not converge"),
        ("D", 11, 12, ""),
    ])
    sc, _ = build_scorecard([str(path)], ScorecardSettings(seed=1, thesis_dir=str(tmp_path / "none")))
    kind, verdict = _kinds(sc)
    assert kind == {"A: iters": BY_CONSTRUCTION, "B: iters": INDEPENDENT, "D: iters": INDEPENDENT}
    assert verdict["A: iters"] == MATCHES and "maxIter" in sc.loc[sc["item"] == "A: iters", "basis"].item()
    summ = summarize(sc).set_index(["chapter", "kind"])
    assert summ.loc[("Chapter 5", INDEPENDENT), "matches"] == 1  # only D
    assert summ.loc[("Chapter 5", BY_CONSTRUCTION), "matches"] == 1


def test_a_scorer_error_is_not_evaluated_with_its_reason(tmp_path):
    """The Table 5.1 caption claim needs the unweakened f_a; without 'norm' in the table and without a readable
    thesis table, the claim is 'not evaluated' with the exception as its reason, not 'does not hold'."""
    path = _estimates_table(tmp_path, [
        ("weak", "f_a", "TC-E", 50, 50, ""),
        ("weak", "f_c", "TC-E", 68, 57, ""),
        ("weak", "sigma_c", "TC-E", 0.05, 0.06, ""),
    ])
    sc, skipped = build_scorecard([str(path)], ScorecardSettings(seed=1, thesis_dir=str(tmp_path / "none")))
    assert not sc["item"].str.contains("identified with high confidence").any()
    claim = skipped[skipped["item"].str.contains("identified with high confidence")]
    assert len(claim) == 1 and claim["verdict"].item() == NOT_EVALUATED
    assert claim["reason"].item().startswith("scorer error: ") and "Error" in claim["reason"].item()
    summ = summarize(sc, skipped).set_index(["chapter", "kind"])
    assert summ.loc[("Chapter 5", INDEPENDENT), "not_evaluated"] == 1
    assert summ.loc[("all", INDEPENDENT), "items"] == len(sc)  # counted apart from the scored items
