"""Identifiability of the muscle groups from the strength tests (issue 31 item 1)
===============================================================================

- :mod:`.profile`  profiles of the best achievable misfit with one group fixed (batched box-constrained LM)
- :mod:`.check`    the independent HiGHS re-evaluation of a profile's optimum
- :mod:`.noise`    the noise level below which a deficit is distinguishable (likelihood-ratio rule)
"""
