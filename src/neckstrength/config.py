"""The configuration: the only reader of the config dict
=======================================================

- :func:`load_config` loads and validates a YAML config (defaults from ``workflow/schemas/config.schema.yaml``).
- :func:`select_settings` / :class:`Settings`: the settings one pipeline rule declares (its ``params``), as a
  read-only view that refuses any undeclared key, so a rule cannot depend on a setting Snakemake does not see.
- :func:`seed_sequence` / :func:`derive_rng`: every random stream of the project, derived from the config ``seed`` and
  a stable text key (``numpy.random.SeedSequence([seed, crc32(key)])``).
- ``*_from_config`` and ``*_settings``: the science objects and typed settings (dataclasses) built from a config.
"""

from __future__ import annotations

import difflib
import json
from dataclasses import fields, replace
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np
import pandas as pd
import yaml

from neckstrength.abc.algorithm4 import ABCSettings
from neckstrength.abc.smc import SMCSettings
from neckstrength.estimation.datasets import (
    SIMULATED_DATASETS,
    Dataset,
    DatasetSettings,
    load_dataset,
    model_directions_table,
    participant_dataset,
)
from neckstrength.gap.benchmark import BenchmarkSettings
from neckstrength.gap.diagnose import BlindData, DiagnosisSettings
from neckstrength.gap.discriminate import DiscriminateSettings
from neckstrength.gap.effects import GapContext
from neckstrength.gap.engine import CalibrationSettings
from neckstrength.gap.fit import FitSettings
from neckstrength.gap.protocols import ProtocolSettings
from neckstrength.errors import ConfigError, DataValidationError, UndeclaredSettingError  # noqa: F401  (re-exported)
from neckstrength.io import read_activations
from neckstrength.model.full import FullModel, load_full_model
from neckstrength.model.geometry import (
    HeadEllipsoid,
    assign_planes,
    direction_table,
    read_point_spec,
    read_test_points,
    reconstruct_test_points,
)
from neckstrength.model.reduction import ReducedModel, named_model
from neckstrength.seeds import derive_rng, seed_sequence  # noqa: F401  (re-exported)
from neckstrength.sequential.algorithms import SequentialSettings
from neckstrength.sequential.joint import JointSettings


SCHEMA = Path(__file__).resolve().parents[2] / "workflow" / "schemas" / "config.schema.yaml"


def unknown_settings(cfg: Any, schema: Mapping, path: str = "") -> list[str]:
    """Every key of ``cfg`` the schema does not list, as "`a.b`: unknown setting; did you mean `c`?".

    An object whose schema lists ``properties`` accepts only those keys; one whose ``additionalProperties`` is a
    schema is a map (free keys, each value checked against that schema); one with neither is free. Array items
    and ``anyOf``/``oneOf`` branches are checked in turn (a value passes a choice when one object branch takes it).
    """
    if not isinstance(schema, Mapping):
        return []
    out: list[str] = []
    for comb in ("anyOf", "oneOf"):
        branches = [b for b in schema.get(comb, ()) if isinstance(b, Mapping)]
        if branches and isinstance(cfg, Mapping):
            per = [unknown_settings(cfg, b, path) for b in branches if "properties" in b
                   or "additionalProperties" in b or b.get("type") == "object"]
            if per and all(per):
                out += per[0]
    for b in schema.get("allOf", ()):
        out += unknown_settings(cfg, b, path)
    if isinstance(cfg, Mapping):
        props = schema.get("properties")
        extra = schema.get("additionalProperties")
        for key, value in cfg.items():
            where = f"{path}.{key}" if path else str(key)
            if props is not None and key in props:
                out += unknown_settings(value, props[key], where)
            elif isinstance(extra, Mapping):
                out += unknown_settings(value, extra, where)
            elif props is not None:
                close = difflib.get_close_matches(str(key), [str(k) for k in props], n=1)
                hint = f"did you mean `{close[0]}`?" if close else f"known: {', '.join(map(str, props))}"
                out.append(f"`{where}`: unknown setting; {hint}")
    elif isinstance(cfg, list) and isinstance(schema.get("items"), Mapping):
        for i, value in enumerate(cfg):
            out += unknown_settings(value, schema["items"], f"{path}[{i}]")
    return out


def validate_config(cfg: dict, schema_path: str | Path = SCHEMA, source: str | Path = "config") -> dict:
    """Check ``cfg`` against the workflow schema and fill in its defaults (in place); returns ``cfg``.

    Unknown keys (a typo of a setting silently has no effect otherwise) and values outside their domain raise
    :class:`ConfigError` naming the dotted setting. The CLI (:func:`load_config`) and the workflow
    (workflow/rules/common.smk) both call this.
    """
    import jsonschema
    from snakemake.exceptions import WorkflowError
    from snakemake.utils import validate

    if not isinstance(cfg, dict):
        raise ConfigError(source, [f"expected a mapping of settings, not {type(cfg).__name__}"])
    schema = yaml.safe_load(Path(schema_path).read_text())
    problems = unknown_settings(cfg, schema)
    if problems:
        raise ConfigError(source, problems)
    errors = sorted(jsonschema.Draft202012Validator(schema).iter_errors(cfg), key=lambda e: list(map(str, e.path)))
    if errors:
        raise ConfigError(source, [f"`{'.'.join(map(str, e.path)) or '(top level)'}`: {_short(e.message)}"
                                   for e in errors])
    try:
        validate(cfg, str(schema_path))
    except WorkflowError as exc:     # a value the defaults made invalid (should not happen with this schema)
        raise ConfigError(source, [_short(str(exc))]) from None
    return cfg


def _short(text: str, limit: int = 200) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[:limit] + " ..."


