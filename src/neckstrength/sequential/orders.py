"""Exact order analysis of Chapter 6: entropy of every subset of tests, of every order, and stop rules."""

from __future__ import annotations

import itertools

import numpy as np

from neckstrength.sequential.algorithms import StrengthGrid, pdf_entropy, pdf_moments, posterior_from_loglik


def subset_table(log_prior: np.ndarray, logliks: np.ndarray, grid: StrengthGrid) -> dict[str, np.ndarray]:
    """Posterior moments and entropies for every subset of the K tests (bit i of the index = test i).

    ``logliks`` (K, m, nb): each test's log factor. Returns arrays of shape (2^K, m): 'E', 'V', 'H', and
    'pdf' (2^K, m, nb). Built incrementally (each subset adds one factor to a smaller subset).
    """
    K, m, nb = logliks.shape
    if K > 16:
        raise ValueError("subset table limited to K <= 16 directions; sample orders instead")
    n = 1 << K
    acc = np.zeros((n, m, nb))
    for s in range(1, n):
        low = (s & -s).bit_length() - 1
        acc[s] = acc[s & (s - 1)] + logliks[low]
    pdf = posterior_from_loglik(log_prior[None], acc)
    E, V = pdf_moments(pdf, grid)
    return {"E": E, "V": V, "H": pdf_entropy(pdf, grid), "pdf": pdf}


def order_entropies(H_subsets: np.ndarray, K: int, orders: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean-over-muscles entropy after each prefix of every order (all K! when ``orders`` is None).

    Returns ``orders`` (n, K) and the entropies (n, K + 1), column t = after t tests (0 = prior).
    """
    if orders is None:
        orders = np.array(list(itertools.permutations(range(K))), dtype=np.int64)
    masks = np.cumsum(np.left_shift(1, orders), axis=1)
    h = H_subsets.mean(axis=1)
    return orders, np.column_stack([np.full(len(orders), h[0]), h[masks]])


def stop_iteration(E_by_iter: np.ndarray, rel_tol: float = 0.05) -> int:
    """Retrospective stop: the first t from which every later point estimate stays within ``rel_tol`` of the
    final one for every muscle (``E_by_iter`` (T + 1, m), row 0 = prior)."""
    final = E_by_iter[-1]
    ok = np.all(np.abs(E_by_iter - final) <= rel_tol * np.abs(final), axis=1)
    t = len(ok) - 1
    while t > 0 and ok[t - 1]:
        t -= 1
    return int(max(t, 1))
