"""Chapter 6: sequential test selection by expected entropy reduction
===================================================================

- :mod:`.algorithms`  candidates from the prior, marginal posteriors on a grid, Algorithms 7-9 (the thesis's estimator)
- :mod:`.orders`      exact order analysis over every subset of tests, stop rules
- :mod:`.analysis`    one run analysed: Algorithm 7 with selection, order analysis, the tables behind Figs. 6.4-6.8
- :mod:`.joint`       the joint posterior with importance resampling and resample-move (beyond the thesis)
- :mod:`.plots`       Figs. 6.4-6.10 (imported on its own: it loads matplotlib)
"""

from neckstrength.sequential.algorithms import (
                                                Proposal,
                                                SequentialSettings,
                                                SequentialState,
                                                SimulatedSet,
                                                StrengthGrid,
                                                activation_bounds,
                                                data_likelihood,
                                                expected_entropy_reduction,
                                                fit_point_estimate,
                                                joint_ess,
                                                log_factor,
                                                pdf_entropy,
                                                pdf_moments,
                                                posterior_from_loglik,
                                                run_sequence,
                                                sample_prior,
                                                scaled_baseline,
                                                select_direction,
                                                sim_key,
                                                stop_by_expected_gain,
)
from neckstrength.sequential.joint import CRITERIA, JointPosterior, JointSettings, relative_error, run_joint
from neckstrength.sequential.orders import order_entropies, stop_iteration, subset_table

__all__ = ["Proposal", "SequentialSettings", "SequentialState", "SimulatedSet", "StrengthGrid", "activation_bounds",
           "data_likelihood", "expected_entropy_reduction", "fit_point_estimate", "joint_ess", "log_factor",
           "pdf_entropy", "pdf_moments", "posterior_from_loglik", "run_sequence", "sample_prior", "scaled_baseline",
           "select_direction", "sim_key", "stop_by_expected_gain", "CRITERIA", "JointPosterior", "JointSettings",
           "relative_error", "run_joint", "order_entropies", "stop_iteration", "subset_table"]