def load_config(path: str | Path) -> dict:
    """Load a YAML config and validate it (defaults filled) against the workflow schema (:func:`validate_config`).

    The schema is ``workflow/schemas/config.schema.yaml`` beside the config's folder, else the package's own.
    """
    path = Path(path)
    if path.is_dir():
        raise DataValidationError(path, "is a folder, not a config file")
    with open(path) as fh:
        try:
            cfg = yaml.safe_load(fh)
        except yaml.YAMLError as exc:
            raise DataValidationError(path, f"not valid YAML: {_short(exc)}") from None
    schema = path.resolve().parent.parent / "workflow" / "schemas" / "config.schema.yaml"
    if not schema.exists():
        schema = SCHEMA
    if schema.exists():
        validate_config(cfg, schema, path.name)
    return cfg


def measurement_participants(path: str | Path) -> list[str] | None:
    """The participant columns of a measurement table (None when the file does not exist yet)."""
    from neckstrength.io import read_measurements

    if not Path(path).is_file():
        return None
    return [str(c) for c in read_measurements(path).columns]


def check_config_datasets(cfg: Mapping, source: str | Path = "config") -> None:
    """Every data-set name the config lists exists: a participant column of the measurement table it reads, a
    simulated set ('norm', 'weak'; Chapter 6 also ``chapter6.simulated``); raises :class:`ConfigError` listing the
    known names. A measurement table that does not exist yet (written by a rule) is not checked here."""
    simulated = ["norm", "weak"]
    main = measurement_participants(cfg["data"]["measurements"])
    gap_table = cfg.get("gap", {}).get("measurements") or cfg["data"]["measurements"]
    gap = measurement_participants(gap_table)
    problems = []

    def check(key: str, names, table_cols, extra=()):
        if table_cols is None:
            return
        known = list(dict.fromkeys([*extra, *table_cols]))
        for name in names or ():
            if str(name) not in known:
                problems.append(f"`{key}`: data set '{name}' is not in the data (known: {', '.join(known)})")

    check("participants", cfg.get("participants"), main)
    c5 = cfg.get("chapter5", {})
    check("chapter5.datasets", c5.get("datasets"), main, simulated)
    check("chapter5.smc.datasets", c5.get("smc", {}).get("datasets"), main, simulated)
    c6 = cfg.get("chapter6", {})
    c6_sim = simulated + list(c6.get("simulated", {}) or {})
    check("chapter6.datasets", c6.get("datasets"), main, c6_sim)
    for model, names in (c6.get("model_datasets") or {}).items():
        check(f"chapter6.model_datasets.{model}", names, main, c6_sim)
    check("gap.datasets", cfg.get("gap", {}).get("datasets"), gap, simulated)
    if problems:
        raise ConfigError(source, problems)


class Settings(Mapping):
    """Read-only view of the config settings a rule declared (dotted keys; a key declares its whole subtree).

    Reading a declared key that the config does not set raises ``KeyError`` (so ``.get`` defaults work as with
    the config itself); reading an undeclared key raises :class:`UndeclaredSettingError`.
    """

    def __init__(self, values: Mapping, declared: Sequence[str], rule: str = "?", _prefix: str = ""):
        self._v, self._declared, self._rule, self._prefix = values, tuple(declared), rule, _prefix

    def _covered(self, path: str) -> bool:  # path itself or one of its ancestors is declared
        return any(path == d or path.startswith(d + ".") for d in self._declared)

    def _on_path(self, path: str) -> bool:  # an ancestor of a declared key
        return self._covered(path) or any(d.startswith(path + ".") for d in self._declared)

    def __getitem__(self, key: str) -> Any:
        path = f"{self._prefix}{key}"
        if not self._on_path(path):
            raise UndeclaredSettingError(
                f"rule {self._rule} reads config setting '{path}' but does not declare it in its params "
                f"(declared: {', '.join(self._declared) or 'none'})")
        v = self._v[key]
        if isinstance(v, Mapping):
            return Settings(v, self._declared, self._rule, path + ".")
        return v

    def __iter__(self) -> Iterator[str]:
        if self._prefix and not self._covered(self._prefix[:-1]):
            raise UndeclaredSettingError(f"rule {self._rule} iterates over config section '{self._prefix[:-1]}' "
                                         "but declares only some of its keys")
        return iter([k for k in self._v if self._on_path(f"{self._prefix}{k}")])

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def to_dict(self) -> dict:
        return {k: (v.to_dict() if isinstance(v, Settings) else v) for k, v in self.items()}


