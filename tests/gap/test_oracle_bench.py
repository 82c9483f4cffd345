"""benchmarks/bench_gap_oracle.py: the Bayes oracle that knows the strengths (issue 32)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy import stats


CONFIG = str(Path(__file__).resolve().parents[2] / "config" / "config.yaml")


@pytest.fixture(scope="module")
def oracle_mod():
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_gap_oracle.py"
    spec = importlib.util.spec_from_file_location("bench_gap_oracle", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_gaussian_and_grid_helpers(oracle_mod):
    rng = np.random.default_rng(3)
    A = rng.normal(size=(5, 5))
    cov = A @ A.T + np.eye(5)
    y, mu = rng.normal(size=5), rng.normal(size=(3, 5))
    from neckstrength.gap.evidence import gaussian_logpdf

    got = gaussian_logpdf(y, mu, cov)
    want = [stats.multivariate_normal.logpdf(y, m, cov) for m in mu]
    assert np.allclose(got, want)
    g = oracle_mod._grid(0.3, 0.7, 4, True)
    assert np.allclose(g, [-0.35, -0.45, -0.55, -0.65, 0.35, 0.45, 0.55, 0.65])
    s = oracle_mod._sphere(50, False)
    assert np.allclose(np.linalg.norm(s, axis=1), 1) and abs(s[:, 2].mean()) < 0.05


def test_oracle_runs_on_the_user_design_and_reports_posteriors(oracle_mod, tmp_path):
    """Three cases of the user benchmark's design (small draw counts): a row per case and strength SD, posteriors
    that sum to one, the cases' truths as the user benchmark names them, and an OUT that is not overwritten."""
    out = oracle_mod.main(["--config", CONFIG, "--out", str(tmp_path), "--limit", "3", "--directions", "4",
                           "--element-draws", "30",
                           "--strength-sd", "0,0.3"])
    rows = out["rows"]
    assert len(rows) == 6 and set(rows.strength_sd) == {0.0, 0.3}
    post = rows[[c for c in rows if c.startswith("post_")]].to_numpy()
    assert np.allclose(post.sum(axis=1), 1.0)
    assert list(rows.case.unique()) == ["u001", "u002", "u003"]
    assert rows.truth.iloc[0] == "none"
    # a known-strengths oracle names the base-model control's truth, whose forces are the base model's plus noise
    known = rows[(rows.case == "u001") & (rows.strength_sd == 0)].iloc[0]
    assert known.map_target == "none"
    assert (tmp_path / "oracle_scores.csv").exists()
    with pytest.raises(SystemExit, match="--force"):
        oracle_mod.main(["--config", CONFIG, "--out", str(tmp_path), "--limit", "1"])


def test_plug_in_fit_matches_the_forces_at_least_as_well_as_the_truth(oracle_mod):
    """``--plug-in``'s base-model fit: on a base-model control (forces of the base model plus noise) its residual is
    no larger than that of the true strengths (it is the most probable fit under a broad prior), and its forces are
    the base model's."""
    from neckstrength.gap.truths import CaseSettings, generate_truth_cases
    from neckstrength.seeds import derive_rng

    cs = CaseSettings(replicates=15, controls=30, rich_controls=10)
    oracle_mod._init(CONFIG, "s3m24", cs, (1,), 4, 30)
    orc = oracle_mod._W["oracles"][1]
    case = generate_truth_cases(orc.setup, cs, derive_rng(oracle_mod._W["seed"], "gap-users/s3m24"), limit=1)[0]
    assert case.truth == "none"
    from neckstrength.gap.evidence import largest_of_normals

    y = np.log(case.forces) - largest_of_normals(3)[0] * case.noise
    fit = orc.fit_base(np.log(case.forces), case.noise)

    def rms(f):
        return float(np.sqrt(np.mean((y - np.log(orc.fc.base(f))) ** 2)))

    assert rms(fit) <= rms(case.strengths) + 1e-3
    assert rms(fit) < 2 * case.noise


