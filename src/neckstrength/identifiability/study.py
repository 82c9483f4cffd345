"""The identifiability study of one model: profiles on the thesis's simulated sets, deficit truths and simulated
participants, per protocol (neutral tests, + postures, + surface EMG bounds), and the distinguishability table."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from neckstrength.identifiability.check import check_against_highs
from neckstrength.identifiability.noise import CHI2_1_95, lr_statistic, sigma_star
from neckstrength.identifiability.profile import (
    Battery,
    ProfileProblem,
    ProfileSettings,
    group_index,
    group_names,
    profile_group,
    strengths_from_factors,
)

PROTOCOLS = ("neutral", "postures", "emg")


@dataclass(frozen=True)
class StudySettings:
    """Config ``identifiability`` for one model (see config/README.md)."""

    profile: ProfileSettings
    groups: tuple[str, ...] | None = None        # profiled on 'norm' and 'weak'; None = every group
    deficit_group: str = "mf"
    deficits: tuple[float, ...] = (0.25, 0.5, 0.75)
    n_participants: int = 4
    population_sd: float = 0.25                  # log-normal sd of every group's factor (participants)
    participant_deficit: float = 0.5             # the deficit group's deficit in the simulated participants
    protocols: tuple[str, ...] = ("neutral", "postures", "emg")
    protocol_grid: tuple[float, ...] = (0.25, 0.5, 0.75, 1.0)   # grid of the postures / EMG profiles
    sigma_ref: float = 0.05                      # noise level at which 'distinguishable' is reported
    check_rtol: float = 1e-6

    def __post_init__(self):
        bad = [p for p in self.protocols if p not in PROTOCOLS]
        if bad:
            raise ValueError(f"unknown identifiability protocols {bad}; known: {PROTOCOLS}")
        if any(not 0 < d < 1 for d in (*self.deficits, self.participant_deficit)):
            raise ValueError("identifiability deficits must be in (0, 1)")
        if self.n_participants < 0 or self.population_sd < 0 or self.sigma_ref <= 0:
            raise ValueError("identifiability: n_participants >= 0, population_sd >= 0, sigma_ref > 0")


@dataclass
class Truth:
    """A data set's true strengths and, where it has one, the deficit group's true factor."""

    name: str
    f: np.ndarray
    deficit_factor: float | None       # deficit group's factor x normal (None: no deficit, e.g. 'norm')
    profile_all: bool                  # profile every configured group (else the deficit group only)


def truths(normal: np.ndarray, weak: np.ndarray, muscle_names: Sequence[str], st: StudySettings,
           rng: np.random.Generator) -> list[Truth]:
    """'norm', 'weak', 'norm' with the deficit group at (1 - deficit), and simulated participants (every group x
    exp(N(0, population_sd^2)), the deficit group then x (1 - participant_deficit))."""
    names = group_names(muscle_names)
    if st.deficit_group not in names:
        raise ValueError(f"identifiability deficit_group {st.deficit_group!r} not in model groups {names}")
    gidx = group_index(muscle_names)
    gi = names.index(st.deficit_group)
    sel = gidx == gi
    weak_factor = float(np.mean(weak[sel] / normal[sel]))
    out = [Truth("norm", normal.copy(), None, True), Truth("weak", weak.copy(), weak_factor, True)]
    for dfc in st.deficits:
        f = normal.copy()
        f[sel] *= 1 - dfc
        out.append(Truth(f"deficit{round(100 * dfc)}", f, 1 - dfc, False))
    for i in range(st.n_participants):
        fac = np.exp(rng.normal(0.0, st.population_sd, len(names)))
        fac[gi] *= 1 - st.participant_deficit
        out.append(Truth(f"participant{i + 1}", strengths_from_factors(normal, gidx, fac)[0], float(fac[gi]), False))
    return out


def run_study(model_name: str, normal: np.ndarray, weak: np.ndarray, batteries: dict[str, Callable[[np.ndarray],
              Battery]], st: StudySettings, rng_for: Callable[[str], np.random.Generator],
              progress: Callable[[str], None] = print) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Profiles and distinguishability of one model.

    ``batteries[protocol](f_true)``: the battery of tests of that protocol for a truth (EMG bounds depend on it).
    ``rng_for(key)``: the seeded stream of one profile (key names model, protocol, data set, group, bounds) and of
    the simulated participants ('participants'). Returns (profiles, distinguishable)."""
    neutral_b = batteries["neutral"](normal)
    names = group_names(neutral_b.muscle_names)
    groups = list(st.groups) if st.groups else names
    unknown = [g for g in groups if g not in names]
    if unknown:
        raise ValueError(f"identifiability groups {unknown} not in {model_name} groups {names}")
    T = truths(normal, weak, neutral_b.muscle_names, st, rng_for("participants"))
    rows = []
    for proto in st.protocols:
        if proto not in batteries:
            progress(f"{model_name}: protocol {proto} not available, skipped")
            continue
        for tr in T:
            if proto != "neutral" and (tr.deficit_factor is None or tr.name.startswith("participant")):
                continue                 # postures / EMG: the deficit truths and 'weak' only (run time)
            t0 = time.time()
            bat = batteries[proto](tr.f)
            w, stat = bat.wrenches(tr.f[None, :])
            if np.any(stat[0] != 0):
                raise ValueError(f"{model_name} {proto}: truth {tr.name} cannot produce tests "
                                 f"{[bat.labels[k] for k in np.flatnonzero(stat[0] != 0)]}")
            prob = ProfileProblem(tr.name, bat, w[0], normal)
            gs = groups if (tr.profile_all and proto == "neutral") else [st.deficit_group]
            ps = st.profile if proto == "neutral" else replace(st.profile, grid=st.protocol_grid)
            for g in gs:
                for bnd in st.profile.bounds:
                    df = profile_group(prob, g, ps, rng_for(f"{proto}/{tr.name}/{g}/{bnd[0]}"), bnd)
                    fcols = [f"f_{n}" for n in names]
                    gidx = group_index(bat.muscle_names)
                    rel = [check_against_highs(bat, strengths_from_factors(normal, gidx, r[fcols].to_numpy(float))[0],
                                               st.check_rtol) for _, r in df.iterrows()]
                    df.insert(0, "protocol", proto)
                    df.insert(0, "model", model_name)
                    df["truth_factor"] = tr.deficit_factor if g == st.deficit_group else np.nan
                    df["highs_max_rel_diff"] = rel
                    rows.append(df)
            progress(f"{model_name} {proto} {tr.name}: {len(gs)} group(s) x {len(st.profile.bounds)} bounds in "
                     f"{time.time() - t0:.1f} s")
    prof = pd.DataFrame(pd.concat(rows, ignore_index=True))
    return prof, distinguishable(prof, st)


