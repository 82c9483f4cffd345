"""The clinician session's settings from the config: :class:`SessionSettings`
==========================================================================

Built once per session with its inputs by :func:`neckstrength.config.session_stage`; the session's own options
(:class:`~neckstrength.session.state.SessionOptions`, the command line's) override some of them.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Sequence

from neckstrength.sequential.algorithms import SequentialSettings
from neckstrength.sequential.decision import DecisionSettings
from neckstrength.sequential.deficit import DeficitDefinition
from neckstrength.sequential.joint import JointSettings


@dataclass(frozen=True)
class SessionSettings:
    """What the config fixes of a session of one model (the defaults of :class:`SessionOptions` that are None)."""

    seed: int                                  # config seed (--seed overrides)
    sequential: SequentialSettings             # chapter6 (+ chapter6.model_settings.<model>): the thesis's scheme
    joint: JointSettings                       # chapter6.joint: the joint posterior
    deficit: DeficitDefinition                 # clinician.deficit: the screen's P(deficit)
    decision: DecisionSettings                 # clinician.decision (--prevalence, --noise override)
    gain_frac: float = 0.2                     # chapter6.stop.gain_frac (--stop-frac overrides)
    criterion: str = "thesis"                  # clinician.session.<model>.criterion (--criterion overrides)
    n_candidates: int | None = None            # clinician.session.<model>.n_candidates (None: chapter6's)
    postures: tuple[str, ...] = ("neutral", "flex20", "ext20", "rotL30", "rotR30", "bendL15", "bendR15")
                                               # postures.postures: the postures '--postures all' means
    force_length: str = "relative"             # postures.force_length
    model_dir: str = "data/model"              # data.model_dir: the posture tables
    test_point_spec: str | None = "data/geometry/test_point_spec.csv"   # geometry.test_point_spec: where to push
    emg_groups: tuple[str, ...] = ()          # chapter6.emg_groups.<model>: the surface EMG channels (Appendix A.1)


def resolve_postures(spec: str | Sequence[str] | None, known: Sequence[str]) -> list[str] | None:
    """``--postures`` -> the session's postures, neutral first; None for neutral only (the default session).
    ``spec``: a comma-separated string or a list; ``'all'`` = every posture of ``known`` (config postures.postures)."""
    if spec is None:
        return None
    items = [x.strip() for x in (spec.split(",") if isinstance(spec, str) else spec)]
    items = [x for x in items if x]
    if not items:
        raise ValueError(f"--postures: no posture given; allowed: all, {', '.join(known)}")
    if items == ["all"]:
        items = list(known)
    out = ["neutral"]
    for x in items:
        if x not in known:
            close = difflib.get_close_matches(x, list(known), n=1)
            hint = f" (did you mean {close[0]}?)" if close else ""
            raise ValueError(f"--postures: unknown posture '{x}'{hint}; allowed: all, {', '.join(known)}")
        if x not in out:
            out.append(x)
    return None if out == ["neutral"] else out