def plain(x: Any) -> Any:
    """A config value with every mapping (e.g. a :class:`Settings` view) turned into a plain dict, for JSON."""
    if isinstance(x, Mapping):
        return {k: plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    return x


def select_settings(config: Mapping, keys: Sequence[str]) -> dict:
    """``{'keys': [...], 'values': {...}}``: the declared dotted ``keys`` and the config's values under them.

    What a rule passes as ``params`` (Snakemake reruns a job when this changes) and its script turns into a
    :class:`Settings` view with :func:`settings_view`. Keys the config does not set are declared but absent.
    """
    values: dict = {}
    for key in keys:
        node, parts = config, key.split(".")
        for part in parts:
            if not isinstance(node, Mapping) or part not in node:
                break
            node = node[part]
        else:
            tgt = values
            for part in parts[:-1]:
                tgt = tgt.setdefault(part, {})
            tgt[parts[-1]] = node
    return {"keys": sorted(set(keys)), "values": _sorted(values)}


def _sorted(x: Any) -> Any:  # canonical order: reordering keys in a YAML file reruns nothing
    if isinstance(x, Mapping):
        return {k: _sorted(x[k]) for k in sorted(x, key=str)}
    if isinstance(x, list):
        return [_sorted(v) for v in x]
    return x


def settings_view(selected: Mapping, rule: str = "?") -> Settings:
    """The :class:`Settings` view of what :func:`select_settings` returned (a rule's ``params.settings``)."""
    return Settings(selected["values"], selected["keys"], rule)


def full_model_from_config(config: Mapping) -> FullModel:
    d, m = config["data"], config["model"]
    return load_full_model(d["model_dir"], d["thesis_dir"], m["moment_arm_source"], m["apply_b1_errata"],
                           m.get("unprinted_strengths", "b3_implied"))


def model_from_config(full: FullModel, config: Mapping, model_name: str) -> ReducedModel:
    m = config["model"]
    return named_model(full, model_name, config["data"]["thesis_dir"], m.get("grouping_supplements", True),
                       m.get("signature_tol_m", 1e-3))


def head_from_config(config: Mapping) -> HeadEllipsoid:
    h = config["geometry"]["head"]
    return HeadEllipsoid(tuple(h["centre"]), tuple(h["semi_axes"]))


def build_directions(config: Mapping) -> pd.DataFrame:
    g = config["geometry"]
    head = head_from_config(config)
    if g.get("test_points"):
        pts = read_test_points(g["test_points"])
        pts["method"] = "measured"
    else:
        pts = reconstruct_test_points(read_point_spec(g["test_point_spec"]), head)
    d = direction_table(pts, head)
    d = assign_planes(d, g["plane_bands"]["elevation_deg"], g["plane_bands"]["azimuth_deg"])
    sag = d["sagittal"].to_numpy()
    d["sagittal_index"] = 0
    d.loc[sag, "sagittal_index"] = np.arange(1, sag.sum() + 1)
    return d


def chapter4_factors(config: Mapping) -> list[float]:
    c = config["chapter4"]
    sweep = np.linspace(c["sweep"]["start"], c["sweep"]["stop"], int(c["sweep"]["num"]))
    return sorted(set(np.round(np.r_[c["factors"], sweep], 6).tolist()))


def cohort_spec(config: Mapping):
    """``chapter3.synthetic`` (with ``chapter3.reliability`` and ``loa_multiplier``) as
    :class:`neckstrength.mfi.synthetic.CohortSpec`, the SYNTHETIC cohort's design and generative assumptions."""
    from neckstrength.mfi.synthetic import CohortSpec

    c = config["chapter3"]
    s = c["synthetic"]
    cov, re, rel = s["covariate_effects"], s["random_effects"], c["reliability"]
    return CohortSpec(n_per_group=int(s["n_per_group"]),
                      reliability_participants=dict(s["reliability_participants"]),
                      age_per_year=float(cov["age_per_year"]), bmi_per_unit=float(cov["bmi_per_unit"]),
                      female=float(cov["female"]), level_slope=float(re["level_slope"]),
                      quartile_slope=float(re["quartile_slope"]), side_share=float(re["side_share"]),
                      intra_loa=tuple(s["intra_loa"]), inter_loa=tuple(s["inter_loa"]),
                      loa_multiplier=float(c["loa_multiplier"]), rater=str(rel["rater"]),
                      second_rater=str(rel["second_rater"]))


def abc_settings(config: Mapping, model_name: str) -> ABCSettings:
    c = config["chapter5"]
    per = c["settings"].get(model_name, {})
    return ABCSettings(sigma0=per.get("sigma0", 0.2), epsilon=c["epsilon"], q=c["q"], eps_D=c["eps_D"],
                       max_iter=per.get("max_iter", 20), sigma_min=c["sigma_clip"][0], sigma_max=c["sigma_clip"][1],
                       tie_sides=per.get("tie_sides", False), store_candidates=c.get("store_candidates", 3000))


def smc_settings(config: Mapping) -> SMCSettings:
    """``chapter5.smc`` (ABC-SMC beside Algorithm 4); ``budget`` is the cap ``max_budget`` (the run uses Algorithm 4's
    budget when smaller)."""
    c = config["chapter5"]
    sc = c["smc"]
    return SMCSettings(n_particles=sc["n_particles"], budget=sc["max_budget"], prior_sigma=sc["prior_sigma"],
                       quantile=sc["quantile"], epsilon=c["epsilon"])


def dataset_settings(config: Mapping, section: str, model_name: str, dataset: str | None = None) -> DatasetSettings:
    """How ``section`` (``chapter5`` or ``chapter6``) builds a data set of ``model_name`` (:func:`load_dataset`).

    With ``dataset`` given, only the keys that kind of data set uses are read (a simulated 'norm'/'weak':
    ``simulated_emg*``; a participant: ``participant_emg*``), so a rule declares only those; the others keep the
    dataclass's defaults."""
    c = config[section]
    kw: dict = {"emg_groups": tuple(c["emg_groups"].get(model_name, []))}
    simulated = dataset in SIMULATED_DATASETS
    if dataset is None or simulated:
        kw.update(simulated_emg=bool(c["simulated_emg"]), simulated_emg_band=float(c["simulated_emg_band"]))
    if dataset is None or not simulated:
        kw.update(participant_emg=str(c["participant_emg"]), participant_emg_band=float(c["participant_emg_band"]))
    return DatasetSettings(**kw)


def dataset_from_config(config: Mapping, section: str, model: ReducedModel, directions: pd.DataFrame,
                        dataset: str) -> Dataset:
    """Data set ``dataset`` of ``model`` as ``section`` (``chapter5`` / ``chapter6``) builds it: 'norm' / 'weak'
    simulated from the thesis's f_a (Sec. 5.3), else a participant column of ``data.measurements``."""
    d = config["data"]
    return load_dataset(model, directions, dataset, dataset_settings(config, section, model.name, dataset),
                        d["thesis_dir"], d["measurements"], d["activations"])


def estimate_settings(config: Mapping, model_name: str):
    """:class:`neckstrength.estimate.EstimateSettings` of ``model_name``: Algorithm 4 and ABC-SMC from ``chapter5``,
    the joint estimator from ``chapter6`` (its ``joint.criteria`` and ``joint.use_emg``), the deficit decision from
    ``clinician.decision``, the seed."""
    from neckstrength.estimate import EstimateSettings

    return EstimateSettings(seed=int(config["seed"]), bootstrap_direction=str(config["chapter5"]["bootstrap_direction"]),
                            thesis_dir=str(config["data"]["thesis_dir"]), abc=abc_settings(config, model_name),
                            smc=smc_settings(config), joint=joint_settings(config),
                            criteria=tuple(config["chapter6"]["joint"]["criteria"]),
                            use_emg=bool(config["chapter6"]["joint"]["use_emg"]),
                            data_alg4=dataset_settings(config, "chapter5", model_name),
                            data_joint=dataset_settings(config, "chapter6", model_name),
                            decision=decision_settings(config))


def diagnosis_settings(config: Mapping, effects: Sequence[str] | None = None,
                       protocols: bool = True, evidence: bool = True) -> DiagnosisSettings:
    """``gap`` as :class:`DiagnosisSettings`; ``protocols`` / ``evidence`` False: without the power per protocol /
    the Bayes evidence (``gap.protocols`` / ``gap.evidence`` not read; the withheld-effect benchmark scores the
    calibrated test only)."""
    g = config["gap"]
    f = g["fit"]
    fit = FitSettings(max_iter=f["max_iter"], ridge=f["ridge"], bounds_rel=tuple(f["bounds_rel"]),
                      fd_step=f["fd_step"], tol=f["tol"])
    return DiagnosisSettings(effects=tuple(effects or g["effects"]), grid_points=g["grid_points"], folds=g["folds"],
                             pairs_top=g["pairs_top"], pair_grid_top=g["pair_grid_top"], penalty=g["penalty"],
                             epsilon=config["chapter5"]["epsilon"], bootstrap=g["bootstrap"], starts=g["starts"],
                             start_spread=g["start_spread"], refine_iter=g["refine_iter"],
                             refine_starts=g.get("refine_starts", 1),
                             reach_samples=g["reach_samples"], reach_iter=g["reach_iter"], seed=config["seed"], fit=fit,
                             calibration=calibration_settings(config),
                             protocols=protocol_settings(config) if protocols else None,
                             evidence=evidence_settings(config) if evidence else None)


def evidence_settings(config: Mapping):
    """``gap.evidence`` as :class:`neckstrength.gap.evidence.EvidenceSettings` (absent or ``enabled: false``: no
    evidence, and the calibrated test decides)."""
    from neckstrength.gap.evidence import EvidenceSettings

    e = dict(config["gap"].get("evidence") or {})
    if not e or not e.get("enabled", True):
        return None
    d = EvidenceSettings()
    return EvidenceSettings(strength_sd=float(e.get("strength_sd", d.strength_sd)),
                            prior_no_effect=float(e.get("prior_no_effect", d.prior_no_effect)),
                            threshold=float(e.get("threshold", d.threshold)),
                            fit_alpha=float(e.get("fit_alpha", d.fit_alpha)),
                            n_grid=int(e.get("grid_points", d.n_grid)),
                            scatter_cones_deg=tuple(float(c) for c in e.get("scatter_cones_deg", d.scatter_cones_deg)),
                            element_spread=float(e.get("element_spread", d.element_spread)),
                            element_draws=int(e.get("element_draws", d.element_draws)),
                            fit_prior_sd=float(e.get("fit_prior_sd", d.fit_prior_sd)),
                            fit_starts=int(e.get("fit_starts", d.fit_starts)),
                            refit_top=int(e.get("refit_top", d.refit_top)),
                            refit_starts=int(e.get("refit_starts", d.refit_starts)),
                            sample_points=int(e.get("sample_points", d.sample_points)),
                            decides=bool(e.get("decides", d.decides)))


def protocol_settings(config: Mapping) -> ProtocolSettings | None:
    """``gap.protocols`` (absent or ``enabled: false``: no power per protocol, no advice in the reports)."""
    p = dict(config["gap"].get("protocols") or {})
    if not p or not p.get("enabled", True):
        return None
    sizes = p.get("sizes")
    return ProtocolSettings(repeats=int(p.get("repeats", 3)),
                            postures=tuple(str(q) for q in p.get("postures", ("flex20", "ext20"))),
                            emg_sd=float(p.get("emg_sd", 0.1)),
                            sizes=None if sizes is None else tuple(float(u) for u in sizes))


def discriminate_settings(config: Mapping) -> DiscriminateSettings | None:
    """``gap.discriminate`` (absent or ``enabled: false``: no proposal of additional measurements)."""
    d = dict(config["gap"].get("discriminate") or {})
    if not d or not d.get("enabled", True):
        return None
    noise = d.get("noise", "auto")
    f = config["gap"]["fit"]
    fit = FitSettings(max_iter=f["max_iter"], ridge=f["ridge"], bounds_rel=tuple(f["bounds_rel"]),
                      fd_step=f["fd_step"], tol=f["tol"])
    pool = dict(d.get("pool") or {})
    kw = {k: pool[k] for k in ("repeats", "surface", "azimuth_step_deg", "face_max_abs_azimuth_deg",
                                "face_max_elevation_deg") if k in pool}
    if "elevation_deg" in pool:
        kw["elevation_deg"] = tuple(float(x) for x in pool["elevation_deg"])
    if "postures" in pool:
        kw["postures"] = tuple(str(q) for q in pool["postures"])
    return DiscriminateSettings(p_best_below=float(d.get("p_best_below", 0.7)),
                                candidates=int(d.get("candidates", 3)), measurements=int(d.get("measurements", 3)),
                                objective=str(d.get("objective", "saturating")),
                                noise=noise if isinstance(noise, str) else float(noise),
                                parameter_uncertainty=bool(d.get("parameter_uncertainty", True)),
                                strength_spread=float(d.get("strength_spread", 0.3)), fit=fit, **kw)


def calibration_settings(config: Mapping) -> CalibrationSettings:
    """``gap.calibration`` (absent: no calibration, the uncalibrated score ranking)."""
    c = dict(config["gap"].get("calibration") or {})
    if not c:
        return CalibrationSettings(replicates=0)
    noise = c.get("noise", "auto")
    if isinstance(noise, bool) or not (isinstance(noise, (int, float)) and noise > 0
                                       or noise in ("auto", "repeats", "prior", "heldout")):
        raise ValueError(f"gap.calibration.noise: auto, repeats, prior, heldout or a positive log SD, not {noise!r}")
    selection = str(c.get("selection", "largest_improvement"))
    if selection not in ("max_z", "largest_improvement"):
        raise ValueError(f"gap.calibration.selection: max_z or largest_improvement, not {selection!r}")
    null = str(c.get("null_truth", "base"))
    if null not in ("base", "elements"):
        raise ValueError(f"gap.calibration.null_truth: base or elements, not {null!r}")
    spread = c.get("element_spread", 0.3)
    if isinstance(spread, bool) or not isinstance(spread, (int, float)) or not spread >= 0:
        raise ValueError(f"gap.calibration.element_spread: a log SD >= 0, not {spread!r}")
    spread = float(spread)
    prior = c.get("noise_prior") or {}
    prior = tuple(float(prior.get(k, d)) for k, d in (("low", 0.05), ("central", 0.08), ("high", 0.15)))
    if not 0 < prior[0] <= prior[1] <= prior[2]:
        raise ValueError(f"gap.calibration.noise_prior: need 0 < low <= central <= high, not {prior}")
    repeats = ()
    if c.get("noise_table"):
        from neckstrength.trials.noise import read_noise_table

        repeats = tuple((p, v["noise_log_sd"], v["df"], v["ci_low"], v["ci_high"])
                        for p, v in sorted(read_noise_table(c["noise_table"]).items()))
    return CalibrationSettings(replicates=int(c.get("replicates", 39)), alpha=float(c.get("alpha", 0.05)),
                               noise=noise if isinstance(noise, str) else float(noise), noise_prior=prior,
                               repeats=repeats, sensitivity=bool(c.get("sensitivity", True)),
                               sensitivity_replicates=(None if c.get("sensitivity_replicates") is None
                                                       else int(c["sensitivity_replicates"])),
                               power_sizes=tuple(float(u) for u in c.get("power_sizes", (0.25, 0.5, 1.0))),
                               power_replicates=int(c.get("power_replicates", 5)),
                               power_target=float(c.get("power_target", 0.8)),
                               strength_spread=float(c.get("strength_spread", 0.3)),
                               starts=int(c.get("starts", 1)), max_iter=int(c.get("max_iter", 15)),
                               cv=str(c.get("cv", "refit")), cv_steps=int(c.get("cv_steps", 1)),
                               null_truth=null, element_spread=spread, selection=selection)


def benchmark_settings(config: Mapping) -> BenchmarkSettings:
    b = config["gap"]["benchmark"]
    nz = b["noise_rel"]
    return BenchmarkSettings(effects=tuple(b["effects"]), pairs=tuple(tuple(p) for p in b.get("pairs", [])),
                             replicates=b["replicates"], controls=b["controls"],
                             noise_rel=tuple(float(x) for x in nz) if isinstance(nz, (list, tuple)) else float(nz),
                             strength_spread=b["strength_spread"], clear_size=tuple(b["clear_size"]),
                             mismatch_replicates=int(b.get("mismatch_replicates", 0)))


def chapter6_settings(config: Mapping, model_name: str | None = None, **over) -> SequentialSettings:
    c = config["chapter6"]
    per = c.get("model_settings", {}).get(model_name, {}) if model_name else {}
    keys = ("n_candidates", "n_sim", "prior_sd_rel", "epsilon", "q", "n_bins", "bin_range_sd", "n_wbins", "alpha_min",
            "likelihood", "likelihood_floor", "predictive", "emg_band")
    kw = {k: per.get(k, c[k]) for k in keys if k in c or k in per}
    kw.update(over)
    return SequentialSettings(**kw)


def joint_settings(config: Mapping, **over) -> JointSettings:
    """``chapter6.joint`` (keys of :class:`JointSettings`; others ignored), with the Chapter 6 grid."""
    c = config["chapter6"]
    j = dict(c.get("joint", {}))
    names = {f.name for f in fields(JointSettings)}
    kw = {k: v for k, v in j.items() if k in names}
    kw.setdefault("prior_sd_rel", float(c.get("prior_sd_rel", 0.3)))
    kw.setdefault("n_bins", int(c.get("n_bins", 50)))
    kw.setdefault("bin_range_sd", float(c.get("bin_range_sd", 4.0)))
    kw.setdefault("emg_band", float(c.get("emg_band", 0.05)))
    kw.update(over)
    return JointSettings(**kw)


def deficit_definition(config: Mapping):
    """``clinician.deficit``: the muscle group and threshold of P(deficit) (session screen and study)."""
    from neckstrength.sequential.deficit import DeficitDefinition

    d = config.get("clinician", {}).get("deficit", {})
    return DeficitDefinition(group=tuple(d.get("group", ["mf"])), threshold=float(d.get("threshold", 0.6)))


def decision_settings(config: Mapping, **over):
    """``clinician.decision``: the deficit decision's hypotheses, noise, prevalence and samplers (issue 31); keys
    the config leaves out keep the dataclass's defaults (the schema's, tests/sequential/test_decision.py)."""
    from dataclasses import fields

    from neckstrength.sequential.decision import DecisionSettings

    d = dict(config.get("clinician", {}).get("decision", {}))
    names = {f.name for f in fields(DecisionSettings)}
    unknown = set(d) - names
    if unknown:
        raise ValueError(f"clinician.decision: unknown settings {sorted(unknown)}; known: {sorted(names)}")
    for k in ("group", "deficit_range"):
        if k in d:
            d[k] = tuple(d[k])
    d.update(over)
    if isinstance(d.get("calibration"), (str, Path)):
        d["calibration"] = load_decision_calibration(d["calibration"])
    if isinstance(d.get("misfit_guard"), (str, Path)):
        d["misfit_guard"] = load_decision_calibration(d["misfit_guard"], guard=True)
    return DecisionSettings(**d)


def load_decision_calibration(path: str | Path, guard: bool = False):
    """``clinician.decision.calibration``: the recalibration file the decision study writes
    (``decision_calibration.csv``); with ``guard``, ``clinician.decision.misfit_guard``: the calibrated misfit guard
    (``decision_misfit_guard.csv``). A relative path is read from the working folder, else from the package's
    own ``data/`` (the shipped file), so sessions started anywhere find it."""
    from neckstrength.sequential.decision import DecisionCalibration, MisfitGuard

    key, what, cls = (("misfit_guard", "decision_misfit_guard.csv", MisfitGuard) if guard
                      else ("calibration", "decision_calibration.csv", DecisionCalibration))

    p = Path(path)
    if not p.is_absolute() and not p.exists():
        alt = Path(__file__).resolve().parents[2] / p
        if alt.exists():
            p = alt
    if not p.is_file():
        raise DataValidationError(path, f"clinician.decision.{key}: no such file (the decision study's {what}), "
                                        "or set it to null")
    try:
        return cls.from_frame(pd.read_csv(p, comment="#"), source=str(path))
    except ValueError as exc:
        raise DataValidationError(path, str(exc)) from None


def decision_study_settings(config: Mapping, model_name: str):
    """``clinician.decision_study`` -> (DecisionStudySettings, n_candidates per hypothesis of the study)."""
    from dataclasses import fields

    from neckstrength.sequential.cohort import CohortSettings
    from neckstrength.sequential.decision_study import DecisionStudySettings

    d = dict(config.get("clinician", {}).get("decision_study", {}))
    n_cand = int(d.pop("n_candidates", 1000))
    ck = {f.name for f in fields(CohortSettings)}
    cohort = CohortSettings(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k in ck})
    rest = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k not in ck}
    if "patients_per_kind" in rest:             # {protocol: k} -> ((protocol, k), ...), hashable and ordered
        rest["patients_per_kind"] = tuple((str(p), int(k)) for p, k in dict(rest["patients_per_kind"]).items())
    emg = tuple(config.get("chapter6", {}).get("emg_groups", {}).get(model_name, []))
    boot = str(config.get("chapter5", {}).get("bootstrap_direction", "back"))   # Algorithm 4's (alg4 protocol)
    study = DecisionStudySettings(cohort=cohort, emg_groups=emg if any("emg" in p for p in
                                                                       rest.get("protocols", ())) else (),
                                  bootstrap_direction=boot, **rest)
    return study, n_cand


