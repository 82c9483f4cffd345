"""The diagnosis stage: :func:`run_diagnose` returns the result in memory, :func:`write_diagnose` writes its files.

The pipeline rule ``gap_diagnose`` (:func:`neckstrength.pipeline.gap.gap_diagnose`) and ``neckstrength diagnose``
both call the two, with inputs built by the same config functions, so the same data set gets the same answer by
either path. Progress goes to ``progress`` (standard error on the command line, the rule's log in the pipeline).
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
import pandas as pd

from neckstrength.gap.diagnose import BlindData, DatasetDiagnosis, DiagnosisSettings, diagnose
from neckstrength.gap.discriminate import (
    PROPOSAL_COLUMNS,
    DiscriminateSettings,
    attach_proposal,
    attach_update,
    measurement_pool,
    read_extra_trials,
)
from neckstrength.gap.effects import GapContext
from neckstrength.gap.report import activation_check, write_figures, write_report
from neckstrength.gap.store import ResultStore
from neckstrength.io import atomic_write_csv, atomic_write_text
from neckstrength.model.geometry import HeadEllipsoid

#: Per-data-set tables and figures (keys of ``outputs``; plus 'summary', 'report' and, optionally, 'protocols' and
#: 'update').
DATASET_FILES = ("residuals", "planes", "components", "muscles", "effects", "strengths", "activation_check", "power",
                 "discrimination")
FIGURES = ("radar", "where", "effects", "activation")


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


@dataclass(frozen=True)
class DiagnoseSettings:
    """The stage's settings: the diagnosis, the proposal of discriminating measurements (None: none proposed) and
    the worker processes (the answer does not depend on them)."""

    diagnosis: DiagnosisSettings = DiagnosisSettings()
    discriminate: DiscriminateSettings | None = None
    workers: int = 1


@dataclass(frozen=True)
class DiagnoseInputs:
    """One data set to diagnose: the model context, the blind data (forces only), the directions table, the withheld
    Table A.3 activations (None: none), the settings as text for the report, the model's name, the head geometry and
    plane bands (for the measurement proposal) and optional extra trials (a CSV of ``measurement``, ``force_N``)."""

    ctx: GapContext
    data: BlindData
    directions: pd.DataFrame
    a3: np.ndarray | None
    settings_text: str
    model_name: str
    head: HeadEllipsoid | None = None
    plane_bands: Mapping | None = None
    extra_trials: str | Path | None = None


@dataclass
class DiagnoseResult:
    """The diagnosis of one data set: the science's result, the output tables by name, the summary (as written to
    ``summary.json``) and what the report and figures need."""

    diagnosis: DatasetDiagnosis
    tables: dict[str, pd.DataFrame]
    summary: dict
    activation_check: pd.DataFrame
    inputs: DiagnoseInputs
    update: pd.DataFrame | None = None
    seconds: float = 0.0
    header: list[str] = field(default_factory=list)


def _empty(columns) -> pd.DataFrame:
    return pd.DataFrame({c: [] for c in columns})


def header_line(inputs: DiagnoseInputs) -> str:
    """The line a caller prints before :func:`run_diagnose` (what is diagnosed)."""
    return (f"gap diagnosis: model {inputs.model_name}, data set {inputs.data.name}, {inputs.ctx.K} directions, "
            "forces only")


def answer_lines(result: DiagnoseResult) -> list[str]:
    """The answer as printed after the run: the decision and the held-out gap, then one line per piece of
    protocol advice ("to tell X from noise, add Y")."""
    s = result.summary
    return ([f"done in {result.seconds:.0f} s: {s['decision']}, held-out gap {s['gap_before']:.3f} -> "
             f"{s['gap_after']:.3f}"] + [f"  {line}" for line in s.get("protocol_advice") or []])


def run_diagnose(settings: DiagnoseSettings, inputs: DiagnoseInputs, resume_dir: str | Path | None = None,
                 progress: Callable[[str], None] = _stderr) -> DiagnoseResult:
    """Diagnose one data set (:func:`neckstrength.gap.diagnose.diagnose`), then propose the measurements that would
    best tell the leading candidates apart (with ``settings.discriminate`` and ``inputs.head``;
    :mod:`neckstrength.gap.discriminate`) and update on ``inputs.extra_trials``. ``resume_dir``: finished pieces are
    kept there and reused by a rerun with the same inputs (:class:`neckstrength.gap.store.ResultStore`)."""
    t0 = time.time()
    ctx, data, s = inputs.ctx, inputs.data, settings.diagnosis
    store = ResultStore(Path(resume_dir), ctx, s) if resume_dir is not None else None
    diag = diagnose(ctx, [data], s, progress=lambda m: progress(f"[{time.time() - t0:.0f} s] {m}"),
                    store=store, workers=settings.workers)[0]
    if settings.discriminate is not None and inputs.head is not None:
        t1 = time.time()
        attach_proposal(ctx, data.forces, diag, inputs.head, settings.discriminate, inputs.plane_bands,
                        settings.workers)
        info = diag.summary["discrimination"]
        progress(f"[{time.time() - t0:.0f} s] additional measurements: "
                 + (f"{', '.join(info['measurements'])} to tell {', '.join(info['candidates'])} apart"
                    if info["proposed"] else info.get("note", "none proposed")) + f" ({time.time() - t1:.1f} s)")
    update = None
    if inputs.extra_trials is not None:
        ds = settings.discriminate or DiscriminateSettings()
        if inputs.head is None:
            raise ValueError("extra trials need the head geometry (geometry.head) for the measurement pool")
        trials = read_extra_trials(inputs.extra_trials, measurement_pool(ctx, inputs.head, ds, inputs.plane_bands))
        attach_update(ctx, data.forces, diag, inputs.head, trials, ds, inputs.plane_bands)
        u = diag.summary["update"]
        progress(f"[{time.time() - t0:.0f} s] {u['trials']} extra trial(s) from {inputs.extra_trials}: favour "
                 f"{u['favoured']} (posterior {u['posterior'][u['favoured']]:.2f})")
        update = diag.update
    act = activation_check(diag, inputs.a3)
    tables = {"residuals": diag.residuals, "planes": diag.planes, "components": diag.components,
              "muscles": diag.muscles, "effects": diag.effects, "strengths": diag.strengths,
              "power": diag.power if len(diag.power) else _empty(
                  ["effect", "size_share", "theta", "replicates", "skipped_unproducible", "identified", "power"]),
              "discrimination": (getattr(diag, "discrimination", None) if len(getattr(diag, "discrimination", ()))
                                 else pd.DataFrame(columns=PROPOSAL_COLUMNS)),
              "activation_check": act if len(act) else _empty(
                  ["candidate", "pearson_r", "spearman_rho", "model_mean", "a3_mean", "mean_abs_diff"])}
    if hasattr(diag, "protocols"):
        from neckstrength.gap.protocols import POWER_COLUMNS

        tables["protocols"] = diag.protocols if len(diag.protocols) else pd.DataFrame(columns=POWER_COLUMNS)
    summary = dict(diag.summary)
    if len(act):
        a = act.set_index("candidate")
        for c, tag in (("none", "base"), (summary["chosen"], "chosen")):
            if c in a.index:
                summary[f"a3_pearson_{tag}"] = float(a.loc[c, "pearson_r"])
                summary[f"a3_model_mean_{tag}"] = float(a.loc[c, "model_mean"])
                summary[f"a3_mean_abs_diff_{tag}"] = float(a.loc[c, "mean_abs_diff"])
        summary["a3_mean"] = float(a["a3_mean"].iloc[0])
    summary["seconds"] = time.time() - t0
    hdr = [f"gap diagnosis (issue 8): model {inputs.model_name}, data set {data.name}; forces only "
           "(Table A.3 withheld)"]
    return DiagnoseResult(diag, tables, summary, act, inputs, update, summary["seconds"], hdr)


def write_diagnose(result: DiagnoseResult, outputs: Mapping[str, str | Path]) -> None:
    """Write the tables, figures, ``report.md`` and ``summary.json`` of :func:`run_diagnose` (keys of ``outputs``:
    :data:`DATASET_FILES`, ``fig_<name>`` for :data:`FIGURES`, 'summary', 'report'; optional 'protocols' and
    'update'). Keys not in ``outputs`` are not written; every figure in ``outputs`` is (the activation figure of a
    model without EMG-recorded groups and without Table A.3 shows its muscle groups' predicted activation:
    :func:`neckstrength.gap.report.write_figures`); the report links the figures written."""
    inp, diag = result.inputs, result.diagnosis
    if result.update is not None and "update" in outputs:
        hdr_u = f"extra trials {inp.extra_trials}: posterior of the top candidates (docs/gap_diagnosis.md)"
        atomic_write_csv(result.update, outputs["update"], [hdr_u], float_format="%.6g")
    for k, df in result.tables.items():
        if k in outputs:
            atomic_write_csv(df, outputs[k], result.header, float_format="%.6g")
    figs = {k: outputs[f"fig_{k}"] for k in FIGURES if f"fig_{k}" in outputs}
    written = write_figures(diag, inp.directions, figs, inp.a3)
    rel = {k: Path(v).name for k, v in figs.items() if k in written}
    write_report(diag, outputs["report"], rel, result.activation_check, inp.settings_text)
    atomic_write_text(json.dumps(result.summary, indent=2, default=float), outputs["summary"])
