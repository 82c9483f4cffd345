"""The Snakemake workflow: lint clean, SLURM-profile dry run, reduced config end to end.

The reduced run happens in a temporary copy of the repository so that it never
touches a user's results/.
"""

import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[2]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]


def run(cmd, cwd, timeout=900):
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def workdir(repo_copy):
    # the session-wide copy (tests/conftest.py), shared with tests/report/test_report.py
    return repo_copy


def test_lint_clean(workdir):
    r = run(SNAKEMAKE + ["--lint"], workdir)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Congratulations, your workflow is in a good condition" in r.stdout + r.stderr


def test_slurm_profile_dry_run(workdir):
    pytest.importorskip("snakemake_executor_plugin_slurm")
    r = run(SNAKEMAKE + ["-n", "--forceall", "--workflow-profile", "workflow/profiles/slurm",
                         "--configfile", "config/config.ci.yaml"], workdir)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "appendix_a4" in r.stdout + r.stderr


def test_full_config_dry_run_lists_all_models(workdir):
    r = run(SNAKEMAKE + ["-n", "--quiet", "rules"], workdir)
    assert r.returncode == 0, r.stdout + r.stderr
    out = r.stdout + r.stderr
    # 6 kinematic x 4 muscle variants minus 3 planar sagittal_axial = 21 variants + 3 named models
    assert "model_reduce" in out


def test_reduced_pipeline_end_to_end(workdir, ci_pipeline):
    r = ci_pipeline  # snakemake -c2 --configfile config/config.ci.yaml, run once per session (conftest.py)
    assert r.returncode == 0, r.stdout + r.stderr
    res = workdir / "results"
    for f in ("model/full_model.csv", "model/momentarm_vs_B1.csv", "geometry/directions.csv",
              "model/s3m24/parameters.csv", "model/p2m7/parameters_vs_thesis.csv",
              "model/s3m24/parameters_vs_thesis.csv", "strength/s3m24/baseline.csv",
              "appendix_a/table_A4.csv", "appendix_a/fig_A4_radar.png"):
        assert (res / f).exists(), f
    assert (res / "appendix_a/fig_A4_radar.png").stat().st_size > 20000
    base = pd.read_csv(res / "strength/s3m24/baseline.csv", comment="#")
    assert len(base) == 25 and (base["force_N"] > 0).all()
    p2 = pd.read_csv(res / "strength/p2m7/baseline.csv", comment="#")
    assert len(p2) == 7
    a4 = pd.read_csv(res / "appendix_a/table_A4.csv", comment="#")
    # Eq. 5.3: the scaled model matches the measurement exactly in the bootstrap direction
    back = a4[a4.direction == "back"]
    assert (back["difference_N"].abs() < 1e-6 * back["measured_N"]).all()
    cmp = pd.read_csv(res / "model/s3m24/parameters_vs_thesis.csv", comment="#")
    sub = cmp[(cmp.group == "subocc-R") & (cmp.quantity == "strength_N")]
    assert abs(float(sub["ours"].iloc[0]) - 100.5) < 0.11
    # beyond-the-thesis Chapter 6: every criterion judged on the joint posterior; same prior at t = 0
    crit = pd.read_csv(res / "chapter6/criteria/p2m7/summary.csv", comment="#")
    assert set(crit["criterion"]) == {"joint_eig", "marginal_entropy", "random", "thesis (Alg. 7-9)"}
    t0 = crit[crit.t == 0]
    assert t0["entropy"].nunique() == 1 and (t0["d_entropy_vs_random"].abs() < 1e-9).all()
    assert (crit.groupby("criterion")["entropy"].apply(lambda e: e.iloc[-1] < e.iloc[0])).all()
    joint = pd.read_csv(res / "chapter6/p2m7/Sim/joint_estimate.csv", comment="#")
    assert len(joint) == 2 * 7 and joint["f_c"].gt(0).all() and joint["f_true"].notna().all()
    # a second run has nothing to do (outputs complete and up to date)
    r2 = run(SNAKEMAKE + ["-c2", "--configfile", "config/config.ci.yaml", "-n"], workdir)
    assert "Nothing to be done" in r2.stdout + r2.stderr


def test_bad_measurement_file_stops_before_writing(workdir, tmp_path, ci_pipeline):
    bad = workdir / "data" / "bad_A2.csv"
    bad.write_text("direction,S003,S005\nforehead,102.7,x\n")
    (workdir / "config" / "bad.yaml").write_text(
        (workdir / "config" / "config.ci.yaml").read_text().replace(
            "data/thesis/table_A2_max_force.csv", "data/bad_A2.csv"))
    target = workdir / "results" / "appendix_a" / "table_A4.csv"
    before = target.read_bytes() if target.exists() else None
    r = run(SNAKEMAKE + ["results/appendix_a/table_A4.csv", "-c1", "--configfile", "config/bad.yaml"], workdir)
    assert r.returncode != 0
    assert "bad_A2.csv, row 1 (line 2), field 'S005': 'x' is not a number" in r.stdout + r.stderr
    # validation happens at start-up: no job ran, the earlier output is untouched
    assert before is not None and target.read_bytes() == before
