"""A SYNTHETIC lab data set generated from the model (for tests, the README walk-through and new users).

Each participant's true strengths are the s3m24 baseline strengths, scaled to a plausible overall level and
perturbed per muscle group; the max wrench in each test and cardinal direction is the model's (the max-wrench
LP), and every trial is a share of it with the imperfections a lab sees:

- effort: the first trial 88-100% of the maximum, later ones 90-100%; a third trial when the protocol asks;
- direction errors: small (a few degrees) in most trials, 25-45 deg in about one trial in eight, and in about
  one test-direction trial in twenty a moment part 4x too large (an R_fm error);
- noise: 2% log-normal on the magnitude;
- a fatiguing participant (the last one): efforts decline linearly to 75% by the end of the session, so the
  end cardinal efforts are about 25% below the start ones;
- frames: one participant's wrenches are given about the lower posterior pad (frame ``pad``);
- EMG: envelopes of the five Appendix A muscle pairs from the model activations (plus co-activation and noise,
  arbitrary per-channel gain); one participant has no left levator scapulae channel.

Nothing here is a measurement: the files say SYNTHETIC and name this generator and its seed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from neckstrength import __version__
from neckstrength.io import atomic_write_csv
from neckstrength.trials.formats import CARDINAL, EMG_CHANNELS, WRENCH
from neckstrength.trials.resolve import PAD_TO_C0_M, default_frames
from neckstrength.wrench import solve
from neckstrength.seeds import derive_rng

#: s3m24 groups recorded by the Appendix A electrodes (model group -> EMG muscle name)
EMG_GROUPS = {"SCM": "SCM", "trap": "trap", "semicap": "SSCap", "spcap": "SpCap", "levscap": "LS"}


def _rotate(v: np.ndarray, angle_rad: float, rng: np.random.Generator) -> np.ndarray:
    """``v`` rotated by ``angle_rad`` about a random axis perpendicular to it (norm kept)."""
    n = np.linalg.norm(v)
    if n < 1e-12 or angle_rad == 0:
        return v.copy()
    vh = v / n
    a = rng.normal(size=3)
    a -= a @ vh * vh
    a /= np.linalg.norm(a)
    return n * (np.cos(angle_rad) * vh + np.sin(angle_rad) * a)


def _perturb(u: np.ndarray, big: bool, rng: np.random.Generator, ratio_error: bool = False) -> np.ndarray:
    """A produced wrench direction near unit wrench ``u``: moment and force parts rotated, ratio jittered
    (``ratio_error``: the moment part 4x too large, i.e. pushing about the wrong centre of rotation)."""
    ang = np.radians(rng.uniform(25, 45) if big else abs(rng.normal(0, 4)))
    M = _rotate(u[:3], ang if (big and rng.random() < 0.5) else np.radians(abs(rng.normal(0, 4))), rng)
    F = _rotate(u[3:], ang, rng)
    M *= np.exp(rng.normal(0, 0.05)) * (4.0 if ratio_error else 1.0)
    w = np.r_[M, F]
    return w / np.linalg.norm(w)


def generate_example(config: Mapping, seed: int, participants=("P01", "P02", "P03"),
                     levels=(1.0, 0.75, 1.15), repeat_sd: float | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Trial table (the documented format) and the true strengths (s3m24 groups) of a synthetic lab.

    ``repeat_sd``: instead of the effort shares and 2% noise above, every trial is the maximum times
    ``exp(N(0, repeat_sd))`` (full effort, a known trial-to-trial log SD: tests of the repeat-noise estimate)."""
    from neckstrength.config import build_directions, full_model_from_config, model_from_config

    rng = derive_rng(seed, "trials/example")
    model = model_from_config(full_model_from_config(config), config, "s3m24")
    d = build_directions(config)
    names = list(d["name"])
    U6 = np.vstack([d[[f"u_{c}" for c in WRENCH]].to_numpy(float),
                    np.array([np.r_[np.array(m, float), 0, 0, 0] for m in CARDINAL.values()])])
    scale = np.r_[d["force_scale"].to_numpy(float), np.ones(len(CARDINAL))]
    all_names = names + list(CARDINAL)
    Ut = model.task_direction(U6)
    w_base, _, _ = solve(model, model.strengths[None, :], Ut, return_alpha=False)
    back = names.index("back")
    pad = default_frames(PAD_TO_C0_M)["pad"]
    rows, truth = [], []
    emg_idx = {}
    for j, mname in enumerate(model.muscle_names):
        g, side = mname.rsplit("-", 1)
        if g in EMG_GROUPS:
            emg_idx[f"{EMG_GROUPS[g]}_{side}"] = j
    for pi, p in enumerate(participants):
        # overall level: 'back' max force ~ 230 N x level (Table A.2: 215 N on average)
        a = 230.0 * levels[pi] / (w_base[0, back] / scale[back])
        groups = sorted({n.rsplit("-", 1)[0] for n in model.muscle_names})
        gfac = {g: float(np.exp(rng.normal(0, 0.25))) for g in groups}
        f = np.array([model.strengths[j] * a * gfac[n.rsplit("-", 1)[0]] for j, n in enumerate(model.muscle_names)])
        truth += [{"participant": p, "muscle": n, "strength_N": f[j]} for j, n in enumerate(model.muscle_names)]
        w, alpha, _ = solve(model, f[None, :], Ut)
        w, alpha = w[0], alpha[0]
        fatigue = pi == len(participants) - 1
        frame = "pad" if pi == 1 else "skull"
        gain = {c: float(rng.uniform(0.05, 0.4)) for c in EMG_CHANNELS}
        missing = {"LS_L"} if pi == 1 else set()
        order = ([("start", k) for k in range(len(names), len(all_names))]
                 + [("main", k) for k in rng.permutation(len(names))]
                 + [("end", k) for k in range(len(names), len(all_names))])
        n_steps = len(order)
        for step, (block, k) in enumerate(order):
            level = 1.0 - (0.25 * step / (n_steps - 1) if fatigue else 0.0)
            mags = []
            n_trials = 2
            t = 0
            while t < n_trials:
                eff = rng.uniform(0.88, 1.0) if t == 0 else rng.uniform(0.90, 1.0)
                mag = w[k] * level * eff * float(np.exp(rng.normal(0, 0.02)))
                if repeat_sd is not None:
                    eff = 1.0
                    mag = w[k] * level * float(np.exp(rng.normal(0, repeat_sd)))
                mags.append(mag)
                if t == 1 and mags[1] > 1.10 * mags[0]:
                    n_trials = 3
                big = rng.random() < 0.125
                ratio_error = block == "main" and rng.random() < 0.05
                u = _perturb(U6[k], big, rng, ratio_error)
                # magnitude along the target = mag: scale the produced wrench accordingly
                ws = u * (mag / float(u @ U6[k]))
                if frame == "pad":      # measured about the pad centre: M_pad = M_skull - p x F
                    p_pad = np.array(pad.origin)
                    ws = np.r_[ws[:3] - np.cross(p_pad, ws[3:]), ws[3:]]
                row = {"participant": p, "direction": all_names[k], "block": block, "trial": t + 1, "frame": frame}
                row.update({c: ws[i] for i, c in enumerate(WRENCH)})
                for c in EMG_CHANNELS:
                    if c in missing or c not in emg_idx:
                        row[f"emg_{c}"] = np.nan
                        row[f"emgmax_{c}"] = np.nan
                        continue
                    act = 0.12 + 0.85 * float(alpha[k, emg_idx[c]]) * eff * level
                    env = gain[c] * act * float(np.exp(rng.normal(0, 0.1)))
                    row[f"emg_{c}"] = env
                    row[f"emgmax_{c}"] = env * rng.uniform(1.0, 1.15)
                rows.append(row)
                t += 1
    return pd.DataFrame(rows), pd.DataFrame(truth)


