"""Settings as types (issue 33 item 2): only ``config.py`` and ``pipeline/`` read the config dict; everything else
receives frozen dataclasses that ``config.py`` builds. The schema's defaults equal the dataclasses' defaults, so a
setting left out of a config means the same thing wherever it is read."""

import ast
import functools
from dataclasses import MISSING, fields
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "src" / "neckstrength"
SCHEMA = ROOT / "workflow" / "schemas" / "config.schema.yaml"

#: names a config dict (or a section of it) goes by
CONFIG_NAMES = {"cfg", "config", "conf", "configuration"}

def _config_name(node: ast.AST) -> str | None:
    if isinstance(node, ast.Name) and node.id in CONFIG_NAMES:
        return node.id
    if isinstance(node, ast.Attribute) and node.attr in CONFIG_NAMES:
        return node.attr
    return None


def config_reads(source: str, filename: str = "<source>") -> list[str]:
    """``line: text`` of every ``cfg[...]``, ``config.get(...)``, ``x.config[...]`` ... in ``source``."""
    out = []
    for node in ast.walk(ast.parse(source, filename)):
        name = None
        if isinstance(node, ast.Subscript):
            name = _config_name(node.value)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in (
                "get", "setdefault", "pop", "items", "keys", "values", "update"):
            name = _config_name(node.func.value)
        if name:
            out.append(f"{node.lineno}: {ast.get_source_segment(source, node)}")
    return out


def _offenders() -> dict[str, list[str]]:
    found = {}
    for p in sorted(PKG.rglob("*.py")):
        rel = p.relative_to(PKG).as_posix()
        if rel == "config.py" or rel.startswith("pipeline/"):
            continue
        reads = config_reads(p.read_text(), str(p))
        if reads:
            found[rel] = reads
    return found


def test_only_config_and_pipeline_read_the_config_dict():
    """A subscript or a dict method (get, items, ...) on a name (or attribute) called cfg / config / conf outside
    config.py and pipeline/ fails; a module receives the typed settings that config.py builds instead."""
    assert _offenders() == {}, "outside config.py and pipeline/, these read the config dict: build typed settings " \
                               "in config.py"


def test_the_detector_finds_config_reads():
    src = ("def f(cfg, ctx, config, other):\n"
           "    a = cfg['seed']\n"
           "    b = config.get('chapter5', {}).get('eps_D')\n"
           "    c = ctx.config['data']['thesis_dir']\n"
           "    d = other['seed'] + other.get('x', 1)\n"
           "    return config_path(cfg)\n")
    got = config_reads(src)
    assert sorted(g.split(":")[0] for g in got) == ["2", "3", "4"]
    assert config_reads("x = settings.seed\n") == []


# --- the schema's defaults are the dataclasses' defaults ----------------------------------------------------------

@functools.lru_cache(maxsize=1)
def _schema() -> dict:
    return yaml.safe_load(SCHEMA.read_text())


def _schema_node(schema: dict, dotted: str) -> dict:
    node = schema
    for part in [p for p in dotted.split(".") if p]:
        node = node["properties"][part]
    return node


def _norm(v):
    if isinstance(v, (list, tuple)):
        return tuple(_norm(x) for x in v)
    if isinstance(v, dict):
        return {k: _norm(x) for k, x in v.items()}
    return v


def _noise_prior(node):      # {low, central, high} -> (low, central, high)
    p = node["properties"]
    return tuple(p[k]["default"] for k in ("low", "central", "high"))


def _bounds(node):           # {name: [lo, hi]} -> ((name, lo, hi), ...)
    return tuple((k, float(v[0]), float(v[1])) for k, v in node["default"].items())


