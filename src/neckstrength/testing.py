"""Helpers shared by the tests and the benchmark scripts that check results (no dependency on pytest)."""

from __future__ import annotations

import math


def assert_close(a, b, path: str = "value", rel: float = 1e-9, abs_tol: float = 1e-12) -> None:
    """``a == b`` for nested dicts, lists and tuples, with floats equal to ``rel`` (relative to ``b``) plus
    ``abs_tol`` and NaN equal to NaN; everything else compared with ``==``. The defaults are the LP solver's
    rounding: two runs that solve the same LPs in other batches or with other cached bases differ in the last digits
    of some wrenches. ``path`` names the value in the message of a failure (``path/key[index]`` below it)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), (path, sorted(map(str, a)), sorted(map(str, b))
                                                          if isinstance(b, dict) else b)
        for k in a:
            assert_close(a[k], b[k], f"{path}/{k}", rel, abs_tol)
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), (path, a, b)
        for k, (x, y) in enumerate(zip(a, b)):
            assert_close(x, y, f"{path}[{k}]", rel, abs_tol)
    elif isinstance(a, float) and isinstance(b, float):
        assert (math.isnan(a) and math.isnan(b)) or abs(a - b) <= abs_tol + rel * abs(b), (path, a, b)
    else:
        assert a == b, (path, a, b)
