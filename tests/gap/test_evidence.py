"""neckstrength.gap.evidence: the Bayes evidence of the diagnosis's explanations."""

import numpy as np
import pytest

from neckstrength.gap.evidence import (NO_EFFECT, fit_strengths_map, largest_of_normals, log_evidence,
                                       log_jacobian, posterior)


def test_largest_of_normals_matches_simulation():
    rng = np.random.default_rng(1)
    z = rng.normal(size=(400_000, 3)).max(axis=1)
    m, v = largest_of_normals(3)
    assert m == pytest.approx(z.mean(), abs=0.005) and v == pytest.approx(z.var(), abs=0.005)
    assert largest_of_normals(1) == pytest.approx((0.0, 1.0), abs=1e-8)
    with pytest.raises(ValueError):
        largest_of_normals(0)


def _linear_world(K=25, p=4, seed=0):
    """A toy base model whose log forces are linear in the log strengths: log F = A log f."""
    rng = np.random.default_rng(seed)
    A = np.abs(rng.normal(size=(K, p)))
    A /= A.sum(axis=1, keepdims=True)          # homogeneous of degree 1, like the max-wrench LP
    pidx = np.arange(p)

    def base(f):
        return np.exp(A @ np.log(f))

    return A, pidx, base


def test_evidence_names_the_explanation_that_made_the_data_and_not_noise():
    """Two toy explanations with distinct signatures beside "no effect": data made by one of them are given to it,
    data of noise alone to "no effect" (each a 1-in-3 guess by chance), and the posteriors sum to one."""
    K, sigma, R = 25, 0.04, 3
    A, pidx, base = _linear_world(K)
    rng = np.random.default_rng(2)
    f = np.exp(rng.normal(0, 0.3, 4))
    lb = np.log(base(f))
    sig_a = np.sin(np.arange(K)) * 0.15
    sig_b = np.where(np.arange(K) % 2 == 0, 0.12, -0.12)
    zero = np.zeros((K, K))
    sig = {"none": [(lb[None, :], zero)], "a": [((lb + s * sig_a)[None, :], zero) for s in (0.5, 1.0)],
           "b": [((lb + s * sig_b)[None, :], zero) for s in (0.5, 1.0)]}
    J = log_jacobian(base, f, pidx)
    assert np.allclose(J, A, atol=1e-6)
    prior = {t: np.log(1 / 3) for t in sig}
    hits = 0
    for truth, shift in (("none", 0 * sig_a), ("a", sig_a), ("b", sig_b)):
        for _ in range(10):
            trials = lb + shift + rng.normal(0, sigma, (R, K))
            y = trials.max(axis=0)
            post = posterior(log_evidence(sig, J, y, sigma, 0.3, R), prior)
            assert sum(post.values()) == pytest.approx(1.0)
            hits += max(post, key=post.get) == truth
    assert hits >= 28


def test_fit_recovers_strengths_where_the_tests_determine_them():
    A, pidx, base = _linear_world()
    rng = np.random.default_rng(3)
    f = np.exp(rng.normal(0, 0.3, 4))
    sigma, R = 0.01, 3
    y = (np.log(base(f)) + rng.normal(0, sigma, (R, len(A)))).max(axis=0)
    fit = fit_strengths_map(base, np.ones(4), pidx, y, sigma, R, prior_sd=3.0)
    assert np.allclose(np.log(fit), np.log(f), atol=0.05)


