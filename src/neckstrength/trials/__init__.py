"""From a lab's raw trials to the tables the estimators read (Appendix A)
=========================================================================

- :mod:`.formats`    the trial table (one row per trial; ``docs/trials.md``) and its validation
- :mod:`.resolve`    load-cell wrench -> skull frame (pad offset), direction matching (Eq. A.2)
- :mod:`.select`     the repeat-trial rule (largest of 2-3 efforts) and the start/end fatigue check
- :mod:`.emg`        EMG: rectify, filter, normalise to each muscle's maximum, read 250 ms before the peak
- :mod:`.report`     quality report: per trial, per participant, every exclusion with its reason; a figure
- :mod:`.importer`   the whole import (:func:`import_trials`, then :func:`write_import`)
- :mod:`.c3d`        optional C3D reader (needs the ``c3d`` extra, imported lazily)
- :mod:`.synthetic`  the SYNTHETIC example lab data set generated from the model
"""

from neckstrength.trials.formats import CARDINAL, EMG_CHANNELS, read_trials
from neckstrength.trials.importer import (
    OUTPUT_FILES,
    ImportResult,
    ImportSettings,
    default_outputs,
    import_to_folder,
    import_trials,
    write_import,
)
from neckstrength.trials.resolve import MatchSettings, default_frames, match, to_skull
from neckstrength.trials.select import fatigue_table, select_trials

__all__ = ["CARDINAL", "EMG_CHANNELS", "read_trials", "OUTPUT_FILES", "ImportResult", "ImportSettings",
           "default_outputs", "import_to_folder", "import_trials", "write_import", "MatchSettings", "default_frames",
           "match", "to_skull", "fatigue_table", "select_trials"]
