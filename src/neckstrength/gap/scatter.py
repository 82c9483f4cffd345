"""Aiming scatter: a push direction that misses the target by a random angle in each test (issue 32, item 1).

A participant who aims each test's push a few degrees off the target, in a direction that differs from test to test,
changes each test's maximum force by ``log F(n') - log F(n)``: zero on average over the aim (with the benchmark's
truths and true strengths, ``benchmarks/bench_gap_truth_signatures.py``: mean -0.031 to +0.033, 36-72 % of tests
lower, for cones of 7-15 deg), but with a spread that grows with how sharply the test's force depends on its
direction (SD 0.05-0.15 in log). No candidate that changes the predicted *mean* force can explain it: the largest
force inside the cone (the window hypothesis of ``direction_tolerance``) raises every test (+0.09 to +0.22 in log)
and is uncorrelated with it (-0.19 to +0.28), and the mean over the cone moves the forces by SD 0.018-0.058 only.
Repeat trials of one test share its aim, so the repeats' scatter does not see it either. What it leaves is **excess
scatter shaped by direction sensitivity**: for an aim uniform in a cone of half-angle ``c``, ``E[r_k^2] = s^2 + v_k
c^2 / (2 a^2)`` for the log residual ``r_k`` of test ``k``, where ``v_k`` is the mean squared change of the fitted
model's log force over a ring of directions at angle ``a`` around the target (:func:`direction_sensitivity`).

**Test.** The slope of the squared held-out log residuals on ``v_k`` (least squares), its p-value from
``permutations`` random reassignments of ``v`` to the tests (exact where the residuals' sizes do not depend on the
tests' direction sensitivity, e.g. measurement noise about the true forces; *not* exact on a fitted model's
held-out residuals, whose prediction error is larger at direction-sensitive tests: heuristic there). Cone estimate:
``c = a sqrt(2 max(slope, 0))`` (heuristic: the ring's mean square stands in for the squared gradient; checked by
the benchmark's direction-error truths, not by a calibration).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from neckstrength.model.reduction import ReducedModel
from neckstrength.wrench import solve


@dataclass(frozen=True)
class ScatterSettings:
    """``ring_deg``: angle ``a`` of the ring of directions (deg); ``ring_points``: directions on it (spatial
    models; planar: the two in-plane tilts); ``permutations``; ``alpha``: the level the decision's step uses
    (:func:`neckstrength.gap.diagnose._aim_scatter`)."""

    ring_deg: float = 10.0
    ring_points: int = 8
    permutations: int = 9999
    alpha: float = 0.01


def _rot(v: np.ndarray, axis: np.ndarray, ang: float) -> np.ndarray:
    return v * np.cos(ang) + np.cross(axis, v) * np.sin(ang) + axis * np.dot(axis, v) * (1 - np.cos(ang))


def _perp(n: np.ndarray) -> np.ndarray:
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e = a - np.dot(a, n) * n
    return e / np.linalg.norm(e)


def _force_along(model: ReducedModel, f: np.ndarray, P: np.ndarray, N: np.ndarray) -> np.ndarray:
    W = np.hstack([np.cross(P, N), N])
    s = np.linalg.norm(W, axis=1)
    U = model.task_direction(W / s[:, None])
    w, _, _ = solve(model, np.asarray(f, float)[None, :], U, return_alpha=False)
    return w[0] / s


def direction_sensitivity(model: ReducedModel, strengths: np.ndarray, P: np.ndarray, N: np.ndarray,
                          s: ScatterSettings = ScatterSettings()) -> np.ndarray:
    """Per test: mean squared change of the log max force (``strengths``: the fitted group strengths, N) when the
    push direction ``N[k]`` at ``P[k]`` tilts by ``ring_deg`` towards ``ring_points`` directions around it (planar
    models: in the plane, both ways). A direction the model cannot push in counts as the target's force."""
    P = np.asarray(P, float)
    N = np.asarray(N, float)
    N = N / np.linalg.norm(N, axis=1, keepdims=True)
    a = np.radians(float(s.ring_deg))
    dirs = []
    for n in N:
        if model.planar:
            z = np.array([0.0, 0.0, 1.0])
            dirs.append([_rot(n, z, a), _rot(n, z, -a)])
        else:
            e1 = _perp(n)
            dirs.append([_rot(n, _rot(e1, n, 2 * np.pi * j / s.ring_points), a) for j in range(s.ring_points)])
    D = np.array(dirs)                                        # K x J x 3
    K, J = D.shape[:2]
    f0 = _force_along(model, strengths, P, N)
    fr = _force_along(model, strengths, np.repeat(P, J, axis=0), D.reshape(-1, 3)).reshape(K, J)
    ok = (f0[:, None] > 0) & (fr > 0)
    lr = np.where(ok, np.log(np.where(ok, fr, 1.0) / np.where(f0 > 0, f0, 1.0)[:, None]), 0.0)
    return (lr ** 2).mean(axis=1)


def scatter_test(logres: np.ndarray, v: np.ndarray, rng: np.random.Generator,
                 s: ScatterSettings = ScatterSettings()) -> dict:
    """Slope of ``logres**2`` on ``v`` (per test), its permutation p-value and the cone it implies (deg)."""
    r2 = np.asarray(logres, float) ** 2
    v = np.asarray(v, float)
    ok = np.isfinite(r2) & np.isfinite(v)
    r2, v = r2[ok], v[ok]
    vc = v - v.mean()
    den = float((vc ** 2).sum())
    if len(v) < 3 or den <= 0:
        return {"slope": np.nan, "p": np.nan, "cone_deg": np.nan, "excess_share": np.nan}
    slope = float(vc @ r2 / den)
    perm = np.array([rng.permutation(vc) for _ in range(int(s.permutations))])
    slopes = perm @ r2 / den
    p = float((1 + (slopes >= slope - 1e-15).sum()) / (len(slopes) + 1))
    cone = float(s.ring_deg * np.sqrt(2 * max(slope, 0.0)))
    expl = float(slope * v.mean() / r2.mean()) if r2.mean() > 0 else np.nan
    return {"slope": slope, "p": p, "cone_deg": cone, "excess_share": expl}
