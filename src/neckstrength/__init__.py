"""neckstrength: model-based inference of individual neck muscle strengths.

After the thesis in ``shared/seed`` (multi-directional isometric neck strength,
ABC strength estimation, entropy-reducing sequential test selection).
Modules (import downward only):

- :mod:`neckstrength.io`         data loading and validation (named file/row/field errors)
- :mod:`neckstrength.model`      full musculoskeletal model tables, kinematic/muscle reduction
- :mod:`neckstrength.geometry`   skull frame, test directions, unit wrenches, Jacobians
- :mod:`neckstrength.maxwrench`  the max-wrench linear program (thesis Eq. 4.1 / 5.2)
"""

__version__ = "0.1.0"