def session_settings(config: Mapping, model_name: str):
    """:class:`neckstrength.session.settings.SessionSettings` of a clinician session of ``model_name``."""
    from neckstrength.session.settings import SessionSettings

    per = session_defaults(config, model_name)
    n = per.get("n_candidates")
    return SessionSettings(seed=int(config["seed"]), sequential=chapter6_settings(config, model_name),
                           joint=joint_settings(config), deficit=deficit_definition(config),
                           decision=decision_settings(config),
                           gain_frac=float(config["chapter6"]["stop"]["gain_frac"]),
                           criterion=str(per.get("criterion", "thesis")), n_candidates=None if n is None else int(n),
                           postures=tuple(config["postures"]["postures"]),
                           force_length=str(config["postures"]["force_length"]),
                           model_dir=str(config["data"]["model_dir"]),
                           test_point_spec=config["geometry"]["test_point_spec"],
                           emg_groups=tuple(config.get("chapter6", {}).get("emg_groups", {}).get(model_name, [])))


def session_defaults(config: Mapping, model_name: str) -> dict:
    """``clinician.session.<model>``: the clinician session's posterior ('joint' or 'marginal', the thesis's
    scheme), criterion and candidate count for ``model_name`` (empty: the thesis's scheme with chapter6 sizes)."""
    return dict(config.get("clinician", {}).get("session", {}).get(model_name, {}))


