"""Checks of inference, kept apart from the inference itself (issue 18)
=====================================================================

- :mod:`.sbc`      simulation-based calibration (SBC) of every estimator that reports an uncertainty: Algorithm 4's
  ``f_c (1 +- sigma_c)`` (a sampling-width heuristic, read here as a normal sd to give it a chance), ABC-SMC
  (:func:`neckstrength.abc.abc_smc`) and the joint sequential posterior (:class:`neckstrength.sequential.joint.
  JointPosterior`) after ``t`` tests. Simulated participants are drawn from each method's own prior (forces only,
  log-normal measurement noise); per participant and muscle the probability integral transform (PIT, the
  continuous rank of the truth among the posterior) and the coverage of central 50% and 90% intervals.
- :mod:`.crosscheck` the same simulator and distance through pyABC's ABC-SMC (optional extra ``crosscheck``).
- :mod:`.plots`    rank (PIT) histograms per muscle group and coverage figures (imported on its own: matplotlib).
"""

from neckstrength.calibration.sbc import (
    METHODS,
    SBCSettings,
    coverage_summary,
    draw_participant,
    pit_rows,
    run_sbc,
    weighted_pit,
)

__all__ = ["METHODS", "SBCSettings", "coverage_summary", "draw_participant", "pit_rows", "run_sbc", "weighted_pit"]