def distinguishable(prof: pd.DataFrame, st: StudySettings) -> pd.DataFrame:
    """Per protocol, bounds and deficit truth: RMS of 'normal' (profile at r = 1), sigma* and the LR at sigma_ref."""
    d = prof[(prof["group"] == st.deficit_group) & np.isclose(prof["r"], 1.0) & prof["truth_factor"].notna()
             & (prof["truth_factor"] < 1)]
    if d.empty:
        return pd.DataFrame(columns=["model", "protocol", "bounds", "dataset", "truth_factor", "deficit", "n_tests",
                                     "rms_normal", "max_abs_residual", "sigma_star", f"lr_at_sigma_ref",
                                     "distinguishable_at_sigma_ref"])
    out = d[["model", "protocol", "bounds", "dataset", "truth_factor", "n_tests"]].copy()
    out.insert(5, "deficit", 1 - out["truth_factor"])
    out["rms_normal"] = d["rms"].to_numpy()
    out["max_abs_residual"] = d["max_abs_residual"].to_numpy()
    out["on_bounds"] = (d["on_lower"].fillna("") + " | " + d["on_upper"].fillna("")).to_numpy()
    out["sigma_star"] = sigma_star(out["rms_normal"].to_numpy(), out["n_tests"].to_numpy())
    out["sigma_ref"] = st.sigma_ref
    out["lr_at_sigma_ref"] = [lr_statistic(r, int(n), st.sigma_ref) for r, n in zip(out["rms_normal"], out["n_tests"])]
    out["distinguishable_at_sigma_ref"] = out["lr_at_sigma_ref"] >= CHI2_1_95
    return out.reset_index(drop=True)