def session_stage(config: Mapping, opts):
    """A clinician session's settings and inputs (:class:`neckstrength.session.settings.SessionSettings`,
    :class:`neckstrength.session.stage.SessionInputs`) for its options ``opts``
    (:class:`~neckstrength.session.state.SessionOptions`: the model and ``--postures``): built once here, so the
    session engine reads neither the config nor the model files."""
    from neckstrength.session.render import where_to_push
    from neckstrength.session.settings import resolve_postures
    from neckstrength.session.stage import SessionInputs

    cs = session_settings(config, opts.model)
    postures = resolve_postures(opts.postures, list(cs.postures))
    full = full_model_from_config(config)
    model = model_from_config(full, config, opts.model)
    d, U = model_directions_table(model, build_directions(config))
    pset = None
    if postures is not None:
        from neckstrength.postures import build_posture_set, load_posture_tables

        pset = build_posture_set(full, model, load_posture_tables(cs.model_dir, postures), postures, cs.force_length)
    return cs, SessionInputs(model, d, U, where_to_push(d, cs.test_point_spec), postures, pset)


# --- the sim-to-real gap diagnosis ---------------------------------------------------------------------------


def gap_context(config: Mapping, model_name: str, directions: pd.DataFrame) -> GapContext:
    g = config["gap"]
    full = full_model_from_config(config)
    model = model_from_config(full, config, model_name)
    d, _ = model_directions_table(model, directions)
    tie = g.get("tie_sides")
    if tie is None:
        tie = bool(config["chapter5"]["settings"].get(model_name, {}).get("tie_sides", False))
    emg = tuple(config["chapter5"].get("emg_groups", {}).get(model_name, []))
    return GapContext(full, model, d, np.asarray(config["geometry"]["head"]["centre"], float), emg,
                      tuple(g["shoulder_muscles"]), bool(tie), dict(g.get("effect_settings") or {}),
                      _gap_posture_tables(config), 0.0, str(config.get("postures", {}).get("force_length", "relative")))


