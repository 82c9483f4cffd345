"""One diagnosis run, written to its output files: tables, figures, ``report.md`` and ``summary.json``.

Called by the pipeline rule ``gap_diagnose`` and by ``neckstrength diagnose`` with the same arguments, so the
same data set gets the same answer by either path.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from neckstrength.gap.diagnose import BlindData, DiagnosisSettings, diagnose
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

#: Per-data-set tables and figures (keys of ``outputs``; plus 'summary' and 'report').
DATASET_FILES = ("residuals", "planes", "components", "muscles", "effects", "strengths", "activation_check", "power",
                 "discrimination")
FIGURES = ("radar", "where", "effects", "activation")


def run_diagnosis(ctx: GapContext, data: BlindData, settings: DiagnosisSettings, directions: pd.DataFrame,
                  a3: np.ndarray | None, outputs: Mapping[str, str | Path],
                  settings_text: str, model_name: str, discriminate: DiscriminateSettings | None = None,
                 head: HeadEllipsoid | None = None, plane_bands: Mapping | None = None, workers: int = 1,
                 extra_trials: str | Path | None = None) -> dict:
    """Diagnose one data set and write every output (keys of ``outputs``); returns the summary. ``workers``:
    processes that screen the calibration's simulated data sets and compute the proposal's predictives (the
    answer does not depend on it).

    With ``discriminate`` and ``head`` (the cranial ellipsoid of the geometry), the measurements that would
    best tell the leading candidates apart are proposed when they are close
    (:mod:`neckstrength.gap.discriminate`; output ``discrimination``). ``extra_trials``: a CSV of additional
    trials (``measurement``, ``force_N``; e.g. the proposed ones, measured): the posterior probabilities of the
    top candidates given them (output ``update``, a section of the report)."""
    t0 = time.time()
    dataset = data.name
    s = settings
    print(f"gap diagnosis: model {model_name}, data set {dataset}, {ctx.K} directions, forces only", flush=True)
    store = ResultStore(Path(outputs["summary"]).parent / "resume", ctx, s)
    diag = diagnose(ctx, [data], s, progress=lambda m: print(f"[{time.time() - t0:.0f} s] {m}", flush=True),
                    store=store, workers=workers)[0]
    if discriminate is not None and head is not None:
        t1 = time.time()
        attach_proposal(ctx, data.forces, diag, head, discriminate, plane_bands, workers)
        info = diag.summary["discrimination"]
        print(f"[{time.time() - t0:.0f} s] additional measurements: "
              + (f"{', '.join(info['measurements'])} to tell {', '.join(info['candidates'])} apart"
                 if info["proposed"] else info.get("note", "none proposed")) + f" ({time.time() - t1:.1f} s)",
              flush=True)
    if extra_trials is not None:
        ds = discriminate or DiscriminateSettings()
        if head is None:
            raise ValueError("extra trials need the head geometry (geometry.head) for the measurement pool")
        trials = read_extra_trials(extra_trials, measurement_pool(ctx, head, ds, plane_bands))
        attach_update(ctx, data.forces, diag, head, trials, ds, plane_bands)
        u = diag.summary["update"]
        print(f"[{time.time() - t0:.0f} s] {u['trials']} extra trial(s) from {extra_trials}: favour "
              f"{u['favoured']} (posterior {u['posterior'][u['favoured']]:.2f})", flush=True)
        if "update" in outputs:
            hdr_u = f"extra trials {extra_trials}: posterior of the top candidates (docs/gap_diagnosis.md)"
            atomic_write_csv(diag.update, outputs["update"], [hdr_u], float_format="%.6g")
    act = activation_check(diag, a3)
    hdr = [f"gap diagnosis (issue 8): model {model_name}, data set {dataset}; forces only (Table A.3 withheld)"]
    tables = {"residuals": diag.residuals, "planes": diag.planes, "components": diag.components,
              "muscles": diag.muscles, "effects": diag.effects, "strengths": diag.strengths,
              "power": diag.power if len(diag.power) else pd.DataFrame(
                  {"effect": [], "size_share": [], "theta": [], "replicates": [], "skipped_unproducible": [],
                   "identified": [], "power": []}),
              "discrimination": (getattr(diag, "discrimination", None) if len(getattr(diag, "discrimination", ()))
                                 else pd.DataFrame(columns=PROPOSAL_COLUMNS)),
              "activation_check": act if len(act) else pd.DataFrame(
                  {"candidate": [], "pearson_r": [], "spearman_rho": [], "model_mean": [], "a3_mean": [],
                   "mean_abs_diff": []})}
    if "protocols" in outputs:
        from neckstrength.gap.protocols import POWER_COLUMNS

        tables["protocols"] = diag.protocols if len(diag.protocols) else pd.DataFrame(columns=POWER_COLUMNS)
    for k, df in tables.items():
        if k in outputs:
            atomic_write_csv(df, outputs[k], hdr, float_format="%.6g")
    figs = {k: outputs[f"fig_{k}"] for k in FIGURES if f"fig_{k}" in outputs}
    if a3 is None:
        Path(figs["activation"]).parent.mkdir(parents=True, exist_ok=True)
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 2))
        ax.text(0.5, 0.5, f"no withheld activation data for {dataset}", ha="center", va="center")
        ax.axis("off")
        fig.savefig(figs["activation"], dpi=80)
        plt.close(fig)
    write_figures(diag, directions, figs, a3)
    rel = {k: Path(v).name for k, v in figs.items()}
    if a3 is None:
        rel.pop("activation")
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
    write_report(diag, outputs["report"], rel, act, settings_text)
    atomic_write_text(json.dumps(summary, indent=2, default=float), outputs["summary"])
    print(f"done in {time.time() - t0:.0f} s: {summary['decision']}, held-out gap "
          f"{summary['gap_before']:.3f} -> {summary['gap_after']:.3f}")
    for line in summary.get("protocol_advice") or []:
        print(f"  {line}")
    return summary
