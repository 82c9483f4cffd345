"""Per-data-set results of the gap diagnosis on disk, so an interrupted run resumes where it stopped.

A result is stored under a key made of everything it depends on: the diagnosis settings (all of them, incl.
the seed and the calibration), the model (name, strengths, moment arms), the test directions, the effect
settings, the data set's name and forces, and the code that computes it (:func:`code_fingerprint`: the source of
the gap, solver, model and estimation modules, so results of an older version are not reused after an upgrade). A
changed setting, input or code gives a new key, so a stale result is never reused; files of other keys are left
alone (delete the folder to clean up).
"""

from __future__ import annotations

import hashlib
import os
import pickle
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np

from neckstrength.gap.effects import GapContext
from neckstrength.gap.engine import BlindData, DiagnosisSettings

#: Sub-packages whose source enters :func:`code_fingerprint`.
CODE_PACKAGES = ("gap", "wrench", "model", "estimation", "abc", "seeds.py")
#: Modules of those packages that only render a stored result (the report's text and figures): left out of the
#: fingerprint, so that after a change to the report alone a rerun reuses the stored diagnoses and renders them again.
RENDER_ONLY = ("gap/report.py",)


def fingerprint_files() -> list[Path]:
    """The source files whose content enters :func:`code_fingerprint`, in order."""
    root = Path(__file__).resolve().parents[1]
    out = []
    for pkg in CODE_PACKAGES:
        files = sorted((root / pkg).rglob("*.py")) if (root / pkg).is_dir() else [root / pkg]
        out += [f for f in files if f.relative_to(root).as_posix() not in RENDER_ONLY]
    return out


def code_fingerprint() -> str:
    """Hash of the source files of :data:`CODE_PACKAGES` but :data:`RENDER_ONLY` (any change to them, comments
    included, gives new keys: rerunning costs time, reusing a result of other code could give a wrong answer)."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for f in fingerprint_files():
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def context_fingerprint(ctx: GapContext) -> str:
    h = hashlib.sha256()
    for a in (ctx.model.strengths, ctx.model.moment_arms, ctx.model.JT, ctx.head_centre,
              ctx.directions.select_dtypes("number").to_numpy(float)):
        h.update(np.ascontiguousarray(np.asarray(a, float)).tobytes())
    for name, t in sorted(dict(ctx.postures or {}).items()):     # posture_drift and the posture tests use them
        h.update(name.encode())
        h.update(np.ascontiguousarray(np.r_[t.moment_arms.ravel(), t.centres.ravel(), t.factor_rel]).tobytes())
    h.update(repr((ctx.posture_angle, ctx.force_length)).encode())
    h.update(repr((ctx.model.name, tuple(ctx.model.muscle_names), tuple(ctx.directions["name"]), ctx.emg_groups,
                   ctx.shoulder_muscles, ctx.tie_sides, sorted((k, sorted(dict(v or {}).items()))
                                                           for k, v in dict(ctx.settings).items()))).encode())
    return h.hexdigest()


class ResultStore:
    """``get`` / ``put`` one data set's diagnosis in ``folder`` (pickles, written atomically)."""

    def __init__(self, folder: str | Path, ctx: GapContext, settings: DiagnosisSettings):
        self.folder = Path(folder)
        self.base = hashlib.sha256((context_fingerprint(ctx) + repr(settings) + code_fingerprint()).encode()
                                   ).hexdigest()

    def path(self, data: BlindData) -> Path:
        h = hashlib.sha256(self.base.encode() + data.name.encode() + np.asarray(data.forces, float).tobytes())
        return self.folder / f"{_safe(data.name, 60)}-{h.hexdigest()[:20]}.pkl"

    def get(self, data: BlindData):
        return _load(self.path(data))

    def put(self, data: BlindData, result) -> None:
        _dump(self.path(data), result)


def _safe(name: str, n: int) -> str:
    """``name`` as a file-name prefix: letters, digits, '_', '.', '-' kept, the rest '_', at most ``n`` long."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name)[:n]


def _load(p: Path):
    """The pickle at ``p``, or None if it is missing or unreadable (a partial write is never left there)."""
    if not p.exists():
        return None
    try:
        with open(p, "rb") as fh:
            return pickle.load(fh)
    except (OSError, pickle.UnpicklingError, EOFError):
        return None


def _dump(p: Path, value) -> None:
    """Pickle ``value`` to ``p`` atomically (a temporary file in the same folder, then renamed)."""
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=p.parent, suffix=".tmp")
    with os.fdopen(fd, "wb") as fh:
        pickle.dump(value, fh)
    os.replace(tmp, p)


class Checkpoints:
    """Intermediate results of one batch (each effect's grid fits of each engine, see
    :func:`neckstrength.gap.engine.single_effect_grids`) in ``folder``, so an interrupted batch resumes within the
    batch rather than from its start. The caller removes the folder (:meth:`clear`) once the batch's per-data-set
    results are stored. A part is stored under a key of everything its fits depend on (the context, the engine's
    settings and problems, the code), so a stale part is never reused."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self._code = code_fingerprint()

    def key(self, ctx: GapContext, settings, *arrays, tag: str = "") -> str:
        h = hashlib.sha256((context_fingerprint(ctx) + repr(settings) + self._code + tag).encode())
        for a in arrays:
            h.update(repr(np.shape(a)).encode())
            h.update(np.ascontiguousarray(np.asarray(a, float)).tobytes())
        return h.hexdigest()[:24]

    def _path(self, key: str, part: str) -> Path:
        return self.folder / f"{_safe(part, 40)}-{key}.pkl"

    def get(self, key: str, part: str):
        return _load(self._path(key, part))

    def put(self, key: str, part: str, value) -> None:
        _dump(self._path(key, part), value)

    def clear(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


def batch_checkpoints(store: ResultStore | None, data) -> Checkpoints | None:
    """The :class:`Checkpoints` of a batch of data sets next to ``store``'s results (None without a store)."""
    if store is None:
        return None
    h = hashlib.sha256(store.base.encode())
    for d in data:
        h.update(d.name.encode())
        h.update(np.asarray(d.forces, float).tobytes())
    return Checkpoints(store.folder / "checkpoints" / h.hexdigest()[:20])