def gap_truth_setup(config: Mapping, model_name: str | None = None):
    """``(model name, diagnosis context, truths' set-up)`` for the gap benchmarks' truths: ``model_name`` or config
    ``gap.benchmark.model``, on the config's test directions (:class:`neckstrength.gap.truths.TruthSetup`)."""
    from neckstrength.gap.truths import TruthSetup

    name = model_name or config["gap"]["benchmark"]["model"]
    ctx = gap_context(config, name, build_directions(config))
    return name, ctx, TruthSetup.of(ctx)


def _gap_posture_tables(config: Mapping) -> dict | None:
    """The shipped posture tables (all seven: ``posture_drift`` drifts about every axis) for the gap diagnosis's
    ``posture_drift`` and the posture protocol; None when the model folder has none (the effect then does not
    apply)."""
    from neckstrength.postures.tables import load_posture_tables

    try:
        return load_posture_tables(config["data"]["model_dir"])
    except FileNotFoundError:
        return None


def gap_models(config: Mapping) -> list[str]:
    """``gap.models``: the models the gap diagnosis runs on (the first is ``neckstrength diagnose``'s default)."""
    return list(config["gap"]["models"])


def plane_bands(config: Mapping) -> dict:
    """``geometry.plane_bands``: the elevation and azimuth bands that assign the directions to planes."""
    return dict(config["geometry"]["plane_bands"])


