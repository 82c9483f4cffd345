"""Optional C3D reader: load-cell and EMG analog channels -> trial-table rows and an EMG signals table.

Needs the ``c3d`` extra (``pip install 'neckstrength[c3d]'``, which installs ezc3d); ezc3d is imported only
when a file is read. One C3D file holds one trial. A manifest CSV names each file's trial::

    path,participant,direction,block,trial,frame
    P01_back_1.c3d,P01,back,main,1,pad

Channel labels default to ``Fx Fy Fz Mx My Mz`` (load cell) and ``SCM_R SCM_L ... LS_L`` (EMG, the trial
table's channel names); ``channels`` maps our names to other labels (``{"Fx": "Force.Fx1", ...}``). Units are
taken from the file's ``ANALOG:UNITS``: forces N (kN scaled), moments N*m (N*mm / Nmm scaled). The wrench is
averaged over 100 ms (Appendix A: the feedback and matching window) and the peak is the sample where its
component along the target unit wrench (in the trial's frame, after resolution to the skull frame) is largest.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from neckstrength.io import Column, DataValidationError, Schema, read_table
from neckstrength.trials.formats import BLOCKS, EMG_CHANNELS, WRENCH
from neckstrength.trials.resolve import Frame, default_frames, target_wrenches, to_skull

_FORCE_SCALE = {"n": 1.0, "kn": 1000.0}
_MOMENT_SCALE = {"n*m": 1.0, "nm": 1.0, "n.m": 1.0, "n m": 1.0, "n*mm": 1e-3, "nmm": 1e-3, "n.mm": 1e-3,
                 "n mm": 1e-3}


def not_a_regular_file(path: str | Path) -> str | None:
    """Why ``path`` cannot be a C3D file (missing, a folder, a device or pipe), or None for a regular file."""
    path = Path(path)
    if not path.exists():
        return "file not found"
    if path.is_dir():
        return "is a folder, not a C3D file"
    if not path.is_file():
        return "is not a regular file (a device, pipe or socket), not a C3D file"
    return None


def c3d_header_frames(path: str | Path) -> dict:
    """The frame counts the C3D header announces and the file size they need (read from the 512-byte header and the
    parameter section's processor type, without ezc3d).

    Returns ``{'frames', 'analog_per_frame', 'points', 'data_start', 'needed_bytes'}`` (``frames`` None when the
    16-bit header field is saturated and the count lives only in the parameters); raises
    :class:`DataValidationError` for a file too short to hold its header.
    """
    import struct

    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(512)
        if len(head) < 512:
            raise DataValidationError(path, f"truncated: {size} bytes, shorter than the 512-byte C3D header")
        fh.seek(max(head[0] - 1, 0) * 512 + 3)     # parameter section, byte 4: processor type
        proc = fh.read(1)
    proc = proc[0] if proc else 84
    endian = ">" if proc == 86 else "<"        # 84 Intel, 85 DEC: little-endian integers; 86 MIPS: big-endian
    points, analog_total, first, last = struct.unpack(endian + "HHHH", head[2:10])
    if proc == 85:                              # DEC float: the sign is the top bit of the first 16-bit word
        negative = bool(head[13] & 0x80)
    else:
        negative = struct.unpack(endian + "f", head[12:16])[0] < 0
    data_start = struct.unpack(endian + "H", head[16:18])[0]
    frames = last - first + 1 if last != 0xFFFF and last >= first else None
    word = 4 if negative else 2                 # float data when the scale factor is negative
    needed = (data_start - 1) * 512 + (frames or 0) * (4 * points + analog_total) * word
    return {"frames": frames, "analog_per_frame": analog_total, "points": points, "data_start": data_start,
            "needed_bytes": needed, "size": size, "word": word}


def load_c3d(path: str | Path) -> tuple[list[str], list[str], float, np.ndarray]:
    """Analog labels, units, rate (Hz) and data (channels x samples) of a C3D file (needs ezc3d).

    A path that is not a regular file is refused before it is opened; a file shorter than its header's frame count
    needs, or whose analog data is shorter than the header announces, is refused as truncated.
    """
    try:
        import ezc3d
    except ImportError as exc:  # pragma: no cover - depends on the optional extra
        raise ImportError("reading C3D files needs the optional extra: pip install 'neckstrength[c3d]'") from exc
    path = Path(path)
    why = not_a_regular_file(path)
    if why:
        raise DataValidationError(path, why)
    h = c3d_header_frames(path)
    if h["frames"] is not None and h["size"] < h["needed_bytes"]:
        raise DataValidationError(path, f"truncated: the header announces {h['frames']} frames, which need "
                                        f"{h['needed_bytes']} bytes; the file has {h['size']}")
    try:
        c = ezc3d.c3d(str(path))
    except Exception as exc:
        raise DataValidationError(path, f"cannot read as C3D ({exc})") from None
    a = c["parameters"]["ANALOG"]
    labels = [str(x).strip() for x in a["LABELS"]["value"]]
    units = [str(x).strip() for x in a.get("UNITS", {}).get("value", [""] * len(labels))]
    units += [""] * (len(labels) - len(units))
    rate = float(np.atleast_1d(a["RATE"]["value"])[0])
    data = np.asarray(c["data"]["analogs"], float)[0]
    if h["frames"] is not None and h["points"] + h["analog_per_frame"] > 0 and len(labels):
        expected = h["frames"] * (h["analog_per_frame"] // len(labels))
        if data.shape[-1] != expected:
            raise DataValidationError(path, f"truncated: {data.shape[-1]} analog samples per channel, the header "
                                            f"announces {expected} ({h['frames']} frames)")
    return labels, units, rate, data


def trial_from_analogs(labels: Sequence[str], units: Sequence[str], rate: float, data: np.ndarray,
                       target: np.ndarray, frame: Frame, channels: Mapping[str, str] | None = None,
                       path: str | Path = "C3D file", window_s: float = 0.1) -> tuple[dict, pd.DataFrame]:
    """Peak wrench (in the trial's frame), its time, and the EMG signals of one trial from analog channels."""
    channels = dict(channels or {})
    idx = {lab: i for i, lab in enumerate(labels)}
    w = np.zeros((6, data.shape[1]))
    for k, c in enumerate(WRENCH):
        lab = channels.get(c, c)
        if lab not in idx:
            raise DataValidationError(path, f"no analog channel '{lab}' for {c} (labels: {', '.join(labels)})",
                                      field_name=c)
        u = units[idx[lab]].lower().replace(" ", "") if units[idx[lab]] else ("n" if k >= 3 else "n*m")
        table = _FORCE_SCALE if k >= 3 else _MOMENT_SCALE
        if u not in {x.replace(" ", "") for x in table}:
            raise DataValidationError(path, f"unit '{units[idx[lab]]}' of channel '{lab}' is not a "
                                      f"{'force (N, kN)' if k >= 3 else 'moment (N*m, N*mm)'} unit", field_name=c)
        scale = {x.replace(" ", ""): v for x, v in table.items()}[u]
        w[k] = data[idx[lab]] * scale
    n = max(1, int(round(window_s * rate)))
    kern = np.ones(n) / n
    wa = np.vstack([np.convolve(row, kern, mode="same") for row in w])
    skull = np.array([to_skull(wa[:, j], frame) for j in range(wa.shape[1])])
    j = int(np.argmax(skull @ target))
    t = np.arange(data.shape[1]) / rate
    row = {c: float(wa[k, j]) for k, c in enumerate(WRENCH)}
    row["peak_time_s"] = float(t[j])
    sig = {"time_s": t}
    for c in EMG_CHANNELS:
        lab = channels.get(c, c)
        if lab in idx:
            sig[c] = data[idx[lab]]
    return row, pd.DataFrame(sig)


MANIFEST_SCHEMA = Schema("C3D manifest", (Column("path", "str"), Column("participant", "str"),
                                          Column("direction", "str"),
                                          Column("block", "str", required=False, allow_missing=True, choices=BLOCKS),
                                          Column("trial", "int", min=1, max=99), Column("frame", "str")),
                         allow_extra_columns=False)


def c3d_to_tables(manifest: str | Path, directions: pd.DataFrame, channels: Mapping[str, str] | None = None,
                  frames: Mapping[str, Frame] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Trial table and EMG signals table (the documented formats) from the C3D files of a manifest."""
    m = read_table(manifest, MANIFEST_SCHEMA)
    frames = dict(frames or default_frames())
    targets = target_wrenches(directions)
    n_comment = len(m.attrs.get("comments", []))
    for i, r in enumerate(m.to_dict("records")):      # every entry a regular file, before any is read
        p = Path(r["path"]) if Path(r["path"]).is_absolute() else Path(manifest).parent / r["path"]
        why = not_a_regular_file(p)
        if why:
            raise DataValidationError(manifest, f"{p}: {why}", i + 1, n_comment + 2 + i, "path")
    rows, sigs = [], []
    for i, r in enumerate(m.to_dict("records")):
        line = n_comment + 2 + i
        if r["direction"] not in targets:
            raise DataValidationError(manifest, f"unknown test direction '{r['direction']}'", i + 1, line, "direction")
        if r["frame"] not in frames:
            raise DataValidationError(manifest, f"unknown frame '{r['frame']}' (known: {', '.join(frames)})",
                                      i + 1, line, "frame")
        p = Path(r["path"])
        if not p.is_absolute():
            p = Path(manifest).parent / p
        labels, units, rate, data = load_c3d(p)
        row, sig = trial_from_analogs(labels, units, rate, data, targets[r["direction"]][0], frames[r["frame"]],
                                      channels, p)
        block = r.get("block") or "main"
        rows.append({"participant": r["participant"], "direction": r["direction"], "block": block,
                     "trial": r["trial"], "frame": r["frame"], **row})
        sig.insert(0, "trial", r["trial"])
        sig.insert(0, "block", block)
        sig.insert(0, "direction", r["direction"])
        sig.insert(0, "participant", r["participant"])
        sigs.append(sig)
    return pd.DataFrame(rows), pd.concat(sigs, ignore_index=True)
