"""One member of a run-to-run distribution: an estimator rerun on one model x data set with one random stream.

Stream keys (:data:`STREAM_KEYS`): member 0 is the pipeline's own run (the stream of ``chapter5_estimate`` /
``chapter6_run``), so the published result is one member of its distribution; member k >= 1 uses
``SeedSequence([seed, crc32('reruns/<chapter>/<model>/<dataset>'), k])`` (:func:`neckstrength.seeds.seed_sequence`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from neckstrength.abc.algorithm4 import ABCSettings, estimate_strengths
from neckstrength.estimation.datasets import Dataset
from neckstrength.estimation.scaling import bootstrap_prior
from neckstrength.model.reduction import ReducedModel
from neckstrength.seeds import seed_sequence
from neckstrength.sequential.algorithms import (
    SequentialSettings,
    SequentialState,
    SimulatedSet,
    StrengthGrid,
    fit_point_estimate,
    sample_prior,
    scaled_baseline,
)
from neckstrength.sequential.analysis import measure_from
from neckstrength.seeds import generator

@dataclass(frozen=True)
class RerunSettings:
    """K and the band of one chapter x model's run-to-run distribution (config ``reruns``; defaults = the schema's).

    ``members``: K (member 0 = the pipeline's own run); ``level``: the central band; ``n_candidates``: N_F of a
    Table 6.1 member (None = ``chapter6.n_candidates``; Chapter 5 has no such setting)."""

    members: int = 10
    level: float = 0.9
    n_candidates: int | None = None

    def __post_init__(self):
        if self.members < 2:
            raise ValueError(f"reruns: members must be >= 2 (a distribution), got {self.members}")
        if not 0 < self.level < 1:
            raise ValueError(f"reruns: level must be in (0, 1), got {self.level}")


#: stream key per chapter: member 0 = the pipeline's run, member k >= 1 = the rerun key with extra word k
STREAM_KEYS = {
    "chapter5": ("{model}/{dataset}", "reruns/chapter5/{model}/{dataset}"),
    "chapter6": ("chapter6/{model}/{dataset}", "reruns/chapter6/{model}/{dataset}"),
}


def member_stream(seed: int, chapter: str, model: str, dataset: str, member: int) -> tuple[np.random.SeedSequence,
                                                                                             str]:
    """The random stream of ``member`` (0 = the pipeline's own run) and its key as text (for the output)."""
    own, rerun = STREAM_KEYS[chapter]
    if member < 0:
        raise ValueError(f"member must be >= 0, got {member}")
    if member == 0:
        key = own.format(model=model, dataset=dataset)
        return seed_sequence(seed, key), f"seed {seed}, key '{key}'"
    key = rerun.format(model=model, dataset=dataset)
    return seed_sequence(seed, key, member), f"seed {seed}, key '{key}', {member}"


def algorithm4_member(model: ReducedModel, data: Dataset, settings: ABCSettings, bootstrap_direction: str,
                      rng: np.random.Generator) -> pd.DataFrame:
    """Algorithm 4 (Chapter 5) once: a long table ``quantity, parameter, value`` with f_c and sigma_c per free
    parameter, D(f_c), the iteration count and convergence (1/0)."""
    f0, a = bootstrap_prior(model, data, bootstrap_direction)
    res = estimate_strengths(model, data, settings, f0, a, rng=rng, checkpoint=None, progress=None)
    rows = [{"quantity": q, "parameter": p, "value": float(v)}
            for q, vals in (("f_c", res.f_c), ("sigma_c", res.sigma_c)) for p, v in zip(res.param_names, vals)]
    rows += [{"quantity": "D_fc", "parameter": "", "value": res.D_fc},
             {"quantity": "iters", "parameter": "", "value": float(res.iterations)},
             {"quantity": "converged", "parameter": "", "value": float(res.converged)}]
    return pd.DataFrame(rows)


def sequential_member(model: ReducedModel, data: Dataset, settings: SequentialSettings,
                      stream: np.random.SeedSequence) -> pd.DataFrame:
    """Table 6.1's estimate once: N_F candidates from the prior (the first child of ``stream``, as
    ``chapter6_run`` draws them), Algorithm 8's update with every direction's measurement, then the posterior
    mean f_c, variance v_c per muscle and D(f_c). After all K tests the posterior does not depend on the order
    (Sec. 6.5.2), so Algorithm 9's order, which only orders the tests, is not run."""
    f0, _, _ = scaled_baseline(model, data)
    ss_prior = stream.spawn(2)[0]
    F = sample_prior(f0, settings.prior_sd_rel, settings.n_candidates, generator(ss_prior))
    grid = StrengthGrid.around(f0, settings.prior_sd_rel, settings.n_bins, settings.bin_range_sd)
    sim = SimulatedSet.build(model, data.directions, data.U, F, [grid], settings.n_wbins)[0]
    state = SequentialState(model, sim, data.force_scale, settings)
    measure = measure_from(data)
    for d in data.directions:
        force, bounds = measure(d)
        state.update(d, force, bounds)
    est = state.estimate()
    D_fc, _ = fit_point_estimate(model, data, est["f_c"].to_numpy(), settings.epsilon)
    rows = [{"quantity": q, "parameter": n, "value": float(v)}
            for q in ("f_c", "v_c") for n, v in zip(est["muscle"], est[q])]
    rows.append({"quantity": "D_fc", "parameter": "", "value": D_fc})
    return pd.DataFrame(rows)
