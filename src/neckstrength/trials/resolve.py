"""Resolving trial wrenches to the skull frame and checking direction matching (Appendix A, Eq. A.2).

Skull frame: origin at C0-C1, x anterior, y superior, z right. Appendix A estimates C0-C1 "8 cm anterior and
2 cm inferior to the centre of the lower posterior pad", so a wrench measured about the pad centre (frame
``pad``, skull-frame axes) is moved to C0-C1 with ``M_skull = M_pad + (p_pad - p_C0) x F`` where
``p_pad - p_C0 = -(0.08, -0.02, 0)`` m. The offset is a parameter (``pad_to_c0_m``); any other frame is an
origin (in the skull frame, m) and a rotation matrix (its axes in skull coordinates).

Direction matching (Appendix A): a wrench is written as moment unit vector ``M_u``, force unit vector ``F_u``
and ratio ``R_fm = |F| / (|M| + |F|)`` (Eq. A.2, moments in N*m, forces in N). A trial matches its target if
the angles between its ``M_u`` and ``F_u`` and the target's are within ``angle_deg`` (20 deg) and
``|R_fm - R_fm,target|`` is within ``ratio_tol`` (0.10; R_fm is itself a fraction). For a pure-moment target
(R_fm = 0) the force angle is ignored and for a pure-force target the moment angle (Appendix A: "the unit
direction for the other component is meaningless"); cardinal directions are judged on the moment angle only
(Appendix A widened their ratio window to allow for the centre of rotation).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
import pandas as pd

from neckstrength.model.geometry import skew
from neckstrength.trials.formats import CARDINAL, WRENCH

#: C0-C1 relative to the centre of the lower posterior pad, skull-frame axes (m): Appendix A
PAD_TO_C0_M = (0.08, -0.02, 0.0)


@dataclass(frozen=True)
class Frame:
    """A measurement frame: its origin in the skull frame (m) and its axes (columns) in skull coordinates."""

    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: tuple[tuple[float, ...], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def default_frames(pad_to_c0_m=PAD_TO_C0_M, extra: Mapping[str, Mapping] | None = None) -> dict[str, Frame]:
    """``skull`` (identity) and ``pad`` (origin at the pad centre = -pad_to_c0_m), plus ``extra`` frames
    given as ``{name: {origin: [x, y, z], rotation: [[...], [...], [...]]}}``."""
    frames = {"skull": Frame(), "pad": Frame(tuple(-float(x) for x in pad_to_c0_m))}
    for name, spec in (extra or {}).items():
        rot = tuple(tuple(float(v) for v in row) for row in spec.get("rotation", Frame().rotation))
        R = np.array(rot)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
            raise ValueError(f"frame '{name}': rotation must be a 3x3 orthonormal matrix")
        frames[name] = Frame(tuple(float(v) for v in spec.get("origin", (0, 0, 0))), rot)
    return frames


def to_skull(wrench: np.ndarray, frame: Frame) -> np.ndarray:
    """Wrench ``(M, F)`` measured in ``frame`` (about its origin, along its axes) -> skull frame at C0-C1."""
    R = np.array(frame.rotation, float)
    M = R @ np.asarray(wrench[:3], float)
    F = R @ np.asarray(wrench[3:], float)
    p = np.array(frame.origin, float)
    return np.r_[M + skew(p) @ F, F]


def wrench_parts(w: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None, float]:
    """Eq. A.2: ``M_u``, ``F_u`` (None for a zero part) and ``R_fm``."""
    M, F = np.asarray(w[:3], float), np.asarray(w[3:], float)
    m, f = np.linalg.norm(M), np.linalg.norm(F)
    return (M / m if m > 1e-12 else None), (F / f if f > 1e-12 else None), float(f / (m + f)) if m + f > 0 else 0.0


def _angle(a, b) -> float:
    if a is None or b is None:
        return 180.0
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


@dataclass(frozen=True)
class MatchSettings:
    angle_deg: float = 20.0
    ratio_tol: float = 0.10
    pure_tol: float = 0.02           # a target with R_fm below this (or above 1 - this) is a pure moment (force)
    cardinal_moment_only: bool = True


def target_wrenches(directions: pd.DataFrame) -> dict[str, tuple[np.ndarray, float]]:
    """Unit wrench (6,) and force scale (wrench magnitude per N) of every test and cardinal direction."""
    out = {r["name"]: (np.array([r[f"u_{c}"] for c in WRENCH], float), float(r["force_scale"]))
           for r in directions.to_dict("records")}
    for name, m in CARDINAL.items():
        out[name] = (np.r_[np.array(m, float), 0.0, 0.0, 0.0], np.nan)
    return out


def match(w: np.ndarray, target: np.ndarray, s: MatchSettings, cardinal: bool = False) -> dict:
    """Direction-matching errors of skull-frame wrench ``w`` against unit wrench ``target``."""
    Mu, Fu, r = wrench_parts(w)
    tM, tF, tr = wrench_parts(target)
    aM = _angle(Mu, tM) if tr < 1 - s.pure_tol else np.nan
    aF = _angle(Fu, tF) if (tr > s.pure_tol and not cardinal) else np.nan
    dr = np.nan if (cardinal and s.cardinal_moment_only) else abs(r - tr)
    reasons = []
    if np.isfinite(aM) and aM > s.angle_deg:
        reasons.append(f"moment direction off by {aM:.1f} deg (> {s.angle_deg:g})")
    if np.isfinite(aF) and aF > s.angle_deg:
        reasons.append(f"force direction off by {aF:.1f} deg (> {s.angle_deg:g})")
    if np.isfinite(dr) and dr > s.ratio_tol:
        reasons.append(f"R_fm {r:.3f} vs target {tr:.3f} (|error| {dr:.3f} > {s.ratio_tol:g})")
    return {"angle_M_deg": aM, "angle_F_deg": aF, "R_fm": r, "R_fm_target": tr, "R_fm_error": dr,
            "matched": not reasons, "mismatch": "; ".join(reasons)}


def resolve_trials(trials: pd.DataFrame, directions: pd.DataFrame, frames: Mapping[str, Frame],
                   settings: MatchSettings | None = None) -> pd.DataFrame:
    """Skull-frame wrench, matching errors and the measured magnitude of every trial.

    ``magnitude`` = wrench magnitude along the target (``w . u``); ``force_N`` = that / the direction's force
    scale (the applied force at the test point, Table A.2's quantity); cardinal directions: ``moment_Nm`` =
    ``M . m_target``.
    """
    settings = settings or MatchSettings()
    targets = target_wrenches(directions)
    rows = []
    for r in trials.to_dict("records"):
        w = to_skull(np.array([r[c] for c in WRENCH], float), frames[r["frame"]])
        u, scale = targets[r["direction"]]
        card = r["direction"] in CARDINAL
        m = match(w, u, settings, card)
        mag = float(w @ u)
        rows.append({**{f"skull_{c}": w[i] for i, c in enumerate(WRENCH)}, **m, "magnitude": mag,
                     "force_N": np.nan if card else mag / scale, "moment_Nm": mag if card else np.nan})
    return pd.concat([trials.reset_index(drop=True), pd.DataFrame(rows)], axis=1)
