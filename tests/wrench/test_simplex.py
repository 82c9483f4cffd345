"""The compiled dual simplex of the batched solver (neckstrength.wrench.simplex) on arbitrary strength vectors.

Property-based: hypothesis draws the model (p2m7, p3m12, s3m24, the 96-muscle s7), the candidate
distribution (prior draws with independent or tied sides, local log-normal draws, the 3-point grid,
log-uniform, zeroed muscles), the spread, EMG-like activation lower bounds (feasible and infeasible)
and extra random directions. Over 100,000 LPs in all, every answer is checked in bulk:

* primal: the returned activations satisfy their bounds and the torque balance ``R (f alpha) = w b``,
  so ``w <= w*``;
* dual: a vector ``y`` with ``b . y = 1`` is rebuilt from the answer alone (complementary
  slackness: ``r_j . y = 0`` for every muscle strictly between its bounds, least squares), and
  weak duality gives ``w* <= U(y) = sum_j f_j max(lb_j r_j . y, ub_j r_j . y)``. ``U(y) - w <=
  1e-9 max(w, 1)`` certifies ``w`` to the criterion of ``test_batched.py`` without any LP solver.

Answers without such a certificate (degenerate optima where ``y`` is not determined, zero and
infeasible statuses) and a fixed random subsample of the others are compared with HiGHS
(``max_wrench``, one call per LP): ``w`` to 1e-9 relative (absolute below 1), equal statuses.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_batched import CODE, REL, assert_agrees, get_model, pair_index, unit

from neckstrength.wrench import batched
from neckstrength.wrench.batched import BasisCache, DirectionSolver, max_wrench_batched
from neckstrength.wrench.highs import max_wrench

MODELS = ("p2m7", "p3m12", "s3m24", "s7")
#: candidates per example (x 7 + 3 directions for p2m7/p3m12, x 25 + 3 for s3m24/s7)
PER_EXAMPLE = {"p2m7": 400, "p3m12": 400, "s3m24": 160, "s7": 24}
HIGHS_SAMPLE = 12        # certified answers per example also compared with HiGHS


def draw_candidates(rng, model, kind, n, spread):
    f0 = model.strengths
    m = f0.size
    pidx = pair_index(model) if model.n > 3 and m < 96 else np.arange(m)
    g = int(pidx.max()) + 1
    if kind == "prior":          # Chapter 6: N(f_0, (spread f_0)^2), independent columns
        F = f0 * np.clip(1 + spread * rng.standard_normal((n, m)), 0, None)
    elif kind == "tied":         # ... left and right tied
        F = f0 * np.clip(1 + spread * rng.standard_normal((n, g)), 0, None)[:, pidx]
    elif kind == "local":        # resample-move: log-normal around one point
        f1 = f0 * np.clip(1 + 0.3 * rng.standard_normal(m), 0.05, None)
        F = f1 * np.exp(spread / 4 * rng.standard_normal((n, m)))
    elif kind == "grid3":
        F = f0 * (1 + spread * rng.integers(-1, 2, size=(n, g)))[:, pidx]
    elif kind == "loguniform":
        F = f0 * np.exp(rng.uniform(-np.log(3), np.log(3), size=(n, m)))
    else:                        # zeros: removed muscles on top of prior draws
        F = f0 * np.clip(1 + spread * rng.standard_normal((n, m)), 0, None)
        F[rng.random((n, m)) < 0.15] = 0.0
    return np.ascontiguousarray(np.maximum(F, 0.0))


def dual_certified(model, F, U, w, alpha, status, lbs, ubs):
    """(N, K) bool: the answer carries a weak-duality certificate rebuilt from alpha (see module doc)."""
    R = model.moment_arms
    n, m = R.shape
    N, K = w.shape
    out = np.zeros((N, K), bool)
    for k in range(K):
        b = model.JT @ U[k]
        ok = status[:, k] == CODE["optimal"]
        if not ok.any() or not np.any(b):
            continue
        a, f, wk = alpha[ok, k], F[ok], w[ok, k]
        lb, ub = lbs[k], ubs[k]
        inner = (a > lb + 1e-9) & (a < ub - 1e-9) & (f > 0)
        # least squares: r_j . y = 0 (j inner), b . y = 1
        Rn = R / np.maximum(np.linalg.norm(R, axis=0), 1e-300)
        M = np.zeros((a.shape[0], m + 1, n))
        M[:, :m, :] = np.where(inner[:, :, None], Rn.T[None, :, :], 0.0)
        M[:, m, :] = b / np.linalg.norm(b)
        t = np.zeros((a.shape[0], m + 1))
        t[:, m] = 1.0 / np.linalg.norm(b)
        y = np.einsum("nij,nj->ni", np.linalg.pinv(M, rcond=1e-12), t)
        by = y @ b
        good = np.abs(by) > 0.5
        y = y / np.where(good, by, 1.0)[:, None]
        c = y @ R                                                  # r_j . y
        Ub = np.sum(f * np.maximum(lb * c, ub * c), axis=1)       # weak-duality bound on w*
        cert = good & np.isfinite(Ub) & (Ub - wk <= REL * np.maximum(wk, 1.0))
        out[np.flatnonzero(ok)[cert], k] = True
    return out


@st.composite
def examples(draw):
    name = draw(st.sampled_from(MODELS))
    kind = draw(st.sampled_from(["prior", "tied", "local", "grid3", "loguniform", "zeros"]))
    spread = draw(st.sampled_from([0.05, 0.2, 0.3, 0.5]))
    lb_kind = draw(st.sampled_from(["none", "none", "emg", "emg_high"]))
    seed = draw(st.integers(0, 2**32 - 1))
    return name, kind, spread, lb_kind, seed


def check_example(name, kind, spread, lb_kind, seed, counts):
    rng = np.random.default_rng(seed)
    model, U_real, _ = get_model(name, 1)
    U = np.vstack([U_real, unit(rng, 3, U_real.shape[1])])
    K, m = U.shape[0], model.m
    F = draw_candidates(rng, model, kind, PER_EXAMPLE[name], spread)
    lbs = np.zeros((K, m))
    if lb_kind != "none":        # EMG-like lower bounds on a few muscles per direction (some infeasible)
        hi = 0.05 if lb_kind == "emg" else 0.3
        lbs = np.where(rng.random((K, m)) < 0.3, rng.uniform(0, hi, (K, m)), 0.0)
    ubs = np.ones((K, m))
    cache = BasisCache()
    w, alpha, status = max_wrench_batched(model, F, U, lbs, ubs, cache=cache)
    st_ = cache.stats()
    counts["lps"] += w.size
    counts["simplex"] += st_["simplex_solved"]
    # primal: bounds and torque balance
    ok = (status == CODE["optimal"]) | (status == CODE["zero"])
    for k in range(K):
        sel = ok[:, k]
        a = alpha[sel, k]
        assert np.all(a >= lbs[k] - 1e-9) and np.all(a <= ubs[k] + 1e-9)
        b = model.JT @ U[k]
        resid = (F[sel] * a) @ model.moment_arms.T - w[sel, k][:, None] * b[None, :]
        scale = (F[sel] * ubs[k]) @ np.abs(model.moment_arms).T + 1.0
        assert np.all(np.abs(resid) <= 1e-8 * scale)
    # dual certificate for every optimal answer; HiGHS for the rest and a random sample
    cert = dual_certified(model, F, U, w, alpha, status, lbs, ubs)
    counts["certified"] += int(cert.sum())
    check = ~cert
    idx = np.argwhere(cert)
    if idx.size:
        pick = idx[rng.choice(len(idx), size=min(HIGHS_SAMPLE, len(idx)), replace=False)]
        check[pick[:, 0], pick[:, 1]] = True
    for i, k in np.argwhere(check):
        r = max_wrench(model.moment_arms, model.JT, F[i], U[k], lbs[k], ubs[k])
        counts["highs"] += 1
        assert CODE[r.status] == status[i, k], (name, kind, i, k, r.status, status[i, k], r.w, w[i, k])
        if np.isfinite(r.w):
            assert abs(w[i, k] - r.w) <= REL * max(abs(r.w), 1.0), (name, kind, i, k, r.w, w[i, k])


def test_property_simplex_exact_on_arbitrary_candidates():
    """>= 100,000 LPs from hypothesis-drawn workloads: every answer certified (dual) or equal to HiGHS."""
    counts = {"lps": 0, "simplex": 0, "certified": 0, "highs": 0}

    @settings(max_examples=45, derandomize=True, database=None, deadline=None,
              suppress_health_check=[HealthCheck.too_slow])
    @given(examples())
    def run(ex):
        check_example(*ex, counts)

    run()
    print(counts)
    assert counts["lps"] >= 100_000
    assert counts["simplex"] >= 0.2 * counts["lps"]          # the dual simplex did the work
    assert counts["certified"] >= 0.5 * counts["lps"]        # most answers carry their own certificate


@pytest.mark.parametrize("name", ["s3m24", "s7"])
def test_simplex_failures_fall_back_to_highs(name, monkeypatch):
    """With no pivot allowed, every simplex row fails over to HiGHS, and the answers stay exact."""
    monkeypatch.setattr(batched, "SIMPLEX_MAX_ITER", 0)
    rng = np.random.default_rng(7)
    model, U, _ = get_model(name, 1)
    F = draw_candidates(rng, model, "prior", 30 if name == "s3m24" else 8, 0.3)
    cache = BasisCache()
    assert_agrees(model, F, U[:5], cache=cache)
    st_ = cache.stats()
    assert st_["simplex_failed"] > 0 and st_["simplex_solved"] == 0
    assert st_["highs_calls"] > 5                              # more than the one bootstrap solve per direction


def test_simplex_off_matches_simplex_on():
    """``simplex=False`` (HiGHS for every miss) gives the same answers as the dual simplex path."""
    rng = np.random.default_rng(11)
    model, U, _ = get_model("s3m24", 1)
    F = draw_candidates(rng, model, "prior", 200, 0.3)
    b = model.JT @ U[3]
    on = DirectionSolver(model.moment_arms, b)
    off = DirectionSolver(model.moment_arms, b, simplex=False)
    w_on, st_on, a_on = on.solve(F, return_alpha=True)
    w_off, st_off, _ = off.solve(F, return_alpha=True)
    assert on.stats.simplex_solved > 0 and off.stats.simplex_solved == 0
    assert np.array_equal(st_on, st_off)
    assert np.all(np.abs(w_on - w_off) <= REL * np.maximum(np.abs(w_off), 1.0))
    assert np.all(np.isfinite(a_on))


def test_learned_bases_serve_later_calls():
    """Bases found by the simplex are cached: the same candidates again are answered from the cache."""
    rng = np.random.default_rng(5)
    model, U, _ = get_model("s3m24", 1)
    F = draw_candidates(rng, model, "local", 3000, 0.2)
    cache = BasisCache()
    w1, _, s1 = max_wrench_batched(model, F, U[:3], cache=cache, return_alpha=False)
    st1 = cache.stats()
    assert st1["learned_bases"] > 0
    w2, _, s2 = max_wrench_batched(model, F, U[:3], cache=cache, return_alpha=False)
    st2 = cache.stats()
    assert st2["cache_hits"] - st1["cache_hits"] > 0.9 * F.shape[0] * 3
    assert np.array_equal(s1, s2)
    assert np.all(np.abs(w1 - w2) <= 1e-12 * np.maximum(np.abs(w1), 1.0))


@pytest.mark.parametrize("name", ["p3m12", "s3m24"])
def test_compiled_basis_maps_equal_numpy(name):
    """``simplex.make_basis`` (compiled) builds the same verified maps as the numpy reference, basis by basis,
    including EMG-like lower bounds and a rank-deficient start (bases found by HiGHS and by the simplex)."""
    rng = np.random.default_rng(23)
    model, U, _ = get_model(name, 2)
    F = draw_candidates(rng, model, "prior", 600, 0.3)
    lb = np.where(rng.random(model.m) < 0.2, 0.05, 0.0)
    checked = 0
    for k, bounds in ((0, None), (1, None), (2, None), (3, lb), (4, lb)):
        s = DirectionSolver(model.moment_arms, model.JT @ U[k], bounds)
        s.solve(F)
        assert len(s.bases) >= 2
        for bb in s.bases:
            n, m = s.n, s.m
            bcols = np.sort(bb.basic[bb.basic <= m])
            brows = np.sort(bb.basic[bb.basic > m]) - (m + 1)
            f = F[rng.integers(F.shape[0])]
            out = []
            for compiled in (True, False):
                col = bb.status.astype(np.int64).copy()
                Binv, T, CW, dvec = np.empty((n, n)), np.empty((n, m)), np.empty((2 * n + 3, m)), np.empty(m)
                if compiled:
                    ok, q, wb = batched._simplex.make_basis(s.A, s.lb, s.ub, s._Acol1, s._fscale, s._wscale,
                                                            s._Rscale, s.b, bcols, brows, col, f, batched.PRIMAL_TOL,
                                                            batched.DUAL_TOL, batched.GAP_REL, batched.MAX_COND,
                                                            Binv, T, CW, dvec)
                else:
                    ok, q, wb = s._make_basis_numpy(bcols, brows, col, f, Binv, T, CW, dvec)
                out.append((ok, q, wb, col, T, CW[:q + 1], dvec))
            (ok1, q1, wb1, c1, T1, C1, d1), (ok2, q2, wb2, c2, T2, C2, d2) = out
            assert ok1 and ok2 and bool(wb1) == bool(wb2) and np.array_equal(c1, c2)
            assert np.abs(T1 - T2).max() <= 1e-11 * max(1.0, float(np.abs(T2).max()))
            assert np.abs(d1 - d2).max() <= 1e-11 * max(1.0, float(np.abs(d2).max()))
            np.testing.assert_allclose(C1[-1], C2[-1], rtol=0, atol=1e-11 * max(1.0, float(np.abs(C2).max())))
            # the checks, as sets of rows; a reduced cost that rounds to +-1e-20 instead of 0 may add the gap
            # row GAP_REL t_w - gap with a rounding-sized gap on one side only (it changes no answer)
            tol = 1e-11 * max(1.0, float(np.abs(C2).max()))
            A_, B_ = (C1[:-1], C2[:-1]) if q1 >= q2 else (C2[:-1], C1[:-1])
            match = np.abs(A_[:, None, :] - B_[None, :, :]).max(axis=2) <= tol
            assert match.any(axis=0).all()                 # every row of the shorter set is in the longer
            extra = A_[~match.any(axis=1)]
            assert abs(q1 - q2) <= 1 and extra.shape[0] == abs(q1 - q2)
            if extra.size:
                gap_row = batched.GAP_REL * (T1[list(bcols).index(m)] if m in bcols else 0.0)
                assert np.abs(extra - gap_row).max() <= 1e-15 * max(1.0, float(np.abs(d2).max()))
            checked += 1
    assert checked > 20


@pytest.mark.parametrize("name", ["s3m24", "s7"])
def test_fresh_solver_starts_from_the_slack_basis_without_highs(name):
    """A fresh solver's first row goes to the dual simplex from the slack basis (w basic, dual feasible for
    every f); the slack basis is not kept, only the optimal one it led to; the answers stay exact."""
    rng = np.random.default_rng(5)
    model, U, _ = get_model(name, 1)
    F = draw_candidates(rng, model, "prior", 40 if name == "s3m24" else 8, 0.3)
    cache = BasisCache()
    assert_agrees(model, F, U[:5], cache=cache)
    st_ = cache.stats()
    assert st_["start_bases"] == 5 and st_["bootstrap_calls"] == 0
    for e in cache.entries():
        n, m = e.n, e.m
        r0 = int(np.argmax(np.abs(e.b)))
        slack = tuple(sorted([m] + [m + 1 + i for i in range(n) if i != r0]))
        assert all(tuple(sorted(bb.basic)) != slack for bb in e.bases)


def test_simplex_proves_infeasible_rows_with_its_own_farkas_certificate():
    """With co-contraction lower bounds many LPs are infeasible: the simplex's final basis yields a Farkas
    certificate (verified before use) instead of a HiGHS call per row; statuses agree with HiGHS."""
    rng = np.random.default_rng(13)
    model, U, _ = get_model("s3m24", 1)
    F = draw_candidates(rng, model, "prior", 60, 0.5)
    lb = np.full(model.m, 0.25)
    cache = BasisCache()
    status = assert_agrees(model, F, U[:6], lb=lb, cache=cache)
    st_ = cache.stats()
    assert (status == CODE["infeasible"]).sum() > 20
    assert st_["simplex_farkas"] > 0
    assert st_["highs_calls"] < 0.5 * (status == CODE["infeasible"]).sum()


def test_packing_only_the_start_bases_is_the_same_solve(monkeypatch):
    """``SIMPLEX_PACK_STARTS`` hands the dual simplex the arrays of its rows' start bases only: every answer, status
    and counter (simplex rows, pivots, learned bases) is the same as with every cached basis packed, over calls
    that start the simplex from many cached bases."""
    rng = np.random.default_rng(23)
    model, U, _ = get_model("s3m24", 1)
    calls = [draw_candidates(rng, model, "local", 300, 0.4) for _ in range(3)]
    calls += [draw_candidates(rng, model, "prior", 300, 0.3) for _ in range(3)]
    got = {}
    for on in (True, False):
        monkeypatch.setattr(batched, "SIMPLEX_PACK_STARTS", on)
        cache = BasisCache()
        got[on] = [max_wrench_batched(model, F, U[:4], cache=cache, return_alpha=False) for F in calls], \
            cache.stats()
    (a, sa), (b, sb) = got[True], got[False]
    assert sa == sb and sa["simplex_solved"] > 500 and sa["learned_bases"] > 40
    for (wa, _, ta), (wb, _, tb) in zip(a, b):
        assert np.array_equal(wa, wb) and np.array_equal(ta, tb)