def _rows():
    """(schema section, dataclass, {field: key under the section (dotted) or (key, converter)}, fields not compared
    with the reason). A field whose name the section lists is compared unless excluded; mapped fields are compared
    under their key."""
    from neckstrength.abc.algorithm4 import ABCSettings
    from neckstrength.abc.smc import SMCSettings
    from neckstrength.estimate import EstimateSettings
    from neckstrength.estimation.datasets import DatasetSettings
    from neckstrength.gap.benchmark import BenchmarkSettings
    from neckstrength.gap.discriminate import DiscriminateSettings
    from neckstrength.gap.engine import CalibrationSettings, DiagnosisSettings
    from neckstrength.gap.fit import FitSettings
    from neckstrength.gap.evidence import EvidenceSettings
    from neckstrength.gap.protocols import ProtocolSettings
    from neckstrength.identifiability.profile import ProfileSettings
    from neckstrength.identifiability.study import StudySettings
    from neckstrength.mfi.synthetic import CohortSpec
    from neckstrength.report.scorecard.settings import ScorecardSettings
    from neckstrength.reruns.runs import RerunSettings
    from neckstrength.sequential.algorithms import SequentialSettings
    from neckstrength.sequential.cohort import CohortSettings
    from neckstrength.sequential.decision import DecisionSettings
    from neckstrength.sequential.decision_study import DecisionStudySettings
    from neckstrength.sequential.deficit import DeficitDefinition
    from neckstrength.sequential.joint import JointSettings
    from neckstrength.session.settings import SessionSettings
    from neckstrength.trials import ImportSettings

    per_model = "a map per model in the schema"
    sub = "a dataclass of its own row"
    return [
        ("chapter5", ABCSettings, {"sigma_min": ("sigma_clip", lambda n: n["default"][0]),
                                   "sigma_max": ("sigma_clip", lambda n: n["default"][1])}, {}),
        ("chapter5.smc", SMCSettings, {"budget": "max_budget"}, {}),
        ("chapter5", DatasetSettings, {}, {"emg_groups": per_model}),
        ("chapter6", DatasetSettings, {}, {"emg_groups": per_model}),
        ("chapter6", SequentialSettings, {}, {}),
        ("chapter6.joint", JointSettings, {}, {}),
        ("chapter6", JointSettings, {}, {"n_candidates": "chapter6.joint's", "n_sim": "chapter6.joint's"}),
        ("", EstimateSettings, {"criteria": "chapter6.joint.criteria", "use_emg": "chapter6.joint.use_emg"}, {}),
        ("gap", DiagnosisSettings, {}, {"fit": sub, "calibration": sub, "protocols": sub, "evidence": sub}),
        ("gap.fit", FitSettings, {}, {}),
        ("gap.calibration", CalibrationSettings, {"noise_prior": ("noise_prior", _noise_prior)}, {}),
        ("gap.discriminate", DiscriminateSettings, {}, {}),
        ("gap.discriminate.pool", DiscriminateSettings, {}, {}),
        ("gap.protocols", ProtocolSettings, {}, {}),
        ("gap.evidence", EvidenceSettings, {"n_grid": "grid_points"}, {}),
        ("gap.benchmark", BenchmarkSettings, {}, {}),
        ("clinician.decision", DecisionSettings, {}, {}),
        ("clinician.deficit", DeficitDefinition, {}, {}),
        ("clinician.decision_study", CohortSettings, {}, {}),
        ("clinician.decision_study", DecisionStudySettings,
         {"patients_per_kind": ("patients_per_kind", lambda n: tuple(n["default"].items()))}, {}),
        ("", SessionSettings, {"gain_frac": "chapter6.stop.gain_frac", "postures": "postures.postures",
                               "force_length": "postures.force_length", "model_dir": "data.model_dir",
                               "test_point_spec": "geometry.test_point_spec"}, {}),
        ("identifiability", ProfileSettings, {"bounds": ("bounds", _bounds)}, {}),
        ("identifiability", StudySettings, {}, {"groups": per_model, "deficit_group": per_model}),
        ("reruns", RerunSettings, {}, {}),
        ("reruns.chapter5", RerunSettings, {}, {}),
        ("chapter3.synthetic", CohortSpec, {}, {}),
        ("chapter3", CohortSpec, {"rater": "reliability.rater", "second_rater": "reliability.second_rater",
                                  "age_per_year": "synthetic.covariate_effects.age_per_year",
                                  "bmi_per_unit": "synthetic.covariate_effects.bmi_per_unit",
                                  "female": "synthetic.covariate_effects.female",
                                  "level_slope": "synthetic.random_effects.level_slope",
                                  "quartile_slope": "synthetic.random_effects.quartile_slope",
                                  "side_share": "synthetic.random_effects.side_share"}, {}),
        ("trials.settings", ImportSettings, {}, {}),
        ("", ScorecardSettings, {"thesis_dir": "data.thesis_dir", "model_dir": "data.model_dir",
                                 "unprinted_strengths": "model.unprinted_strengths",
                                 "grouping_supplements": "model.grouping_supplements",
                                 "apply_b1_errata": "model.apply_b1_errata",
                                 "mixed_model_alpha": "chapter3.mixed_model.alpha", "eps_D": "chapter5.eps_D",
                                 "sigma_clip": "chapter5.sigma_clip",
                                 "claim_tolerance_rel": "chapter4.claim_tolerance_rel",
                                 "anterior_max_azimuth_deg": "chapter4.anterior_max_azimuth_deg"}, {}),
    ]


