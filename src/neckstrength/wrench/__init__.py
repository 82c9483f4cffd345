"""The max-wrench linear program (thesis Eq. 4.1 / 5.2)
=====================================================

Given a reduced model (moment arms ``R``, skull-frame ``J^T``, strengths ``f``) and a unit wrench ``u``,
the largest ``w`` such that some activations ``alpha_lb <= alpha <= alpha_ub`` produce ``w u``.

- :mod:`.problem`  the LP in muscle forces, status codes, one direction's HiGHS model
- :mod:`.highs`    the HiGHS reference (one LP, or a loop over strength vectors)
- :mod:`.batched`  the exact batched solver (cached optimal bases, verified optimality)
- :mod:`.solve`    :func:`solve`, the one entry every caller uses
"""

from neckstrength.wrench.batched import BasisCache
from neckstrength.wrench.highs import max_wrench, max_wrench_batch
from neckstrength.wrench.problem import STATUS_CODES, MaxWrenchResult
from neckstrength.wrench.solve import METHODS, solve

__all__ = ["solve", "METHODS", "STATUS_CODES", "MaxWrenchResult", "BasisCache", "max_wrench", "max_wrench_batch"]
