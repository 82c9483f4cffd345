"""The one public entry to the max-wrench LP (thesis Eq. 4.1 / 5.2): :func:`solve`."""

from __future__ import annotations

import numpy as np

from neckstrength.model.reduction import ReducedModel
from neckstrength.wrench.batched import max_wrench_batched
from neckstrength.wrench.highs import max_wrench_batch

METHODS = ("batched", "highs")


def solve(model: ReducedModel, F: np.ndarray, U: np.ndarray, alpha_lb=None, alpha_ub=None,
          method: str = "batched", return_alpha: bool = True, chunk_size: int = 65536, cache=None,
          n_threads: int = 1):
    """Max wrench for every strength vector in ``F`` (N x m) and unit wrench in ``U`` (K x d).

    ``alpha_lb``/``alpha_ub``: None, (m,), or (K, m) per-direction activation bounds. Returns ``w``
    (N x K), ``alpha`` (N x K x m, or ``None`` with ``return_alpha=False``) and integer ``status``
    (N x K, see :data:`neckstrength.wrench.STATUS_CODES`).

    ``method``: 'batched' (:mod:`neckstrength.wrench.batched`: exact, cached optimal bases; the default)
    or 'highs' (:func:`neckstrength.wrench.highs.max_wrench_batch`: one warm-started HiGHS instance per
    direction, the reference). ``cache``: a :class:`neckstrength.wrench.BasisCache` to keep bases across
    calls (e.g. across ABC iterations); ``chunk_size``/``n_threads`` tune the batched solver.
    """
    if method == "batched":
        return max_wrench_batched(model, F, U, alpha_lb, alpha_ub, chunk_size=chunk_size, cache=cache,
                                  return_alpha=return_alpha, n_threads=n_threads)
    if method != "highs":
        raise ValueError(f"unknown method {method!r}; one of {METHODS}")
    w, alpha, status = max_wrench_batch(model, F, U, alpha_lb, alpha_ub)
    return w, (alpha if return_alpha else None), status