def test_explanations_of_a_context_prior_and_a_noise_only_data_set(ctx_s3):
    """The diagnosis's explanations on s3m24 (three candidates, small draws): the prior gives "no effect" its stated
    share, and a data set of the base model plus 4 % noise at strengths the fit must find (tied sides, as the
    model's) is most probably "no effect" (P 0.6-0.7 on the user benchmark's base-model controls; an effect is named
    there in 0 of 30), and the fit check tells forces that nothing fits."""
    from neckstrength.gap.evidence import EvidenceSettings, Explanations

    ex = Explanations(ctx_s3, ["asymmetry", "origin_offset", "submaximal_effort"],
                      EvidenceSettings(element_draws=40, n_grid=9))
    lp = ex.logprior()
    assert set(lp) == {*NO_EFFECT, "asymmetry", "origin_offset", "submaximal_effort", "direction_scatter"}
    assert sum(np.exp(lp[t]) for t in NO_EFFECT) == pytest.approx(0.5)
    assert sum(np.exp(v) for v in lp.values()) == pytest.approx(1.0)
    rng = np.random.default_rng(4)
    f = ctx_s3.model.strengths * np.exp(rng.normal(0, 0.3, ex.pidx.max() + 1))[ex.pidx]   # sides tied
    forces = (ex.base(f)[None, :] * np.exp(rng.normal(0, 0.04, (3, len(ex.N))))).max(axis=0)
    res = ex.evidence(forces, 0.04, rng)
    assert sum(res.posterior.values()) == pytest.approx(1.0)
    assert res.named == "none" and res.p_no_effect > 0.3
    assert res.best in NO_EFFECT and res.fit_p > 0.01           # noise only: the best explanation fits
    # forces the model cannot produce (every other test twice as strong): something is most probable, but nothing
    # fits (at 30 % the aiming scatter's widest cone, 20 deg, still absorbs it: fit_p 0.46)
    bad = ex.evidence(forces * np.where(np.arange(len(forces)) % 2 == 0, 2.0, 1.0), 0.04, rng)
    assert bad.fit_p < 1e-6
    assert np.all(np.isfinite(res.strengths)) and res.settings.strength_sd == 0.3



def test_centred_element_null_drops_the_strength_like_part_of_its_shift(ctx_s3):
    """element_centred: the element null's mean shift keeps only its part outside the strengths' Jacobian span
    (the fitted strengths carry the rest); off (the default), the shift is as drawn; the covariance is the same."""
    from dataclasses import replace

    from neckstrength.gap.evidence import EvidenceSettings, Explanations, log_jacobian

    es = EvidenceSettings(element_draws=40, n_grid=5, refit_top=0, fit_starts=0)
    ex = Explanations(ctx_s3, ["asymmetry"], es)
    rng = np.random.default_rng(5)
    f = ctx_s3.model.strengths * np.exp(rng.normal(0, 0.3, ex.pidx.max() + 1))[ex.pidx]
    y = np.log(ex.base(f)) + rng.normal(0, 0.03, len(ex.N))
    _, plain, _ = ex.explain(y, 0.03, np.random.default_rng(1), strengths=f)
    ex.s = replace(es, element_centred=True)
    _, cent, _ = ex.explain(y, 0.03, np.random.default_rng(1), strengths=f)
    J = log_jacobian(ex.base, f, ex.pidx, base_rows=ex.base_rows)
    lb = np.log(ex.base(f))
    d0, d1 = plain["none_elements"][0][0][0] - lb, cent["none_elements"][0][0][0] - lb
    assert np.linalg.norm(J.T @ d1) < 1e-8 * np.linalg.norm(J.T @ d0)          # nothing left in the span
    assert np.linalg.norm(d0) > 0.05 and np.linalg.norm(d1) < 0.5 * np.linalg.norm(d0)
    resid = d0 - J @ np.linalg.lstsq(J, d0, rcond=None)[0]
    np.testing.assert_allclose(d1, resid, atol=1e-10)
    np.testing.assert_allclose(plain["none_elements"][0][1], cent["none_elements"][0][1], rtol=1e-6, atol=1e-12)
    np.testing.assert_array_equal(plain["none"][0][0], cent["none"][0][0])