def write_example(config: Mapping, out_dir: str | Path, seed: int) -> dict[str, Path]:
    """Write ``trials.csv`` and ``true_strengths.csv`` (both labelled SYNTHETIC, with generator and seed)."""
    trials, truth = generate_example(config, seed)
    out = Path(out_dir)
    hdr = ["SYNTHETIC example lab data (not measurements): generated from the s3m24 model by "
           f"neckstrength.trials.synthetic.generate_example, seed {seed}, neckstrength {__version__}",
           "regenerate: neckstrength example-lab --out <folder> (same seed -> same file)",
           "units: Mx=N*m; My=N*m; Mz=N*m; Fx=N; Fy=N; Fz=N",
           "emg_*: EMG envelope (arbitrary unit) 250 ms before the peak wrench; emgmax_*: that trial's envelope maximum"]
    paths = {"trials": out / "trials.csv", "truth": out / "true_strengths.csv"}
    fmt = trials.copy()
    for c in WRENCH:
        fmt[c] = fmt[c].map("{:.4f}".format if c.startswith("M") else "{:.2f}".format)
    atomic_write_csv(fmt, paths["trials"], hdr, float_format="%.5f")
    atomic_write_csv(truth, paths["truth"], hdr[:2] + ["units: strength_N=N; true strengths of the s3m24 groups"],
                     float_format="%.3f")
    return paths
