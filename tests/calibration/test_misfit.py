"""Misfit-aware kernel width (issue 18 item 2): the held-out misfit estimate and the richer truth's reduction."""

from __future__ import annotations

import numpy as np
import pytest

from neckstrength.calibration.misfit import MisfitSettings, heldout_misfit, rich_truth
from neckstrength.estimation.datasets import simulated_dataset
from neckstrength.sequential.joint import JointSettings


def test_heldout_misfit_small_when_model_fits_large_when_it_does_not(p2m7_full_config):
    """Forces the model produces (5% noise) against the same forces distorted direction by direction (+-40% in
    log force, alternating): the held-out errors must reveal the distortion and not invent one."""
    _, model, directions = p2m7_full_config
    data = simulated_dataset(model, directions, "x", 0.9 * model.strengths)
    rng = np.random.default_rng(0)
    noisy = data.forces * np.exp(0.05 * rng.standard_normal(len(data.forces)))
    bent = noisy * np.exp(0.4 * np.where(np.arange(len(noisy)) % 2 == 0, 1.0, -1.0))
    js = JointSettings(n_candidates=3000, noise_rel=0.05)
    args = (model, data.directions, data.U, data.force_scale)
    m_fit, tab = heldout_misfit(*args, noisy, model.strengths, js, 7, np.random.default_rng(1))
    m_bent, _ = heldout_misfit(*args, bent, model.strengths, js, 7, np.random.default_rng(1))
    assert sorted(tab["direction"]) == sorted(data.directions)       # every direction held out once
    assert m_bent > 0.2 and m_fit < 0.5 * m_bent


def test_rich_truth_reduces_like_the_model():
    S = np.array([[1, 0], [1, 0], [0, 1]], float)
    fe, fg = rich_truth(np.array([3.0, 4.0, 5.0]), S, 0.0, np.random.default_rng(0))
    assert np.allclose(fe, [3, 4, 5]) and np.allclose(fg, [5.0, 5.0])     # ||(3, 4)|| = 5 (Sec. 4.2.1.3)
    with pytest.raises(ValueError, match="folds"):
        MisfitSettings(folds=1)