def test_participants_script_reports_that_no_explanation_fits_s003(tmp_path):
    """benchmarks/bench_gap_evidence_participants.py on S003 at the prior's noise 0.08: a most probable explanation
    with its posterior, and the fit check saying that it does not fit (the calibrated decision's remainder is
    likewise not explained); the table is written once and not overwritten."""
    import importlib.util
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    path = root / "benchmarks" / "bench_gap_evidence_participants.py"
    spec = importlib.util.spec_from_file_location("bench_ev_p", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "ev.csv"
    df = mod.main(["--config", str(root / "config" / "config.yaml"), "--datasets", "S003", "--noise", "0.08",
                   "--out", str(out)])
    assert len(df) == 1 and out.exists()
    row = df.iloc[0]
    assert row.most_probable in row.top3 and 0 <= row.p_no_effect <= 1
    assert row.fit_p_best < 1e-3
    with pytest.raises(SystemExit, match="--force"):
        mod.main(["--config", str(root / "config" / "config.yaml"), "--datasets", "S003", "--out", str(out)])


def test_prior_points_cover_the_box_of_a_many_parameter_effect(ctx_s3):
    """One or two parameters: the screen grid without its neutral point; three or more (the effort lobe: b and its
    width): quasi-random points filling the box, oblique ones included, the same on every call."""
    from neckstrength.gap.effects import EFFECTS
    from neckstrength.gap.evidence import EvidenceSettings, prior_points

    s = EvidenceSettings(n_grid=9, sample_points=64)
    a = EFFECTS["asymmetry"](ctx_s3)
    assert [float(t[0]) for t in prior_points(a, s)] == [float(t[0]) for t in a.grid(9)[1:]]
    e = EFFECTS["submaximal_effort"](ctx_s3)
    pts = np.array(prior_points(e, s))
    assert pts.shape == (64, 4) and np.all(pts >= e.lower) and np.all(pts <= e.upper)
    assert np.array_equal(pts, np.array(prior_points(e, s)))
    oblique = (np.abs(pts[:, :3]) > 0.3 * e.upper[:3]).all(axis=1)
    assert oblique.sum() >= 8                           # the screen grid has none: it lies on the b axes
    assert pts[:, 3].min() < 1.5 and pts[:, 3].max() > 3.5


def test_a_large_effect_is_judged_at_strengths_refitted_under_it(ctx_s3):
    """Forces of a left/right strength ratio of e^0.6 (made with the user benchmark's generator, not the effect's
    code), 3 trials of 4 % noise: judged at the base fit (strengths bent towards the asymmetry) the asymmetry does not
    fit; refitted under it, it fits, is most probable, and is named (the base fit alone left such cases unnamed on
    the user benchmark, docs/gap_diagnosis.md)."""
    from neckstrength.gap import truths as T
    from neckstrength.gap.evidence import EvidenceSettings, Explanations, best_fit_chi2

    ex = Explanations(ctx_s3, ["asymmetry", "origin_offset"], EvidenceSettings(element_draws=40, n_grid=17))
    setup = T.TruthSetup.of(ctx_s3)
    rng = np.random.default_rng(5)
    f = ctx_s3.model.strengths * np.exp(rng.normal(0, 0.2, ex.pidx.max() + 1))[ex.pidx]
    clean = T.make_forces(setup, "asymmetry", f, {"log_LR_ratio": 0.6})
    forces = (clean[None, :] * np.exp(rng.normal(0, 0.04, (3, len(clean))))).max(axis=0)
    y = np.log(forces)
    fb, sig, Js = ex.explain(y, 0.04, rng)
    base_sig = ex.signatures(fb, rng)
    J = log_jacobian(ex.base, fb, ex.pidx, base_rows=ex.base_rows)
    at_base = best_fit_chi2(base_sig["asymmetry"], J, y, 0.04, 0.3, 3)
    refitted = best_fit_chi2(sig["asymmetry"], Js["asymmetry"], y, 0.04, 0.3, 3)
    # chi-square with 25 degrees of freedom (here 46 and 24): 40 is p 0.03, 35 p 0.09
    assert at_base > 40 and refitted < 35
    res = ex.evidence(forces, 0.04, rng)
    assert res.named == "asymmetry" and res.p_no_effect < 0.01 and res.fit_p_effect > 1e-3