def _default(f):
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:
        return f.default_factory()
    return MISSING


def compared_defaults(schema: dict, section: str, cls, mapping: dict, excluded: dict) -> list[tuple]:
    """(field, dataclass default, schema default) of every field of ``cls`` the schema section gives a default."""
    props = _schema_node(schema, section).get("properties", {})
    out = []
    for f in fields(cls):
        if f.name in excluded:
            continue
        key, conv = mapping.get(f.name, f.name), None
        if isinstance(key, tuple):
            key, conv = key
        try:
            node = _schema_node({"properties": props}, key)
        except KeyError:
            assert f.name not in mapping, f"{section}: no setting `{key}` for {cls.__name__}.{f.name}"
            continue
        if _default(f) is MISSING or conv is None and "default" not in node:
            continue
        want = conv(node) if conv else node["default"]
        out.append((f.name, _norm(_default(f)), _norm(want)))
    return out


ROW_IDS = ["chapter5:ABC", "chapter5.smc:SMC", "chapter5:Dataset", "chapter6:Dataset", "chapter6:Sequential",
           "chapter6.joint:Joint", "chapter6:Joint", "estimate", "gap:Diagnosis", "gap.fit", "gap.calibration",
           "gap.discriminate", "gap.discriminate.pool", "gap.protocols", "gap.evidence", "gap.benchmark",
           "clinician.decision", "clinician.deficit", "decision_study:Cohort", "decision_study:Study", "session",
           "identifiability:Profile", "identifiability:Study", "reruns", "reruns.chapter5", "chapter3.synthetic",
           "chapter3", "trials.settings", "scorecard"]


@pytest.mark.parametrize("row", range(len(ROW_IDS)), ids=ROW_IDS)
def test_schema_defaults_are_the_dataclass_defaults(row):
    section, cls, mapping, excluded = _rows()[row]
    got = compared_defaults(_schema(), section, cls, mapping, excluded)
    assert got, f"{section}: no default of {cls.__name__} compared (wrong section?)"
    bad = [f"{section}.{mapping.get(n, n) if not isinstance(mapping.get(n), tuple) else mapping[n][0]} "
           f"(schema {s!r}) != {cls.__name__}.{n} = {d!r}" for n, d, s in got if d != s]
    assert bad == []


def test_every_settings_class_config_builds_is_compared():
    """Every dataclass with defaults that config.py constructs (by name) has a row above."""
    import dataclasses
    import importlib

    import neckstrength.config as config

    tree = ast.parse(Path(config.__file__).read_text())
    built = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id[:1].isupper():
            built.add(node.func.id)
        if isinstance(node, ast.Attribute) and node.attr == "from_mapping" and isinstance(node.value, ast.Name):
            built.add(node.value.id)
    imported = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("neckstrength"):
            for a in node.names:
                imported[a.asname or a.name] = node.module
    classes = set()
    for name in built & set(imported):
        obj = getattr(importlib.import_module(imported[name]), name)
        if dataclasses.is_dataclass(obj) and any(_default(f) is not MISSING for f in fields(obj)):
            classes.add(obj)
    # inputs, not settings; DiagnoseSettings only groups DiagnosisSettings and DiscriminateSettings (compared above)
    # with the worker count (the rule's threads, not a config setting)
    not_settings = {"GapContext", "BlindData", "HeadEllipsoid", "DecisionCalibration", "DiagnoseInputs",
                    "DiagnoseSettings"}
    covered = {r[1] for r in _rows()}
    missing = {c.__name__ for c in classes if c not in covered and c.__name__ not in not_settings}
    assert missing == set(), "config.py builds these settings: add a row to _rows()"
    assert len(classes) >= 15


def test_the_defaults_check_finds_a_mismatch():
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class S:
        a: int = 1
        b: float = 0.5
        c: str = "x"

    schema = {"properties": {"sec": {"properties": {"a": {"default": 1}, "b": {"default": 0.25}, "c": {}}}}}
    assert compared_defaults(schema, "sec", S, {}, {}) == [("a", 1, 1), ("b", 0.5, 0.25)]
