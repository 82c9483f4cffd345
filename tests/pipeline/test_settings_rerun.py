"""A changed setting reruns exactly the jobs that read it (and their dependents), nothing else.

Every rule declares the config settings it reads as ``params: settings=settings(...)``; its script hands them to
the package as a :class:`neckstrength.config.Settings` view that refuses undeclared keys. Here a dry run after
the reduced pipeline (session fixture) with one setting changed in a copy of the CI config lists the jobs
Snakemake would rerun.
"""

import re
import subprocess
import sys

import pytest
import yaml

from neckstrength.config import Settings, UndeclaredSettingError, select_settings, settings_view

SNAKEMAKE = [sys.executable, "-m", "snakemake"]


def run_cmd(cmd, cwd, timeout=300):
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)


def scheduled_rules(workdir, config_path, run_cmd) -> dict[str, int]:
    r = run_cmd(SNAKEMAKE + ["-n", "--configfile", str(config_path)], workdir)
    assert r.returncode == 0, r.stdout + r.stderr
    out = r.stdout + r.stderr
    if "Nothing to be done" in out:
        return {}
    stats = out.split("Job stats:", 1)[1]
    return {m.group(1): int(m.group(2)) for m in re.finditer(r"^(\w+)\s+(\d+)\s*$", stats, flags=re.M)
            if m.group(1) not in ("job", "total", "all")}


def changed_config(workdir, tmp_path, dotted: str, value):
    cfg = yaml.safe_load((workdir / "config" / "config.ci.yaml").read_text())
    node = cfg
    *parents, leaf = dotted.split(".")
    for p in parents:
        node = node[p]
    assert node[leaf] != value
    node[leaf] = value
    path = tmp_path / "changed.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


@pytest.fixture(scope="module")
def done(repo_copy, ci_pipeline):
    assert ci_pipeline.returncode == 0, ci_pipeline.stdout + ci_pipeline.stderr
    return repo_copy


def test_unchanged_config_reruns_nothing(done, tmp_path):
    assert scheduled_rules(done, done / "config" / "config.ci.yaml", run_cmd) == {}


def test_chapter5_epsilon_reruns_its_jobs_only(done, tmp_path):
    rules = scheduled_rules(done, changed_config(done, tmp_path, "chapter5.epsilon", 2.5), run_cmd)
    # the jobs that read chapter5.epsilon (Eq. 5.5), and what depends on them
    for r in ("chapter5_estimate", "chapter5_smc", "chapter5_coverage", "chapter5_figures", "chapter5_table",
              "gap_diagnose", "gap_benchmark", "report_scorecard"):
        assert r in rules, (r, rules)
    assert rules["chapter5_estimate"] == 3        # norm, weak, S005 (config.ci.yaml)
    # nothing else: the model, Chapters 3, 4 and 6 do not read it
    assert not [r for r in rules if r.startswith(("model_", "chapter3_", "chapter4_", "chapter6_", "appendix_"))], rules


def test_chapter4_tolerance_reruns_claims_only(done, tmp_path):
    rules = scheduled_rules(done, changed_config(done, tmp_path, "chapter4.claim_tolerance_rel", 0.02), run_cmd)
    assert "chapter4_claims" in rules and "report_scorecard" in rules, rules
    assert not [r for r in rules if r.startswith(("model_", "chapter3_", "chapter5_", "chapter6_", "gap_",
                                                  "chapter4_surface", "chapter4_reference"))], rules


def test_gap_discriminate_reruns_the_diagnoses_only(done, tmp_path):
    # issue 17 item 5: the proposal of additional measurements is part of each diagnosis (report, csv)
    rules = scheduled_rules(done, changed_config(done, tmp_path, "gap.discriminate.measurements", 4), run_cmd)
    assert rules.get("gap_diagnose") == 2, rules          # S003, S005 (config.ci.yaml)
    assert "gap_benchmark" not in rules and not [r for r in rules if r.startswith(("model_", "chapter"))], rules


def test_settings_view_refuses_undeclared_keys():
    cfg = {"seed": 1, "chapter5": {"epsilon": 3.0, "q": 90.0, "settings": {"p2m7": {"sigma0": 0.3}}}}
    v = settings_view(select_settings(cfg, ["seed", "chapter5.epsilon", "chapter5.settings.p2m7", "chapter5.x"]),
                      "r")
    assert isinstance(v, Settings)
    assert v["seed"] == 1 and v["chapter5"]["epsilon"] == 3.0
    assert v["chapter5"]["settings"]["p2m7"]["sigma0"] == 0.3
    assert v["chapter5"].get("x", "default") == "default"       # declared, not set: .get works
    with pytest.raises(UndeclaredSettingError, match="chapter5.q"):
        v["chapter5"]["q"]
    with pytest.raises(UndeclaredSettingError):
        v["chapter5"].get("q", 1.0)                             # .get does not hide an undeclared read
    with pytest.raises(UndeclaredSettingError):
        dict(v["chapter5"])                                     # iterating a partly declared section
    assert v["chapter5"]["settings"]["p2m7"].to_dict() == {"sigma0": 0.3}
