"""estimation.datasets."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from neckstrength.io import read_activations, read_measurements
from neckstrength.model.reduction import ReducedModel
from neckstrength.wrench import solve
from neckstrength.wrench.problem import STATUS_CODES


@dataclass
class Dataset:
    """Measured (or simulated) maximum wrenches in a model's task space."""

    name: str
    directions: list[str]
    U: np.ndarray                      # (K, d) unit wrenches in the model's task space
    w_meas: np.ndarray                 # (K,) wrench magnitudes along U (force x force_scale)
    force_scale: np.ndarray            # (K,) wrench magnitude per N of applied force
    alpha_lb: np.ndarray | None = None  # (K, m) activation bounds (EMG), or None
    alpha_ub: np.ndarray | None = None
    f_true: np.ndarray | None = None   # (m,) for simulated data sets
    postures: list[str] | None = None  # (K,) posture of each test (issue 20); None = all neutral

    @property
    def forces(self) -> np.ndarray:
        return self.w_meas / self.force_scale


WRENCH = ("Mx", "My", "Mz", "Fx", "Fy", "Fz")


RESULT_TABLES = {"p2m7": "table_5_1_p2m7.csv", "p3m12": "table_5_2_p3m12.csv", "s3m24": "table_5_3_s3m24.csv"}


ABBREV_TABLE = {"p2m7": "Table 5.1", "p3m12": "Table 5.2", "s3m24": "Table 5.3"}


def model_directions_table(model: ReducedModel, directions: pd.DataFrame) -> tuple[pd.DataFrame, np.ndarray]:
    d = directions[directions["sagittal"]] if model.planar else directions
    d = d.reset_index(drop=True)
    return d, model.task_direction(d[[f"u_{c}" for c in WRENCH]].to_numpy(float))


def thesis_result_table(thesis_dir: str | Path, model_name: str, table: str | None = None) -> pd.DataFrame:
    """A thesis result table (long format) with the muscle abbreviations mapped to our group names."""
    thesis_dir = Path(thesis_dir)
    table = table or RESULT_TABLES[model_name]
    t = pd.read_csv(thesis_dir / table, comment="#")
    ab = pd.read_csv(thesis_dir / "muscle_abbreviations.csv", comment="#")
    label = {"table_6_1_p2m7_sequential.csv": "Table 6.1"}.get(table, ABBREV_TABLE.get(model_name))
    mapping = dict(zip(ab[ab["table"] == label]["abbrev"], ab[ab["table"] == label]["group"]))
    t["group"] = t["muscle"].map(mapping)
    return t


def thesis_f_actual(model: ReducedModel, thesis_dir: str | Path, dataset: str, table: str | None = None) -> np.ndarray:
    """f_a of a simulated data set, in model muscle order (both sides get the printed value)."""
    t = thesis_result_table(thesis_dir, model.name, table)
    t = t[(t["dataset"] == dataset) & (t["quantity"] == "f_a")]
    if t.empty:
        raise ValueError(f"no f_a for data set {dataset!r} of {model.name} in the thesis tables")
    val = dict(zip(t["group"], t["value_numeric"]))
    f = []
    for name in model.muscle_names:
        g = name[:-2] if (not model.planar and name.endswith(("-R", "-L"))) else name
        if g not in val:
            raise ValueError(f"thesis table has no f_a for group {g!r} (model {model.name})")
        f.append(val[g])
    return np.array(f, float)


def emg_mask(model: ReducedModel, groups: Sequence[str]) -> np.ndarray:
    """Muscles of ``model`` whose activation was recorded by surface EMG (group names, both sides)."""
    keep = set(groups)
    return np.array([(n[:-2] if n.endswith(("-R", "-L")) else n) in keep for n in model.muscle_names])


