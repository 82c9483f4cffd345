"""The musculoskeletal neck model (thesis Sec. 4.2, Appendix B)
=============================================================

- :mod:`.full`       the 96-muscle x 7-joint model at the neutral posture (derived tables + Table B.1)
- :mod:`.reduction`  kinematic variants and muscle groupings (Sec. 4.2.1): :class:`ReducedModel`
- :mod:`.geometry`   skull frame, test points and directions, unit wrenches, Jacobians
- :mod:`.opensim`    the optional derivation of the model tables from OpenSim models (needs ``opensim``)
"""

from neckstrength.model.full import (
                                     AXES,
                                     COORDINATES,
                                     JOINTS,
                                     KINEMATIC_VARIANTS,
                                     MUSCLE_VARIANTS,
                                     NAMED_MODELS,
                                     FullModel,
                                     base_name,
                                     load_full_model,
                                     load_table_b1,
                                     side_of,
)
from neckstrength.model.geometry import (
                                     PLANAR_INDEX,
                                     WRENCH_COMPONENTS,
                                     HeadEllipsoid,
                                     direction_table,
                                     jacobian_transpose,
                                     reconstruct_test_points,
                                     unit_wrench,
)
from neckstrength.model.reduction import ReducedModel, grouping_matrix, named_model, reduce_model, scale_strengths

__all__ = ["AXES", "COORDINATES", "JOINTS", "KINEMATIC_VARIANTS", "MUSCLE_VARIANTS", "NAMED_MODELS", "FullModel",
           "base_name", "load_full_model", "load_table_b1", "side_of", "PLANAR_INDEX", "WRENCH_COMPONENTS",
           "HeadEllipsoid", "direction_table", "jacobian_transpose", "reconstruct_test_points", "unit_wrench",
           "ReducedModel", "grouping_matrix", "named_model", "reduce_model", "scale_strengths"]
