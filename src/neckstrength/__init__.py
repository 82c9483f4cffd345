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


def _job_record() -> None:
    # Inside a Snakemake rule script only: append run time / peak memory to the job's log at exit, read by the
    # report's run-time table (neckstrength.runinfo). Does nothing anywhere else.
    import sys

    if getattr(sys.modules.get("__main__"), "snakemake", None) is not None:
        from .runinfo import install_job_record

        install_job_record()


_job_record()
