"""neckstrength: model-based inference of individual neck muscle strengths
=========================================================================

After the thesis in ``shared/seed`` (multi-directional isometric neck strength, ABC strength estimation,
entropy-reducing sequential test selection). Subpackages, each importing downward only:

- :mod:`neckstrength.errors`      the shared exception types (imports nothing from the package)
- :mod:`neckstrength.io`          reading and validating tables (errors name file, row and field), atomic writers
- :mod:`neckstrength.config`      the only reader of the config dict: loading, typed settings, seeds
- :mod:`neckstrength.plotting`    shared plot helpers (radar grid, save)
- :mod:`neckstrength.model`       full model, reduction (Sec. 4.2.1), geometry, optional OpenSim derivation
- :mod:`neckstrength.wrench`      the max-wrench LP (Eq. 4.1 / 5.2) and its one entry, ``wrench.solve``
- :mod:`neckstrength.estimation`  data sets, data discrepancy (Eq. 5.5-5.6), bootstrap scaling (Eq. 5.3)
- :mod:`neckstrength.mfi`         Chapter 3: MFI reliability and group statistics
- :mod:`neckstrength.surfaces`    Chapter 4: strength surfaces and claims
- :mod:`neckstrength.abc`         Chapter 5: Algorithm 4, ABC-SMC, coverage
- :mod:`neckstrength.sequential`  Chapter 6: candidates, posteriors, Algorithms 7-9, order analysis, joint estimator
- :mod:`neckstrength.gap`         the sim-to-real gap diagnosis
- :mod:`neckstrength.report`      scorecard, tolerances, run records
- :mod:`neckstrength.pipeline`    Snakemake glue, one module per rules file (science never imports it)
- :mod:`neckstrength.trials`      a lab's raw trials -> max-force and activation tables, quality report
- :mod:`neckstrength.session`, :mod:`neckstrength.cli`   applications on top of config and science (the session's
  engine, :class:`neckstrength.session.Session`, has an API for front ends other than the terminal)
- :mod:`neckstrength.estimate`   the ``estimate`` command: the Chapter 5/6 pipeline steps on one table

Importing the package has no side effects.
"""

__version__ = "0.1.0"
