"""What the estimators of Chapters 5 and 6 and the gap diagnosis share
=====================================================================

- :mod:`.datasets`     a data set (measured or simulated max wrenches, optional EMG bounds): :class:`Dataset`
- :mod:`.discrepancy`  data discrepancy of simulated vs measured wrenches (Eq. 5.5-5.6)
- :mod:`.scaling`      bootstrap scaling of the baseline strengths (Eq. 5.3)
- :mod:`.parameters`   free parameters (left/right tying)
"""

from neckstrength.estimation.datasets import (
                                              Dataset,
                                              SIMULATED_DATASETS,
                                              DatasetSettings,
                                              load_dataset,
                                              model_directions_table,
                                              participant_dataset,
                                              simulated_dataset,
                                              thesis_f_actual,
                                              thesis_result_table,
)
from neckstrength.estimation.discrepancy import composite_score, data_discrepancy
from neckstrength.estimation.parameters import free_parameters
from neckstrength.estimation.scaling import bootstrap_prior, bootstrap_scale

__all__ = ["Dataset", "DatasetSettings", "SIMULATED_DATASETS", "load_dataset", "model_directions_table",
           "participant_dataset", "simulated_dataset",
           "thesis_f_actual", "thesis_result_table", "composite_score", "data_discrepancy", "free_parameters",
           "bootstrap_prior", "bootstrap_scale"]