def simulated_dataset(model: ReducedModel, directions: pd.DataFrame, name: str, f_actual: np.ndarray,
                      emg_groups: Sequence[str] = (), emg_band: float = 0.05) -> Dataset:
    """Simulated measurements ``{w_meas, alpha_meas} = M(f_a, u_i)`` (Sec. 5.3)."""
    d, U = model_directions_table(model, directions)
    w, alpha, status = solve(model, f_actual[None, :], U)
    bad = [d["name"][k] for k in range(len(d)) if STATUS_CODES[int(status[0, k])] != "optimal"]
    if bad:
        raise ValueError(f"{model.name} with f_a cannot produce directions {bad}")
    lb = ub = None
    mask = emg_mask(model, emg_groups)
    if mask.any():
        lb = np.zeros((len(d), model.m))
        ub = np.ones((len(d), model.m))
        lb[:, mask] = np.clip(alpha[0][:, mask] - emg_band, 0.0, 1.0)
        ub[:, mask] = np.clip(alpha[0][:, mask] + emg_band, 0.0, 1.0)
    return Dataset(name, list(d["name"]), U, w[0], d["force_scale"].to_numpy(float), lb, ub, f_actual)


def participant_dataset(model: ReducedModel, directions: pd.DataFrame, participant: str,
                        measurements: str | Path, activations: str | Path | None = None,
                        emg: str = "none", emg_groups: Sequence[str] = (), emg_band: float = 0.2) -> Dataset:
    """Measured maximum forces of one participant (Table A.2 layout) as a data set.

    ``emg``: 'none' (default) ignores Table A.3; 'a3_band' bounds every EMG-recorded group's activation to
    [a - band, a + band] with ``a`` the participant's single activation value of that direction.
    """
    d, U = model_directions_table(model, directions)
    meas = read_measurements(measurements, list(directions["name"]))
    if participant not in meas.columns:
        raise ValueError(f"{measurements}: no column for participant {participant!r}")
    forces = meas[participant].reindex(d["name"]).to_numpy(float)
    if np.isnan(forces).any():
        missing = list(d["name"][np.isnan(forces)])
        raise ValueError(f"{measurements}: participant {participant} has no force for directions {missing}")
    scale = d["force_scale"].to_numpy(float)
    lb = ub = None
    if emg == "a3_band":
        if activations is None:
            raise ValueError("emg='a3_band' needs the activation table")
        act = read_activations(activations, list(directions["name"]))[participant].reindex(d["name"]).to_numpy()
        mask = emg_mask(model, emg_groups)
        lb = np.zeros((len(d), model.m))
        ub = np.ones((len(d), model.m))
        lb[:, mask] = np.clip(act[:, None] - emg_band, 0, 1)
        ub[:, mask] = np.clip(act[:, None] + emg_band, 0, 1)
    elif emg != "none":
        raise ValueError(f"unknown emg option {emg!r}")
    return Dataset(participant, list(d["name"]), U, forces * scale, scale, lb, ub, None)


@dataclass(frozen=True)
class DatasetSettings:
    """How a data set is built from the tables for one model (config ``chapter5`` / ``chapter6``: ``emg_groups`` of
    the model, ``simulated_emg``, ``simulated_emg_band``, ``participant_emg``, ``participant_emg_band``)."""

    emg_groups: tuple[str, ...] = ()       # the model's EMG-recorded groups
    simulated_emg: bool = False            # simulated 'norm'/'weak': bound the EMG groups' activations
    simulated_emg_band: float = 0.05
    participant_emg: str = "none"          # participants: 'none' or 'a3_band' (Table A.3 +- band)
    participant_emg_band: float = 0.2


#: the data sets simulated from the thesis's f_a (Sec. 5.3) rather than read from a measurement table
SIMULATED_DATASETS = ("norm", "weak")


def load_dataset(model: ReducedModel, directions: pd.DataFrame, dataset: str, settings: DatasetSettings,
                 thesis_dir: str | Path, measurements: str | Path, activations: str | Path | None) -> Dataset:
    """Data set ``dataset`` ('norm', 'weak': simulated from the thesis's f_a; else a participant column of
    ``measurements``) for ``model``."""
    s = settings
    if dataset in SIMULATED_DATASETS:
        return simulated_dataset(model, directions, dataset, thesis_f_actual(model, thesis_dir, dataset),
                                 s.emg_groups if s.simulated_emg else (), s.simulated_emg_band)
    return participant_dataset(model, directions, dataset, measurements, activations, s.participant_emg,
                               s.emg_groups, s.participant_emg_band)
