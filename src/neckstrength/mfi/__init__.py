"""Chapter 3: muscle fat infiltration (MFI) of the deep cervical extensors.

The thesis (Sec. 3.3) measured MFI = IF/(IF+IW) per participant, side, cervical
level (C3-C7) and muscle quartile (Q1 medial .. Q4 lateral); the per-participant
data were never published.  This subpackage holds (import downward only):

- :mod:`neckstrength.mfi.schema`       the per-participant, per-ROI data schema and its validation
- :mod:`neckstrength.mfi.synthetic`    a SYNTHETIC cohort generator calibrated to Tables 3.1 / 3.2 and to
                                       the reported rater agreement
- :mod:`neckstrength.mfi.reliability`  Bland-Altman limits of agreement, ICC (Shrout & Fleiss forms)
- :mod:`neckstrength.mfi.mixedmodel`   the linear mixed model of Sec. 3.3.3 (statsmodels MixedLM), Wald
                                       tests, estimated marginal means, Bonferroni pairwise comparisons
- :mod:`neckstrength.mfi.tables`       Table 3.2 regenerated from data, thesis-vs-ours comparison
- :mod:`neckstrength.mfi.plots`        Figs. 3.2-3.4
- :mod:`neckstrength.pipeline.chapter3`       one function per Snakemake rule
"""

from .schema import GROUPS, LEVELS, MFI_SCHEMA, QUARTILES, SIDES, read_mfi, validate_mfi_frame

__all__ = ["GROUPS", "LEVELS", "QUARTILES", "SIDES", "MFI_SCHEMA", "read_mfi", "validate_mfi_frame"]