def trial_settings(config: Mapping):
    """``trials.settings`` as :class:`neckstrength.trials.ImportSettings` (the trial import's windows and frames)."""
    from neckstrength.trials import ImportSettings

    return ImportSettings.from_mapping(config["trials"]["settings"])


def gap_measurements_path(config: Mapping) -> str:
    return config["gap"].get("measurements") or config["data"]["measurements"]


def gap_blind_dataset(config: Mapping, ctx: GapContext, directions: pd.DataFrame, dataset: str,
                      measurements: str | Path | None = None) -> BlindData:
    """Forces only: a participant column of the measurement table (``measurements``, default
    :func:`gap_measurements_path`), or a simulated data set ('norm', 'weak')."""
    measurements = measurements or gap_measurements_path(config)
    if dataset in ("norm", "weak"):
        data = load_dataset(ctx.model, directions, dataset,
                            replace(dataset_settings(config, "chapter5", ctx.model.name), participant_emg="none"),
                            config["data"]["thesis_dir"], measurements, config["data"]["activations"])
    else:
        data = participant_dataset(ctx.model, directions, dataset, measurements)
    if list(data.directions) != list(ctx.directions["name"]):
        raise ValueError("data set directions do not match the model's directions")
    return BlindData(dataset, data.forces)


def gap_withheld_activations(config: Mapping, ctx: GapContext, dataset: str) -> np.ndarray | None:
    """Table A.3 column of ``dataset`` in direction order, or None when it has none (e.g. simulated)."""
    path = config["data"].get("activations")
    if not path or not Path(path).exists():
        return None
    act = read_activations(path)
    if dataset not in act.columns:
        return None
    return act[dataset].reindex(ctx.directions["name"]).to_numpy(float)


def gap_settings_text(config: Mapping, s: DiagnosisSettings) -> str:
    g = config["gap"]
    return "\n".join([f"- effects: {', '.join(s.effects)}",
                      f"- effect settings: `{json.dumps(plain(g.get('effect_settings') or {}))}`",
                      f"- grid points per effect: {s.grid_points}; folds: {s.folds}; starts per fit: {s.starts} "
                      f"(spread {s.start_spread} in log strength); pairs of the best {s.pairs_top} effects on the "
                      f"best {s.pair_grid_top} grid points of each",
                      f"- fit: {json.dumps(plain(g['fit']))}; penalty {s.penalty} per extra parameter; bootstrap {s.bootstrap}",
                      f"- effect-parameter refinement iterations (all-direction fit): {s.refine_iter} "
                      f"({s.refine_starts} start(s) per trial)",
                      f"- reach envelope: {s.reach_samples} samples, {s.reach_iter} gradient iterations",
                      f"- calibration: {s.calibration.replicates} noise-only replicates (p resolution "
                      f"{1 / (s.calibration.replicates + 1):.3g}), alpha {s.calibration.alpha}, noise "
                      f"{s.calibration.noise} (prior low / central / high "
                      f"{' / '.join(f'{x:g}' for x in s.calibration.noise_prior)}; repeat-trial noise for "
                      f"{', '.join(r[0] for r in s.calibration.repeats) or 'no data set'}; sensitivity "
                      f"{'on' if s.calibration.sensitivity else 'off'}); power at sizes "
                      f"{list(s.calibration.power_sizes)} with "
                      f"{s.calibration.power_replicates} replicates each (target {s.calibration.power_target}); "
                      f"screen (measured and simulated data alike): {s.calibration.starts} start(s), max_iter "
                      f"{s.calibration.max_iter}",
                      *_discriminate_text(config),
                      _protocols_text(s),
                      f"- seed {config['seed']}"])


