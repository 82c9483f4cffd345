"""The report: what was reproduced and how, and what the run cost
=================================================================

- :mod:`.scorecard`  every thesis number we reproduce beside ours, with its tolerance and conclusion test
- :mod:`.runinfo`    run time and peak memory per job, software versions, seeds
- :mod:`.headline`   the README's reproduction row from the scorecard summary (``python -m ...headline``)
"""

from neckstrength.report.runinfo import environment_table, runtime_by_rule, runtime_table, software_versions
from neckstrength.report.scorecard import (
                                           SOURCES,
                                           TOLERANCES,
                                           VERDICTS,
                                           build_scorecard,
                                           scorecard_inputs,
                                           summarize,
                                           tolerance_table,
                                           tolerances,
)

__all__ = ["environment_table", "runtime_by_rule", "runtime_table", "software_versions", "SOURCES", "TOLERANCES",
           "VERDICTS", "build_scorecard", "scorecard_inputs", "summarize", "tolerance_table", "tolerances"]
