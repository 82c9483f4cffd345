"""What the scorecard reads of the configuration: :class:`ScorecardSettings`
==========================================================================

Built once by :func:`neckstrength.config.scorecard_settings`; the scorers read it from their
:class:`~neckstrength.report.scorecard.rows.Context`.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ScorecardSettings:
    """The settings that decide how a number is scored (the schema's defaults)."""

    seed: int = 20261123                        # seed: the chance rates' permutations
    thesis_dir: str = "data/thesis"             # data.thesis_dir: the printed tables
    model_dir: str = "data/model"               # data.model_dir: b3_implied_strengths.csv
    unprinted_strengths: str = "b3_implied"     # model.unprinted_strengths: recovered strengths are calibrated
    grouping_supplements: bool | str = "anatomy"   # model.grouping_supplements: 'all' (or true) applies the fitted
                                                   # supplements
    apply_b1_errata: bool = True                # model.apply_b1_errata: Table B.1 cells the erratum relocated
    mixed_model_alpha: float = 0.05             # chapter3.mixed_model.alpha: significance of the Chapter 3 tests
    eps_D: float = 0.95                         # chapter5.eps_D: Algorithm 4's convergence threshold
    sigma_clip: tuple[float, float] = (0.01, 0.3)   # chapter5.sigma_clip: sigma_c at a limit is by construction
    claim_tolerance_rel: float = 0.01           # chapter4.claim_tolerance_rel (in the Chapter 4 rows' text)
    anterior_max_azimuth_deg: float = 90.0      # chapter4.anterior_max_azimuth_deg (in the Chapter 4 rows' text)
