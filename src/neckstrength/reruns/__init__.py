"""Run-to-run distributions of the thesis's estimates (issue 36)
===============================================================

The thesis prints one run of each estimator. To tell "our implementation differs" from "the estimator lands
elsewhere on every run", each estimate is rerun with K independent random streams and the thesis's value is
judged against our central 90 % band (:mod:`neckstrength.report.scorecard.distribution`).

- :mod:`.runs`   one member of a distribution: Algorithm 4 (Chapter 5) or Algorithms 7-8's final posterior
  (Chapter 6, Table 6.1) on one model x data set with one random stream; the stream keys
- :mod:`.bands`  per printed item: the members' central band, spread and the printed precision

Algorithm 4 draws nothing at random (Sec. 5.2.2.2: the candidates are every permutation of three explicit
samples per muscle); its random stream only subsamples the candidates kept for Fig. 5.3. Its members are
therefore identical, and the reruns show it. Table 6.1's estimate depends on the N_F candidates drawn from the
prior (Sec. 6.5.1), so its members differ.
"""

from neckstrength.reruns.bands import band_table, printed_half_unit
from neckstrength.reruns.runs import (
    STREAM_KEYS,
    RerunSettings,
    algorithm4_member,
    member_stream,
    sequential_member,
)

__all__ = ["STREAM_KEYS", "RerunSettings", "algorithm4_member", "band_table", "member_stream", "printed_half_unit",
           "sequential_member"]
