"""Derivation of the model tables from OpenSim models (optional extra ``opensim``)
=================================================================================

- :mod:`.derive`  moment arms, strengths and joint frames of the 96 muscle elements from the public neck models,
                  thesis Table B.1/B.2/B.3 parsing and comparison, and the ``derive-model`` command

Importing this package does not import ``opensim``; :func:`derive_full_model` does when it runs.
"""

from neckstrength.model.opensim.derive import derive_full_model, derive_tables, write_tables

__all__ = ["derive_full_model", "derive_tables", "write_tables"]
