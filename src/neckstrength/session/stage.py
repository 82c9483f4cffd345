"""The clinician session as a stage: :class:`SessionInputs` in, :class:`SessionResult` out, :func:`write_session`
================================================================================================================

A session is built from :class:`~neckstrength.session.settings.SessionSettings` (what the config fixes) and
:class:`SessionInputs` (the reduced model, its directions, where to push, the posture models), both made once by
:func:`neckstrength.config.session_stage` from the config and the session's options; the engine
(:class:`~neckstrength.session.state.Session`) reads no config and no file besides its own folder. Each step
(:meth:`~neckstrength.session.state.Session.tell`) returns its record in memory; the session's end result
(:meth:`~neckstrength.session.state.Session.result`: the estimate, the per-step trajectory, the measurements, with
their header lines) is a :class:`SessionResult` in memory, and :func:`write_session` writes its four files
(``summary.csv``, ``steps.csv``, ``measurements.csv``, ``summary.png``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.model.reduction import ReducedModel

#: The files :func:`write_session` writes (keys of its answer -> file names in the session folder).
SESSION_FILES = {"summary_csv": "summary.csv", "summary_png": "summary.png", "steps_csv": "steps.csv",
                 "measurements_csv": "measurements.csv"}


@dataclass(frozen=True)
class SessionInputs:
    """What a session of one model reads besides its settings: the reduced ``model``, its ``directions`` table (one
    row per direction: ``name``, ``force_scale``, point and normal) and unit wrenches ``U``, ``push`` (direction ->
    where the pad sits and which way the head pushes, for the screen) and, for a session in several postures, the
    resolved ``postures`` (neutral first) and their models ``pset`` (None: neutral only)."""

    model: ReducedModel
    directions: pd.DataFrame
    U: np.ndarray
    push: dict
    postures: list[str] | None
    pset: object | None


@dataclass
class SessionResult:
    """A session's result in memory (what a stop writes): ``estimate`` per muscle (``summary.csv``) under the
    ``header`` lines, the per-step ``steps`` (iteration 0 = prior; ``steps.csv`` under the header's first two lines),
    the ``measurements`` in order (``measurements.csv``, the format replay reads, under ``measurements_header``) and
    the figure's ``title``."""

    estimate: pd.DataFrame
    header: list[str]
    steps: pd.DataFrame
    measurements: pd.DataFrame
    measurements_header: list[str]
    title: str


def write_session(result: SessionResult, out: str | Path) -> dict[str, Path]:
    """Write ``result``'s four files into the session folder ``out``; returns their paths (keys of
    :data:`SESSION_FILES`)."""
    from neckstrength.io import atomic_write_csv
    from neckstrength.session.plots import summary_figure

    out = Path(out)
    paths = {k: out / v for k, v in SESSION_FILES.items()}
    atomic_write_csv(result.estimate, paths["summary_csv"], result.header, float_format="%.6g")
    atomic_write_csv(result.steps, paths["steps_csv"], result.header[:2], float_format="%.6g")
    atomic_write_csv(result.measurements, paths["measurements_csv"], result.measurements_header)
    summary_figure(result.steps, result.estimate, paths["summary_png"], result.title)
    return paths
