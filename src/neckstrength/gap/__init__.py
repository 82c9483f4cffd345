"""Sim-to-real gap diagnosis (issue 8): where the model misses the measured forces, which unmodelled
effect explains it, and how far the gap shrinks when that effect is added.

Modules, each importing downward only:

- :mod:`.effects`    candidate unmodelled effects (a registry: one class per effect) and the model
                     :class:`~.effects.Instance` they modify (moment arms, strengths, bounds, directions)
- :mod:`.fit`        free strengths (+ fixed effect parameters) fitted to measured forces: a Levenberg-Marquardt
                     least-squares fit vectorised over many problems, with the exact Jacobian of the LP
- :mod:`.engine`     fits of every (effect, parameter) key for many problems (folds x data sets), cached by key
- :mod:`.calibrate`  the calibrated decision (issue 17): noise-only null per data set, maxT p-value, remainder
                     test, power per effect
- :mod:`.diagnose`   where (residuals by direction, plane, wrench component, active muscle; reach envelope),
                     which (cross-validation over held-out directions, calibrated decision, ranking) and how far
- :mod:`.discriminate` which additional measurements (repeats, further points on the head surface) would tell
                     the leading candidates apart: expected log Bayes factor per pair, greedy proposal
- :mod:`.forked`     forked worker processes for work on unpicklable state (the fits' solvers)
- :mod:`.store`      per-data-set results on disk, keyed by everything they depend on (resume)
- :mod:`.benchmark`  withheld-effect generator and blind scoring (kept apart from the diagnosis)
- :mod:`.truths`     the user-facing benchmark's truths (direction errors in a cone, effort, posture drift, size,
                     the 96-element truth), made without the diagnosis's effects
- :mod:`.scoring`    its scoring against a model-free detectability, with Wilson intervals
- :mod:`.report`     per-data-set markdown report and figures
"""

from .effects import EFFECTS, Effect, GapContext, Instance, Param, available_effects, base_instance, compose

__all__ = ["EFFECTS", "Effect", "GapContext", "Instance", "Param", "available_effects", "base_instance", "compose"]
