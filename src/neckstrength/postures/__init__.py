"""Posture as a test dimension (issue 20; thesis Sec. 6.6.2 / 7.1.2.2)
====================================================================

- :mod:`.tables`      the shipped posture tables (``data/model/postures``) and their OpenSim-free checks
- :mod:`.model`       reduced models per posture (same reduction), max wrench of (posture, direction) tests
- :mod:`.datasets`    simulated and measured data sets whose tests name a posture
- :mod:`.sequential`  the joint sequential estimator over (posture, direction) pairs, cost per posture change
- :mod:`.compare`     what postures buy: neutral-only vs neutral + postures at equal numbers of tests
"""

from neckstrength.postures.model import PostureSet, build_posture_set, pair_label, split_label
from neckstrength.postures.tables import (
    POSTURE_NAMES,
    SAGITTAL_POSTURES,
    PostureTable,
    check_posture_tables,
    load_posture_tables,
)

__all__ = [
    "POSTURE_NAMES",
    "SAGITTAL_POSTURES",
    "PostureSet",
    "PostureTable",
    "build_posture_set",
    "check_posture_tables",
    "load_posture_tables",
    "pair_label",
    "split_label",
]
