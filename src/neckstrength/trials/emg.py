"""EMG as Appendix A processes it: rectified, filtered, normalised, read 250 ms before the peak wrench.

Appendix A: "EMG records were rectified and filtered using a moving average filter centered over a 250 ms
window. EMG levels were normalized with respect to the maximum value obtained over all trials for each muscle.
The normalized EMG level at the timepoint 250 ms prior to the maximum wrench magnitude for each trial was taken
as the muscle activation level for that trial."

Two inputs: the trial table's ``emg_<channel>`` (envelope at the read-out time, any unit) and optional
``emgmax_<channel>`` (that trial's envelope maximum) columns, or a signals file (raw EMG per sample, its own
time base) that :func:`envelope_values` turns into those columns. :func:`normalise` divides by each
participant's maximum over all trials per channel; a value above 1 after that is an error naming the row.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.io import MAX_SIGNALS_BYTES, Column, DataValidationError, Schema, read_table
from neckstrength.trials.formats import BLOCKS, EMG_CHANNELS, emg_channels


def envelope(t: np.ndarray, x: np.ndarray, window_s: float = 0.25) -> np.ndarray:
    """Full-wave rectified (after removing the mean) and centred moving-average filtered signal."""
    dt = float(np.median(np.diff(t)))
    n = max(1, int(round(window_s / dt)))
    r = np.abs(x - np.mean(x))
    k = np.ones(n) / n
    return np.convolve(r, k, mode="same")


def signals_schema() -> Schema:
    cols = (Column("participant", "str"), Column("direction", "str"),
            Column("block", "str", required=False, allow_missing=True, choices=BLOCKS),
            Column("trial", "int", min=1, max=99), Column("time_s", "float", "s"))
    chan = "|".join(EMG_CHANNELS)
    return Schema("EMG signals", cols, allow_extra_columns=False,
                  pattern_columns=((rf"({chan})", Column("", "float", None, allow_missing=True)),))


def envelope_values(signals_path: str | Path, trials: pd.DataFrame, delay_s: float = 0.25,
                    window_s: float = 0.25) -> pd.DataFrame:
    """Fill ``emg_<ch>`` (envelope ``delay_s`` before ``peak_time_s``) and ``emgmax_<ch>`` from a signals file.

    Signals file (long CSV): participant, direction, [block], trial, time_s, one column per channel (``SCM_R``,
    ...), one row per sample. Every trial in it must be in the trial table with a ``peak_time_s``.
    """
    sig = read_table(signals_path, signals_schema(), max_bytes=MAX_SIGNALS_BYTES)     # one row per sample
    n_comment = len(sig.attrs.get("comments", []))
    if "block" not in sig.columns:
        sig["block"] = "main"
    sig["block"] = [b if b else "main" for b in sig["block"]]
    chans = [c for c in EMG_CHANNELS if c in sig.columns]
    out = trials.copy()
    for c in chans:
        out[f"emg_{c}"] = np.nan
        out[f"emgmax_{c}"] = np.nan
    key = {(r.participant, r.direction, r.block, r.trial): r.Index for r in out.itertuples()}
    sig["_row"] = np.arange(1, len(sig) + 1)
    for k, g in sig.groupby(["participant", "direction", "block", "trial"], sort=False):
        row0 = int(g["_row"].iloc[0])
        if k not in key:
            raise DataValidationError(signals_path, f"trial {k} is not in the trial table", row0, row0 + n_comment + 1,
                                      "trial")
        i = key[k]
        t = g["time_s"].to_numpy(float)
        if len(t) < 3 or np.any(np.diff(t) <= 0):
            raise DataValidationError(signals_path, f"time_s of trial {k} must increase strictly (>= 3 samples)",
                                      row0, row0 + n_comment + 1, "time_s")
        pk = out.at[i, "peak_time_s"] if "peak_time_s" in out.columns else np.nan
        if not np.isfinite(pk):
            raise DataValidationError(trials.attrs.get("source", "trial table"), f"trial {k} has EMG signals but no "
                                      "peak_time_s", int(out.at[i, "row"]), int(out.at[i, "line"]), "peak_time_s")
        tq = pk - delay_s
        if tq < t[0] or tq > t[-1]:
            raise DataValidationError(signals_path, f"trial {k}: read-out time {tq:.3f} s (peak {pk:.3f} s - "
                                      f"{delay_s} s) outside the recorded {t[0]:.3f}..{t[-1]:.3f} s",
                                      row0, row0 + n_comment + 1, "time_s")
        for c in chans:
            x = g[c].to_numpy(float)
            if np.isnan(x).all():
                continue
            if np.isnan(x).any():
                bad = int(g["_row"].to_numpy()[np.isnan(x)][0])
                raise DataValidationError(signals_path, "missing sample inside a recorded channel", bad,
                                          bad + n_comment + 1, c)
            env = envelope(t, x, window_s)
            out.at[i, f"emg_{c}"] = float(np.interp(tq, t, env))
            out.at[i, f"emgmax_{c}"] = float(env.max())
    return out


def normalise(trials: pd.DataFrame, path: str | Path | None = None, tol: float = 1e-9) -> pd.DataFrame:
    """Columns ``act_<ch>`` = ``emg_<ch>`` / (participant's max over all trials of ``emgmax_<ch>`` or ``emg_<ch>``).

    A channel with no positive value for a participant stays NaN (not recorded). Raises
    :class:`DataValidationError` (row, field) for a normalised value outside [0, 1].
    """
    path = path or trials.attrs.get("source", "trial table")
    out = trials.copy()
    for c in emg_channels(trials):
        v = out[f"emg_{c}"].astype(float)
        ref = out[f"emgmax_{c}"].astype(float) if f"emgmax_{c}" in out.columns else v
        norm = ref.groupby(out["participant"]).transform("max")
        act = v / norm.where(norm > 0)
        bad = act[(act > 1 + tol) | (act < -tol)]
        if len(bad):
            i = bad.index[0]
            raise DataValidationError(path, f"EMG normalised to {act[i]:.3f}, outside [0, 1]: the value exceeds the "
                                      f"channel's maximum over all trials ({norm[i]:g}); check emgmax_{c}",
                                      int(out.at[i, "row"]), int(out.at[i, "line"]), f"emg_{c}")
        out[f"act_{c}"] = act.clip(0.0, 1.0)
    return out
