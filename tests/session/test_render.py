"""The session screen's pieces that need no session: the misfit guard's line (issue 31)."""
from __future__ import annotations

from neckstrength.sequential.decision import DecisionSettings
from neckstrength.session.render import misfit_text


def test_misfit_line_is_the_guards_own_label_when_the_history_has_it():
    s = DecisionSettings()
    label = "misfit guard: best fit 6.1% RMS, threshold 5.4%: FLAGGED, model misfit; calibrated (...)"
    assert misfit_text({"misfit_rms": 0.061, "misfit_label": label}, s) == label


def test_misfit_line_of_an_older_log_names_the_heuristic_rule():
    s = DecisionSettings()
    text = misfit_text({"misfit_rms": 0.07}, s)
    assert "7.0% RMS" in text and "heuristic" in text and f"{s.misfit_factor:g} x" in text
    assert misfit_text({"misfit_rms": float("nan")}, s) == "misfit guard: not checked yet"
