"""Forked worker processes for work on state that cannot be pickled (the fits' solvers and basis caches).

A forked child inherits this process's memory, so the function and its inputs are not pickled, only the
results. The function is registered under a key just before the pool forks and dropped afterwards.
"""

from __future__ import annotations

import contextlib
import itertools
import multiprocessing as mp
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed

_JOBS: dict[int, tuple[Callable, Sequence]] = {}
_KEYS = itertools.count()


def _call(key: int, i: int):
    fn, items = _JOBS[key]
    return fn(items[i])


def fork_map(fn: Callable, items: Sequence, workers: int) -> Iterator[tuple[int, object]]:
    """``fn(item)`` for every item of ``items`` in ``workers`` forked processes, submitted in order (a process
    that is done takes the next item); yields ``(index, result)`` as they finish."""
    items = list(items)
    key = next(_KEYS)
    _JOBS[key] = (fn, items)
    try:
        with ProcessPoolExecutor(max(1, min(int(workers), len(items))), mp_context=mp.get_context("fork")) as ex:
            futs = {ex.submit(_call, key, i): i for i in range(len(items))}
            for f in as_completed(futs):
                yield futs[f], f.result()
    finally:
        _JOBS.pop(key, None)


@contextlib.contextmanager
def fork_background(fn: Callable[[], object]) -> Iterator[Future]:
    """``fn()`` in one forked process while this one goes on; yields its future (cancelled if left unused)."""
    key = next(_KEYS)
    _JOBS[key] = (lambda _: fn(), [None])
    ex = ProcessPoolExecutor(1, mp_context=mp.get_context("fork"))
    try:
        yield ex.submit(_call, key, 0)
    finally:
        ex.shutdown(cancel_futures=True)
        _JOBS.pop(key, None)
