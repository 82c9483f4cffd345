"""Model reduction (Sec. 4.2.1.3) reproduces the published reduced-model tables.

Reducing the printed rows of Table B.1 (with the documented row-shift erratum,
data/thesis/errata_B1.csv) must reproduce Table B.3 (s3m24) and Table B.5
(p3m12) for every group whose members are all printed in the seed (rows 15-30
and 47-62 of B.1 are missing, so hyoids, SCM, scalenes, spcap, semicap,
levscap, mf and spcerv cannot be checked from B.1 alone).
Tolerances: B.1 prints 4 decimals (m) and 1 decimal (N); a 2-norm / weighted
mean of rounded values is within 0.0001 m + half a printed unit of the truth.
"""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from neckstrength.model.full import AXES, B1_JOINTS, base_name, load_table_b1
from neckstrength.model.reduction import read_grouping, reduce_strengths_and_arms

THESIS = Path(__file__).resolve().parents[2] / "data" / "thesis"
MA_TOL = 0.00016
F_TOL = 0.11


def _key(s):
    return " ".join(str(s).lower().split())


@pytest.fixture(scope="module")
def b1():
    return load_table_b1(THESIS, apply_errata=True)


def b1_group(b1, members, sides):
    keep = [(_key(base_name(n)) in members) and (("L" if n.endswith(" L") else "R") in sides)
            for n in b1["name"]]
    rows = b1[keep]
    f = rows["strength_N"].to_numpy(float)
    R = np.nan_to_num(rows[[f"{j}_{a}" for j in B1_JOINTS for a in AXES]].to_numpy(float)).T
    return f, R, rows


def groups(path):
    g = read_grouping(THESIS / path)
    return {name: set(_key(m) for m in sub["name_normalized"]) for name, sub in g.groupby("group")}


def printed_rows(b1):
    return set(_key(base_name(n)) for n in b1["name"])


def test_subocc_example_from_issue(b1):
    members = groups("table_B2_groups_s3m24.csv")["subocc"]
    f, R, _ = b1_group(b1, members, {"R"})
    fg, Rg = reduce_strengths_and_arms(R, f, np.ones((len(f), 1)))
    assert fg[0] == pytest.approx(100.5, abs=F_TOL)          # Table B.3 subocc-R strength
    assert Rg[B1_JOINTS.index("C0-C1") * 3 + 0, 0] == pytest.approx(0.0462, abs=MA_TOL)  # C0-C1 pitch


def _check_table(b1, grouping_file, params_file, planar):
    members_by_group = groups(grouping_file)
    params = pd.read_csv(THESIS / params_file, comment="#")
    printed = printed_rows(b1)
    checked = []
    for r in params.to_dict("records"):
        gname = r["group"]
        side = None
        if not planar:
            gname, side = gname.rsplit("-", 1)
        members = members_by_group[gname]
        if not members <= printed:
            continue
        f, R, rows = b1_group(b1, members, {"R", "L"} if planar else {side})
        fg, Rg = reduce_strengths_and_arms(R, f, np.ones((len(f), 1)))
        assert fg[0] == pytest.approx(r["strength_N"], abs=F_TOL), r["group"]
        for k, j in enumerate(B1_JOINTS):
            for a_i, a in enumerate(AXES):
                col = f"{j}_{a}"
                if col not in params.columns:
                    continue
                expected = 0.0 if pd.isna(r[col]) else r[col]
                assert Rg[3 * k + a_i, 0] == pytest.approx(expected, abs=MA_TOL), (r["group"], col)
        checked.append(r["group"])
    return checked


def test_b3_reproduced_for_every_fully_printed_group(b1):
    checked = _check_table(b1, "table_B2_groups_s3m24.csv", "table_B3_params_s3m24.csv", planar=False)
    assert sorted(checked) == sorted(["LC-R", "LC-L", "trap-R", "trap-L", "subocc-R", "subocc-L",
                                      "Lcap-R", "Lcap-L"])


def test_b5_reproduced_except_trap(b1):
    # Table B.5's trap row (186.6 N, C0-C1 0.0710 m) equals trapezius clavicular alone merged left+right:
    # the thesis dropped trap acr (no moment arm at the three joints) from p3m12's trap group although
    # Table B.4 lists it, and kept it in s3m24 (Table B.3 trap-R 372.7 N). We reproduce B.4 as printed
    # and record the discrepancy (docs/model.md); this test pins both facts.
    members = groups("table_B4_groups_p3m12.csv")
    params = pd.read_csv(THESIS / "table_B5_params_p3m12.csv", comment="#").set_index("group")
    f, R, _ = b1_group(b1, {"trap cl"}, {"R", "L"})
    fg, Rg = reduce_strengths_and_arms(R, f, np.ones((len(f), 1)))
    assert fg[0] == pytest.approx(params.loc["trap", "strength_N"], abs=F_TOL)
    assert Rg[6, 0] == pytest.approx(params.loc["trap", "C0-C1_pitch"], abs=MA_TOL)
    f, R, _ = b1_group(b1, members["trap"], {"R", "L"})
    fg_all, _ = reduce_strengths_and_arms(R, f, np.ones((len(f), 1)))
    assert abs(fg_all[0] - params.loc["trap", "strength_N"]) > 100  # B.4 membership does not give B.5

    params_no_trap = params.drop(index="trap").reset_index()
    checked = []
    for r in params_no_trap.to_dict("records"):
        mem = members[r["group"]]
        if not mem <= printed_rows(b1):
            continue
        f, R, _ = b1_group(b1, mem, {"R", "L"})
        fg, Rg = reduce_strengths_and_arms(R, f, np.ones((len(f), 1)))
        assert fg[0] == pytest.approx(r["strength_N"], abs=F_TOL), r["group"]
        for k, j in enumerate(B1_JOINTS):
            expected = 0.0 if pd.isna(r[f"{j}_pitch"]) else r[f"{j}_pitch"]
            assert Rg[3 * k, 0] == pytest.approx(expected, abs=MA_TOL), (r["group"], j)
        checked.append(r["group"])
    assert sorted(checked) == ["Lcap", "Lcol", "subocc"]