def diagnose_stage(config: Mapping, model_name: str, dataset: str, directions: pd.DataFrame,
                   measurements: str | Path | None = None, extra_trials: str | Path | None = None,
                   effects: Sequence[str] = (), workers: int = 1):
    """The diagnosis stage's settings and inputs (:class:`neckstrength.gap.stage.DiagnoseSettings`,
    :class:`~neckstrength.gap.stage.DiagnoseInputs`): the rule ``gap_diagnose`` and ``neckstrength diagnose`` both
    build them here, so both give the same answer. ``effects``: candidates instead of ``gap.effects``;
    ``measurements``: a max-force table instead of the config's."""
    from dataclasses import replace

    from neckstrength.gap.stage import DiagnoseInputs, DiagnoseSettings

    ctx = gap_context(config, model_name, directions)
    data = gap_blind_dataset(config, ctx, directions, dataset, measurements=measurements)
    s = diagnosis_settings(config)
    if effects:
        s = replace(s, effects=tuple(effects))
    settings = DiagnoseSettings(s, discriminate_settings(config), max(1, int(workers)))
    inputs = DiagnoseInputs(ctx, data, directions, gap_withheld_activations(config, ctx, dataset),
                            gap_settings_text(config, s), model_name, head_from_config(config), plane_bands(config),
                            extra_trials)
    return settings, inputs


def _protocols_text(s: DiagnosisSettings) -> str:
    p = s.protocols
    if p is None:
        return "- what to measure to tell: not computed (`gap.protocols` absent or disabled)"
    return (f"- what to measure to tell (gap.protocols): power of the present tests, {p.repeats} trials per direction, "
            f"the tests in {', '.join(p.postures) or 'no posture'}, surface EMG (SD {p.emg_sd:g}) and all of them, "
            f"at sizes {list(p.sizes or s.calibration.power_sizes)}; linearised, scaled to the simulated power")


def _discriminate_text(config: Mapping) -> list[str]:
    d = discriminate_settings(config)
    if d is None:
        return ["- additional measurements: not proposed (`gap.discriminate` absent or disabled)"]
    return [(f"- additional measurements (gap.discriminate): when P(best) of the best < {d.p_best_below}, the "
            f"{d.measurements} that best separate the top {d.candidates} candidates (objective {d.objective}; noise "
            f"{d.noise}; parameter uncertainty {'on' if d.parameter_uncertainty else 'off'}, strength spread "
            f"{d.strength_spread}); pool: {'repeats' if d.repeats else ''}{' + ' if d.repeats and d.surface else ''}"
            f"{'surface grid every ' + format(d.azimuth_step_deg, 'g') + ' deg azimuth at elevations ' if d.surface else ''}"
            f"{list(d.elevation_deg) if d.surface else ''}")]


# --- the thesis scorecard -----------------------------------------------------------------------------------------


def scorecard_settings(config: Mapping):
    """:class:`neckstrength.report.scorecard.settings.ScorecardSettings`: what the scorecard reads of the config."""
    from neckstrength.report.scorecard.settings import ScorecardSettings

    m, c4, c5 = config["model"], config["chapter4"], config["chapter5"]
    return ScorecardSettings(seed=int(config["seed"]), thesis_dir=str(config["data"]["thesis_dir"]),
                             model_dir=str(config["data"]["model_dir"]),
                             unprinted_strengths=m["unprinted_strengths"],
                             grouping_supplements=m["grouping_supplements"], apply_b1_errata=m["apply_b1_errata"],
                             mixed_model_alpha=config["chapter3"]["mixed_model"]["alpha"], eps_D=c5["eps_D"],
                             sigma_clip=tuple(c5["sigma_clip"]), claim_tolerance_rel=c4["claim_tolerance_rel"],
                             anterior_max_azimuth_deg=c4["anterior_max_azimuth_deg"])


# --- identifiability (issue 31 item 1) ------------------------------------------------------------------------


def identifiability_settings(config: Mapping, model_name: str):
    """``identifiability``: the misfit profiles and distinguishability study of ``model_name`` (frozen dataclass)."""
    from neckstrength.identifiability.profile import ProfileSettings
    from neckstrength.identifiability.study import StudySettings

    c = config["identifiability"]
    per = dict(c.get("model_settings", {}).get(model_name, {}))
    grid = tuple(float(x) for x in per.get("grid", c["grid"]))
    bounds = tuple((str(k), float(v[0]), float(v[1])) for k, v in c["bounds"].items())
    prof = ProfileSettings(grid=grid, bounds=bounds, n_starts=int(per.get("n_starts", c["n_starts"])),
                           continuation=bool(c["continuation"]), max_iter=int(c["max_iter"]),
                           fd_step=float(c["fd_step"]), tol=float(c["tol"]))
    groups = per.get("groups", c["groups"].get(model_name, "all"))
    if model_name not in c["deficit_group"]:
        raise ValueError(f"identifiability.deficit_group has no entry for model {model_name!r}")
    pp = c["participants"]
    return StudySettings(profile=prof, groups=None if groups == "all" else tuple(groups),
                         deficit_group=str(c["deficit_group"][model_name]),
                         deficits=tuple(float(x) for x in c["deficits"]),
                         n_participants=int(per.get("n_participants", pp["n"])), population_sd=float(pp["sd"]),
                         participant_deficit=float(pp["deficit"]),
                         protocols=tuple(per.get("protocols", c["protocols"])),
                         protocol_grid=tuple(float(x) for x in c["protocol_grid"]), sigma_ref=float(c["sigma_ref"]),
                         check_rtol=float(c["check_rtol"]))


def rerun_settings(config: Mapping, chapter: str, model_name: str):
    """:class:`neckstrength.reruns.runs.RerunSettings` of one chapter x model (config ``reruns``): K from
    ``reruns.<chapter>.members``, overridden per model by ``reruns.chapter5.model_members``."""
    from neckstrength.reruns.runs import RerunSettings

    r = config["reruns"]
    if chapter not in ("chapter5", "chapter6"):
        raise ValueError(f"reruns: unknown chapter {chapter!r} (chapter5, chapter6)")
    c = r[chapter]
    members = int(c.get("model_members", {}).get(model_name, c["members"]))
    n = c.get("n_candidates") if chapter == "chapter6" else None
    return RerunSettings(members=members, level=float(r["level"]), n_candidates=None if n is None else int(n))