def test_diagnosis_families_name_the_first_cases(oracle_mod, tmp_path):
    """``--families diagnosis --plug-in --noise measured``: the diagnosis's own candidates, its aiming-scatter model
    and its element null, fitted strengths and the trials' measured noise. Posteriors sum to one over the
    diagnosis's families; the first three cases of the design (a base-model control, an aiming error of 8.8 deg,
    an asymmetry of 0.43) get their targets (each a 1-in-15 guess among the families)."""
    out = oracle_mod.main(["--config", CONFIG, "--out", str(tmp_path), "--limit", "3", "--element-draws", "40",
                           "--strength-sd", "0.3", "--families", "diagnosis", "--plug-in", "--noise", "measured"])
    rows = out["rows"]
    post = rows[[c for c in rows if c.startswith("post_")]]
    assert {"post_direction_scatter", "post_none_elements", "post_finer_groups"} <= set(post)
    assert np.allclose(post.to_numpy().sum(axis=1), 1.0)
    assert list(rows.truth) == ["none", "direction_error", "asymmetry"]
    assert list(rows.map_target) == ["none", "direction_scatter", "asymmetry"]
    assert rows.p_no_effect.iloc[0] > 0.5 and rows.p_no_effect.iloc[1:].max() < 0.01


def test_candidate_leave_one_out(tmp_path):
    """bench_gap_candidates.py: with every candidate it reproduces the stored decision; leaving out the truth's
    candidate makes the runner-up named (a misattribution) or nothing, and a control stays a control."""
    import pandas as pd

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_gap_candidates.py"
    spec = importlib.util.spec_from_file_location("bench_gap_candidates", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    # three cases: asymmetry truth (asymmetry far ahead, effort second), an effort truth whose evidence is weak,
    # a control; log evidences per explanation
    rows = pd.DataFrame({
        "case": ["a", "b", "c"], "target": ["asymmetry", "submaximal_effort", "none"], "detectable": [True] * 3,
        "strength_sd": 0.3, "fit_p_best_effect": [0.5, 0.5, 0.5],
        "ll_none": [0.0, 0.0, 0.0], "ll_none_elements": [0.0, 0.0, 0.0],
        "ll_asymmetry": [20.0, 0.0, -5.0], "ll_submaximal_effort": [10.0, 1.0, -5.0]})
    tab, mis = mod.leave_one_out(rows, 0.05, 0.001, 0.5)
    full = tab.set_index("left_out").loc["(none: every candidate)"]
    assert (full["named_correctly"], full["detectable"], full["false_alarms"]) == (1, 2, 0)
    no_asym = tab.set_index("left_out").loc["asymmetry"]
    assert no_asym["named_correctly"] == 0 and no_asym["fit_check_not_recomputed"] == 1
    m = mis.set_index("truth_candidate")
    assert m.loc["asymmetry", "named_another"] == 1 and m.loc["asymmetry", "instead"] == ["submaximal_effort"]
    assert m.loc["submaximal_effort", "named_another"] == 0
    rows.assign(strength_sd=0.3).to_csv(tmp_path / "rows.csv", index=False)
    out = mod.main(["--rows", str(tmp_path / "rows.csv")])
    assert int(out["table"].iloc[0]["named_correctly"]) == 1


def _bench(name):
    path = Path(__file__).resolve().parents[2] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_element_null_and_stability_scripts(tmp_path):
    """bench_gap_element_null.py: on the shipped design's 96-element controls the element null fits far better than
    "no effect" (mean chi-square; the table is written); bench_gap_evidence_stability.py: with the base fit held,
    two streams name the same effect for a base-model control, and every stream's row is there."""
    en = _bench("bench_gap_element_null").main(["--config", CONFIG, "--truths", "rich96",
                                                "--out", str(tmp_path / "en.csv")])
    assert len(en) == 10 and (tmp_path / "en.csv").exists()
    assert en["chi2_none_elements"].mean() < 0.5 * en["chi2_none"].mean()
    st = _bench("bench_gap_evidence_stability").main(["--config", CONFIG, "--cases", "u001", "--streams", "2",
                                                      "--fit-starts", "4"])
    assert len(st) == 4 and set(st["mode"]) == {"shipped", "base fit held"}
    held = st[st["mode"] == "base fit held"]
    assert held["named"].nunique() == 1 and held["log_strength_norm"].nunique() == 1