def test_planar_merge_is_sqrt2_of_spatial(b1):
    """Left/right merge of a symmetric pair: strength x sqrt(2), pitch arm x sqrt(2) (B.3 vs B.5)."""
    members = groups("table_B2_groups_s3m24.csv")["subocc"]
    fR, RR, _ = b1_group(b1, members, {"R"})
    fB, RB, _ = b1_group(b1, members, {"R", "L"})
    gR, aR = reduce_strengths_and_arms(RR, fR, np.ones((len(fR), 1)))
    gB, aB = reduce_strengths_and_arms(RB, fB, np.ones((len(fB), 1)))
    assert gB[0] == pytest.approx(np.sqrt(2) * gR[0])
    assert aB[6, 0] == pytest.approx(np.sqrt(2) * aR[6, 0])
    assert aB[7, 0] == pytest.approx(0.0, abs=1e-12)  # roll cancels between sides


def test_errata_applied_only_when_asked():
    raw = load_table_b1(THESIS, apply_errata=False).set_index("index")
    fixed = load_table_b1(THESIS, apply_errata=True).set_index("index")
    assert np.isnan(raw.loc[33, "C0-C1_pitch"]) and raw.loc[35, "C0-C1_pitch"] == -0.0120
    assert fixed.loc[33, "C0-C1_pitch"] == -0.0120 and np.isnan(fixed.loc[35, "C0-C1_pitch"])


# --- the assembled full model (OpenSim-derived moment arms, B.1 / B.3-implied strengths) -----------------

from neckstrength.model.full import load_full_model
from neckstrength.model.reduction import named_model

MODEL = Path(__file__).resolve().parents[2] / "data" / "model"
PARAM_TABLES = {"p2m7": "table_B7_params_p2m7.csv", "p3m12": "table_B5_params_p3m12.csv",
                "s3m24": "table_B3_params_s3m24.csv"}


@pytest.fixture(scope="module")
def full():
    return load_full_model(MODEL, THESIS)


def _max_diffs(model, table):
    t = pd.read_csv(THESIS / table, comment="#").set_index("group")
    ours = model.to_frame().set_index("muscle").loc[t.index]
    cols = [c for c in t.columns if c not in ("index", "strength_N")]
    df = (ours["strength_N"] - t["strength_N"]).abs().max()
    dr = (ours[cols].fillna(0.0) - t[cols].fillna(0.0)).abs().max().max()
    return df, dr


@pytest.mark.parametrize("name", ["p2m7", "p3m12", "s3m24"])
def test_named_models_reproduce_printed_parameter_tables(full, name):
    m = named_model(full, name, THESIS)
    assert m.m == {"p2m7": 7, "p3m12": 12, "s3m24": 24}[name]
    df, dr = _max_diffs(m, PARAM_TABLES[name])
    # B.1/B.3 print 0.1 N and 1e-4 m; rounding of inputs and outputs adds up to ~0.15 N and 1e-4 m
    assert df < 0.15 and dr < 1.0e-4


def test_p2m7_needs_the_supplement(full):
    # Table B.6 as printed leaves 13 muscles unassigned: the loader refuses rather than guessing
    from neckstrength.io import DataValidationError
    with pytest.raises(DataValidationError, match="is in no group"):
        named_model(full, "p2m7", THESIS, grouping_supplements=False)


def test_variant_shapes(full):
    from neckstrength.model.reduction import reduce_model
    for kin, n, d in [("s7", 21, 6), ("s3", 9, 6), ("s2", 6, 6), ("p7", 7, 3), ("p3", 3, 3), ("p2", 2, 3)]:
        m = reduce_model(full, kin, "independent", THESIS)
        assert m.moment_arms.shape == (n, 96 if kin.startswith("s") else 48)
        assert m.JT.shape == (n, d)
    # the thesis reports 21 pairs (m = 42) for sagittal+axial and 12 pairs (m = 24) for sagittal grouping;
    # our sign-signature rule is printed beside those numbers in docs/model.md; here: pairs, left/right split
    for g in ("sagittal", "sagittal_axial"):
        m = reduce_model(full, "s3", g, THESIS)
        assert m.m % 2 == 0 and np.allclose(m.S.sum(axis=1), 1.0)
