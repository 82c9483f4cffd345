"""P(deficit) of a muscle group, the joint posterior with undo (clinician session), and the detection study."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from neckstrength.estimation.datasets import simulated_dataset
from neckstrength.sequential.algorithms import SequentialSettings, StrengthGrid, producible_truth
from neckstrength.sequential.deficit import DeficitDefinition, StudySettings, detection_summary, run_deficit_study
from neckstrength.sequential.joint import JointSettings
from neckstrength.sequential.joint_state import JointState

S3_NAMES = ["mf-R", "mf-L", "trap-R", "trap-L"]


def test_group_indices_ratio_and_weighted_probability():
    d = DeficitDefinition(group=("mf",), threshold=0.6)
    assert list(d.indices(S3_NAMES)) == [0, 1] and not d.applies(["TS-E", "TS-B"])
    base = np.array([100.0, 100.0, 300.0, 300.0])
    F = np.array([[50, 50, 300, 300], [70, 40, 1, 1], [100, 100, 10, 10], [10, 200, 1, 1]], float)
    assert np.allclose(d.ratio(F, base, S3_NAMES), [0.5, 0.55, 1.0, 1.05])
    w = np.array([0.1, 0.2, 0.3, 0.4])
    assert d.probability(F, w, base, S3_NAMES) == pytest.approx(0.3)       # rows 0 and 1 (summed sides)
    with pytest.raises(ValueError, match="threshold"):
        DeficitDefinition(threshold=1.2)


def test_marginal_probability_matches_monte_carlo_of_independent_pdfs():
    """The convolution of two per-muscle PDFs (thesis scheme: independent) against sampling from the same PDFs."""
    d = DeficitDefinition(group=("mf",), threshold=0.6)
    base = np.array([100.0, 100.0, 300.0, 300.0])
    grid = StrengthGrid.around(base, 0.3, 50, 4.0)
    c = grid.centres
    pdf = np.exp(-0.5 * ((c - 0.7 * base[:, None]) / (0.2 * base[:, None])) ** 2)
    pdf /= (pdf * grid.widths[:, None]).sum(axis=1, keepdims=True)
    p = d.probability_marginal(pdf, grid, base, S3_NAMES)
    rng = np.random.default_rng(0)
    n = 400_000
    x = sum(c[j][rng.choice(50, n, p=pdf[j] * grid.widths[j] / (pdf[j] * grid.widths[j]).sum())] for j in (0, 1))
    assert p == pytest.approx(float((x < 120.0).mean()), abs=0.01)
    assert 0.2 < p < 0.5                                   # mean 140 of threshold 120: a minority below
    low = np.zeros_like(pdf)
    low[:, 5] = 1.0 / grid.widths                          # all mass at 5/50 of the range: far below 60%
    assert d.probability_marginal(low, grid, base, S3_NAMES) == pytest.approx(1.0)


def test_detection_summary_counts_first_alarm_and_false_alarms():
    rows = []
    traj = {(0, "deficit"): [0.1, 0.5, 0.95, 0.97], (1, "deficit"): [0.1, 0.2, 0.3, 0.4],
            (2, "normal"): [0.1, 0.92, 0.5, 0.2], (3, "normal"): [0.1, 0.0, 0.0, 0.0]}
    for (i, kind), ps in traj.items():
        for t, p in enumerate(ps):
            rows.append({"participant": i, "kind": kind, "true_ratio": 0.4 if kind == "deficit" else 1.0,
                         "strategy": "joint_eig", "run": "joint_eig", "t": t, "p_deficit": p})
    per, summ = detection_summary(pd.DataFrame(rows), 0.9)
    assert per.set_index("participant")["t_detect"].fillna(-1).tolist() == [2, -1, 1, -1]
    s = summ.set_index("kind")
    assert s.loc["deficit", "share_reached"] == 0.5 and s.loc["normal", "false_alarm_rate"] == 0.5
    assert s.loc["deficit", "t_detect_q25"] == 2 and np.isinf(s.loc["deficit", "t_detect_q75"])


def _joint_state(p2m7_full_config, seed=3):
    _, model, directions = p2m7_full_config
    data = simulated_dataset(model, directions, "x", 0.9 * model.strengths)
    st = JointState(model, data.directions, data.U, data.force_scale, model.strengths,
                    JointSettings(n_candidates=800, resample_ess=0.5), np.random.default_rng(seed),
                    deficit=DeficitDefinition(group=("TS-E",)))
    return st, data


def test_joint_state_undo_restores_and_equals_replay(p2m7_full_config):
    """push A, push B, undo, push C == push A, push C (candidates, weights, random state): the session's undo and
    resume give the same numbers; a rejected measurement changes nothing."""
    a, data = _joint_state(p2m7_full_config)
    f = dict(zip(data.directions, data.forces))
    for d in ("back", "forehead"):
        a.push(a.likelihood(d, 1.3 * f[d]))                # 30% off: forces a resample (tempering)
    assert a.post.n_resamples > 0
    a.undo()
    a.push(a.likelihood("chinFront", f["chinFront"]))
    b, _ = _joint_state(p2m7_full_config)
    for d, x in (("back", 1.3 * f["back"]), ("chinFront", f["chinFront"])):
        b.push(b.likelihood(d, x))
    assert a.tested == b.tested == ["back", "chinFront"]
    assert np.array_equal(a.post.F, b.post.F) and np.allclose(a.post.weights(), b.post.weights())
    assert [h["p_deficit"] for h in a.history] == pytest.approx([h["p_deficit"] for h in b.history])
    assert np.array_equal(a.post.ancestor, b.post.ancestor)
    assert [h["p_deficit_se"] for h in a.history] == pytest.approx([h["p_deficit_se"] for h in b.history])
    assert all(0 <= h["p_deficit_se"] <= 0.5 for h in a.history)
    with pytest.raises(ValueError, match="already been tested"):
        a.likelihood("back", 100.0)
    with pytest.raises(ValueError, match="positive"):
        a.likelihood("backLow", -1.0)
    p = a.propose(np.random.default_rng(0))
    t = p.table()
    assert set(t["direction"]) == set(a.remaining) and t.loc[t["selected"], "direction"].item() == p.choice
    assert p.choice == t.loc[t["score"].idxmax(), "direction"]


def test_deficit_study_runs_every_strategy_with_fixed_seeds(p2m7_full_config):
    _, model, directions = p2m7_full_config
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.seeds import derive_rng

    d, U = model_directions_table(model, directions)
    study = StudySettings(n_deficit=1, n_normal=1, n_max=3, strategies=("joint_eig", "random", "thesis",
                                                                        "joint_eig+emg", "joint_eig+emg+deep"),
                          emg_groups=("TS-B",))
    args = (model, list(d["name"]), U, d["force_scale"].to_numpy(float), model.strengths,
            DeficitDefinition(group=("TS-E",)), study, JointSettings(n_candidates=300),
            SequentialSettings(n_candidates=2000, n_sim=10))
    df = run_deficit_study(*args, lambda w, i: derive_rng(7, w, i))
    assert len(df) == 2 * 5 * 4 and df["p_deficit"].between(0, 1).all()
    truth = df.groupby("participant")[["kind", "true_ratio"]].first()
    assert 0.25 <= truth.loc[0, "true_ratio"] <= 0.5 and truth.loc[1, "kind"] == "normal"
    assert 0.8 <= truth.loc[1, "true_ratio"] <= 1.2
    runs = df[df["t"] > 0].groupby("run")["direction"]
    assert all(g.groupby(df.loc[g.index, "participant"]).nunique().eq(3).all() for _, g in runs)
    again = run_deficit_study(*args, lambda w, i: derive_rng(7, w, i), first=1)      # resume from participant 1
    assert np.allclose(again["p_deficit"].to_numpy(), df[df["participant"] == 1]["p_deficit"].to_numpy())


def test_producible_truth_returns_the_first_all_optimal_draw_and_names_the_participant_when_none_is():
    from neckstrength.wrench import STATUS_CODES
    code = {v: k for k, v in STATUS_CODES.items()}
    draws = iter([("a", np.array([code["optimal"], code["infeasible"]])),
                  ("b", np.array([code["optimal"], code["optimal"]])),
                  ("c", np.array([code["optimal"], code["optimal"]]))])
    assert producible_truth(lambda: next(draws), "p")[0] == "b"
    with pytest.raises(RuntimeError, match="participant 7: no producible truth in 3 draws"):
        producible_truth(lambda: ("x", np.array([code["zero"]])), "participant 7", tries=3)


def test_surface_strategy_chooses_among_more_directions_and_leaves_the_others_unchanged(p2m7_full_config):
    """'joint_eig+surface' may pick head-surface points (here the s3m24 grid of the CI config, all on the
    cranial ellipsoid); adding the strategy does not change the other strategies' numbers (its noise is drawn after
    theirs); without the surface directions the strategy is refused."""
    from neckstrength.config import full_model_from_config, head_from_config, model_from_config
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.pipeline.clinician import surface_directions
    from neckstrength.seeds import derive_rng

    cfg, _, directions = p2m7_full_config
    model = model_from_config(full_model_from_config(cfg), cfg, "s3m24")
    d, U = model_directions_table(model, directions)
    base = {"n_deficit": 1, "n_normal": 0, "n_max": 3, "surface_azimuth_step_deg": 60.0,
            "surface_elevation_deg": (0.0, 30.0)}
    with_surface = StudySettings(strategies=("joint_eig", "joint_eig+surface"), **base)
    names, Us, fss = surface_directions(model, head_from_config(cfg), with_surface)
    assert len(names) == 11 and Us.shape == (11, U.shape[1]) and np.all(fss > 0)     # 12 grid points, 1 on the face
    assert all(n.startswith("az") for n in names)
    args = (model, list(d["name"]), U, d["force_scale"].to_numpy(float), model.strengths,
            DeficitDefinition(group=("mf",)))
    def rng(w, i):
        return derive_rng(11, w, i)

    js = JointSettings(n_candidates=300)
    df = run_deficit_study(*args, with_surface, js, None, rng, surface=(names, Us, fss))
    only = run_deficit_study(*args, StudySettings(strategies=("joint_eig",), **base), js, None, rng)
    a = df[df["strategy"] == "joint_eig"].reset_index(drop=True)
    assert a["direction"].tolist() == only["direction"].tolist()
    np.testing.assert_allclose(a["p_deficit"], only["p_deficit"], rtol=1e-9, atol=1e-12)
    surf = df[(df["strategy"] == "joint_eig+surface") & (df["t"] > 0)]
    assert len(surf) == 3 and set(surf["direction"]) <= set(d["name"]) | set(names)
    with pytest.raises(ValueError, match="surface directions"):
        run_deficit_study(*args, with_surface, js, None, rng)
