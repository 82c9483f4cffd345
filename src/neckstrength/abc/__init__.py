"""Chapter 5: ABC estimation of every muscle group's strength
============================================================

- :mod:`.algorithm4`  the thesis's Algorithm 4 (grid sampling around the estimate, rejection, update)
- :mod:`.smc`         ABC-SMC with all muscles free (beyond the thesis)
- :mod:`.coverage`    coverage check of the reported spread (beyond the thesis)
- :mod:`.plots`       Figs. 5.3-5.14 (imported on its own: it loads matplotlib)
"""

from neckstrength.abc.algorithm4 import ABCResult, ABCSettings, estimate_strengths
from neckstrength.abc.coverage import coverage_check
from neckstrength.abc.smc import SMCResult, SMCSettings, abc_smc

__all__ = ["ABCResult", "ABCSettings", "estimate_strengths", "coverage_check", "SMCResult", "SMCSettings", "abc_smc"]
