"""neckstrength.testing.assert_close, the comparison the session tests and benchmarks/bench_app.py share."""

import math

import pytest

from neckstrength.testing import assert_close


def test_assert_close_allows_rounding_and_names_the_first_difference():
    a = {"estimate": [1.0, 2.0, math.nan], "decision": {"log_bf": -3.5, "call": "deficit", "n": 4}}
    b = {"estimate": [1.0 + 5e-10, 2.0, math.nan], "decision": {"log_bf": -3.5 * (1 + 5e-10), "call": "deficit",
                                                                  "n": 4}}
    assert_close(a, b)                                         # within 1e-9 relative; NaN equals NaN
    with pytest.raises(AssertionError, match=r"snap/estimate\[1\]"):
        assert_close(a, {**b, "estimate": [1.0, 2.0 * (1 + 1e-8), math.nan]}, "snap")
    with pytest.raises(AssertionError, match="snap/decision/call"):
        assert_close(a, {**b, "decision": {**b["decision"], "call": "none"}}, "snap")
    with pytest.raises(AssertionError, match="snap/estimate"):
        assert_close(a, {**b, "estimate": [1.0, 2.0]}, "snap")        # lengths differ
    with pytest.raises(AssertionError, match="snap"):
        assert_close(a, {"estimate": b["estimate"]}, "snap")          # keys differ
    assert_close(1.0, 1.0 + 1e-7, rel=1e-6)                           # looser tolerance when asked
    with pytest.raises(AssertionError):
        assert_close(math.nan, 1.0)
