"""From a lab's trial table to the tables the pipeline reads (Table A.2 / A.3 layouts) plus a quality report.

:func:`import_trials` validates everything first (errors name file, row and field) and returns an
:class:`ImportResult`; :func:`write_import` then writes all outputs atomically, so a bad input never leaves a
half-written or overwritten result behind.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from neckstrength import __version__
from neckstrength.io import atomic_write_csv, atomic_write_text
from neckstrength.trials import emg as emg_mod
from neckstrength.trials import report
from neckstrength.trials.formats import CARDINAL, emg_channels, read_trials
from neckstrength.trials.noise import repeat_noise
from neckstrength.trials.resolve import MatchSettings, default_frames, resolve_trials
from neckstrength.trials.select import fatigue_table, select_trials

#: output keys -> file names (the pipeline rule and the CLI use the same names)
OUTPUT_FILES = {"max_force": "max_force.csv", "activation": "activation.csv",
                "activation_by_muscle": "activation_by_muscle.csv", "trials": "quality_trials.csv",
                "exclusions": "exclusions.csv", "fatigue": "fatigue.csv", "noise": "noise.csv",
                "report": "quality_report.md",
                "figure": "fig_quality.png", "summary": "summary.json"}


@dataclass(frozen=True)
class ImportSettings:
    angle_deg: float = 20.0               # Appendix A: unit-vector error of moment and force
    ratio_tol: float = 0.10               # Appendix A: error of R_fm (Eq. A.2)
    mismatch_action: str = "drop"         # 'drop' or 'flag' trials outside the window
    repeat_rel: float = 0.10              # third trial when the second is > 10% above the first
    fatigue_threshold: float = 0.10       # flag a participant whose cardinal efforts drop > 10% on average
    pad_to_c0_m: tuple[float, float, float] = (0.08, -0.02, 0.0)   # C0-C1 relative to the lower posterior pad
    frames: Mapping[str, Mapping] = field(default_factory=dict)     # extra frames {name: {origin, rotation}}
    emg_delay_s: float = 0.25             # read-out 250 ms before the peak wrench
    emg_window_s: float = 0.25            # centred moving-average window

    @classmethod
    def from_mapping(cls, m: Mapping | None) -> "ImportSettings":
        m = dict(m or {})
        names = set(cls.__dataclass_fields__)
        unknown = set(m) - names
        if unknown:
            raise ValueError(f"unknown trial-import settings {sorted(unknown)} (known: {sorted(names)})")
        if "pad_to_c0_m" in m:
            m["pad_to_c0_m"] = tuple(float(x) for x in m["pad_to_c0_m"])
        return cls(**m)


@dataclass
class ImportResult:
    selected: pd.DataFrame
    max_force: pd.DataFrame
    activation: pd.DataFrame
    activation_by_muscle: pd.DataFrame
    fatigue_dirs: pd.DataFrame
    fatigue: pd.DataFrame
    exclusions: pd.DataFrame
    emg_missing: pd.DataFrame
    summary: dict
    noise: pd.DataFrame = field(default_factory=pd.DataFrame)   # trial-to-trial scatter (trials.noise)


def import_trials(trials_csv: str | Path, directions: pd.DataFrame, settings: ImportSettings | None = None,
                  signals_csv: str | Path | None = None) -> ImportResult:
    """Validate, resolve, match, select, check fatigue and normalise EMG (nothing is written)."""
    s = settings or ImportSettings()
    frames = default_frames(s.pad_to_c0_m, s.frames)
    names = list(directions["name"])
    tr = read_trials(trials_csv, names, tuple(frames))
    if signals_csv is not None:
        tr = emg_mod.envelope_values(signals_csv, tr, s.emg_delay_s, s.emg_window_s)
    tr = emg_mod.normalise(tr, trials_csv)
    res = resolve_trials(tr, directions, frames, MatchSettings(s.angle_deg, s.ratio_tol))
    sel = select_trials(res, s.repeat_rel, s.mismatch_action)
    parts = list(dict.fromkeys(sel["participant"]))
    kept = sel[sel["kept"] & ~sel["direction"].isin(list(CARDINAL))]
    mf = pd.DataFrame({"direction": names})
    for p in parts:
        k = kept[kept["participant"] == p].set_index("direction")["force_N"]
        mf[p] = k.reindex(names).to_numpy(float)
    chans = emg_channels(tr)
    act = pd.DataFrame({"direction": names})
    long_rows = []
    for p in parts:
        k = kept[kept["participant"] == p].set_index("direction")
        vals = []
        for d in names:
            if d not in k.index:
                vals.append(np.nan)
                continue
            a = [float(k.at[d, f"act_{c}"]) for c in chans if np.isfinite(k.at[d, f"act_{c}"])]
            for c in chans:
                long_rows.append({"participant": p, "direction": d, "muscle": c.rsplit("_", 1)[0],
                                  "side": c.rsplit("_", 1)[1], "activation": k.at[d, f"act_{c}"],
                                  "trial": int(k.at[d, "trial"])})
            vals.append(float(np.mean(a)) if a else np.nan)
        act[p] = vals
    by_muscle = pd.DataFrame(long_rows, columns=["participant", "direction", "muscle", "side", "activation", "trial"])
    missing = [{"participant": p, "channel": c} for p in parts for c in chans
               if not np.isfinite(tr.loc[tr["participant"] == p, f"act_{c}"]).any()]
    emg_missing = pd.DataFrame(missing, columns=["participant", "channel"])
    fat_dirs, fat = fatigue_table(sel, s.fatigue_threshold)
    excl = report.exclusions(sel, names)
    noise = repeat_noise(sel, names)
    summary = {"source": str(trials_csv), "signals": None if signals_csv is None else str(signals_csv),
               "neckstrength": __version__, "settings": {**asdict(s), "frames": dict(s.frames)},
               "trials": int(len(sel)), "participants": len(parts), "participant_ids": parts,
               "matched": int(sel["matched"].sum()), "kept": int(sel["kept"].sum()),
               "excluded_trials": int((~sel["kept"]).sum()),
               "excluded_mismatch": int(sel["reason"].str.startswith("direction not matched").sum()),
               "missing_directions": int((excl["what"] == "direction").sum()),
               "fatigued": [r["participant"] for r in fat.to_dict("records") if r["fatigued"]],
               "emg_channels": chans, "emg_missing": missing,
               "noise_log_sd": {r["participant"]: (None if r["df"] == 0 else float(r["noise_log_sd"]))
                                for r in noise.to_dict("records")}}
    summary["settings"]["source"] = str(trials_csv)
    return ImportResult(sel, mf, act, by_muscle, fat_dirs, fat, excl, emg_missing, summary, noise)


def write_import(result: ImportResult, outputs: Mapping[str, str | Path]) -> None:
    """Write every output of an import (keys of :data:`OUTPUT_FILES`), each atomically."""
    s = result.summary
    prov = [f"imported from trials {s['source']} by neckstrength {s['neckstrength']} (neckstrength import-trials)",
            f"direction window {s['settings']['angle_deg']:g} deg / R_fm +- {s['settings']['ratio_tol']:g}, "
            f"mismatched trials: {s['settings']['mismatch_action']}; largest valid trial per direction kept"]
    atomic_write_csv(result.max_force, outputs["max_force"], prov + [
        "units: " + "; ".join(f"{p}=N" for p in result.max_force.columns[1:]),
        "force = wrench along the target unit wrench / the direction's force scale (applied force at the test point)"],
        float_format="%.2f")
    atomic_write_csv(result.activation, outputs["activation"], prov + [
        "units: " + "; ".join(f"{p}=1" for p in result.activation.columns[1:]),
        "activation = mean over the recorded EMG channels of the kept trial, each normalised to its maximum over "
        "all trials and read 250 ms before the peak wrench (per muscle: activation_by_muscle.csv)"],
        float_format="%.4f")
    atomic_write_csv(result.activation_by_muscle, outputs["activation_by_muscle"], prov, float_format="%.4f")
    atomic_write_csv(report.trial_quality(result.selected), outputs["trials"], prov, float_format="%.4g")
    atomic_write_csv(result.exclusions, outputs["exclusions"], prov)
    atomic_write_csv(result.fatigue.merge(result.fatigue_dirs, on="participant", how="left"), outputs["fatigue"],
                     prov + ["change_rel = end / start - 1 of the kept cardinal efforts (N*m)"], float_format="%.4g")
    atomic_write_csv(result.noise, outputs["noise"], prov + [
        "noise_log_sd: pooled within-direction SD of log force over the valid repeats of the test directions "
        "(main block), df = sum (n - 1); ci_low / ci_high: 95% chi-square interval (normal log trials); the "
        "scatter of one trial (docs/trials.md); df 0: no repeats, no value",
        "use: gap.calibration.noise_table (docs/gap_diagnosis.md)"], float_format="%.5g")
    flags = result.selected[result.selected["kept"] & (result.selected["flag"] != "")]
    atomic_write_text(report.markdown(s, result.fatigue, result.exclusions, flags, result.emg_missing),
                      outputs["report"])
    report.quality_figure(result.selected, result.fatigue_dirs, s["settings"], outputs["figure"])
    atomic_write_text(json.dumps(s, indent=2, default=float), outputs["summary"])


def default_outputs(out_dir: str | Path) -> dict[str, Path]:
    return {k: Path(out_dir) / v for k, v in OUTPUT_FILES.items()}


def import_to_folder(trials_csv: str | Path, directions: pd.DataFrame, out_dir: str | Path,
                     settings: ImportSettings | None = None, signals_csv: str | Path | None = None,
                     ) -> tuple[ImportResult, dict[str, Path]]:
    res = import_trials(trials_csv, directions, settings, signals_csv)
    outputs = default_outputs(out_dir)
    write_import(res, outputs)
    return res, outputs


__all__: Sequence[str] = ["ImportSettings", "ImportResult", "import_trials", "write_import", "import_to_folder",
                          "OUTPUT_FILES", "default_outputs"]
