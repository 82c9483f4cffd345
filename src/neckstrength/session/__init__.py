"""The clinician-in-the-loop session on top of the Chapter 6 sequential estimator (Algorithms 7-9)
===============================================================================================

One session = one participant, one model. At every step it proposes the next test (Eq. 6.7, Eq. 6.8 with muscle
priorities, or the joint posterior's expected information gain), shows the expected information of every remaining
test (Eq. 6.6, a text bar chart like Fig. 6.8), the current estimate (posterior mean ± sd per muscle), P(deficit)
or the deficit decision and a stop recommendation; the clinician enters a force, measures another test, skips,
undoes or stops.

- :mod:`.parse`   a prompt line or CSV row -> :class:`Entry`, or :class:`InputError` with the message to show
- :mod:`.log`     :class:`SessionLog`: the append-only, hash-chained, fsync'd log and the folder lock
- :mod:`.state`   :class:`Session`, the engine (no terminal I/O): ``create``/``resume``, ``propose``, ``tell``,
  ``undo``, ``stop``, ``snapshot`` (a JSON-serialisable dict of everything a screen shows); :class:`SessionOptions`
- :mod:`.stage`   :class:`SessionInputs` (built with the settings by :func:`neckstrength.config.session_stage`),
  :class:`SessionResult` (:meth:`Session.result`, in memory) and :func:`write_session` (the files a stop writes)
- :mod:`.render`  text screens (:func:`~.render.screen`, :func:`bar_chart`, :func:`where_to_push`)
- :mod:`.plots`   the summary figure
- :mod:`.repl`    the terminal: :func:`run_interactive` and the CSV replay (:func:`replay_csv`, :func:`replay_into`),
  through the engine's API, so the terminal and any other front end give the same numbers
"""

from neckstrength.errors import InputError, SessionLockedError
from neckstrength.session.log import HEADER, LOG, SessionLog, effective_entries
from neckstrength.session.parse import (
    Entry,
    check_posture,
    parse_activations,
    parse_entry,
    parse_force,
    parse_priorities,
    read_measurements_csv,
)
from neckstrength.session.plots import summary_figure
from neckstrength.session.render import HELP, MIN_MC_CLUSTERS, bar_chart, where_to_push
from neckstrength.session.repl import replay_csv, replay_into, run_interactive
from neckstrength.session.stage import SessionInputs, SessionResult, write_session
from neckstrength.session.state import (
    CRITERIA,
    MODELS,
    Session,
    SessionOptions,
    emg_choices,
    resolve_emg_channels,
    resolve_postures,
    session_threads,
)

__all__ = [
    "InputError", "SessionLockedError", "HEADER", "LOG", "SessionLog", "effective_entries", "Entry", "check_posture",
    "parse_activations", "parse_entry", "parse_force", "parse_priorities", "read_measurements_csv", "summary_figure",
    "HELP", "MIN_MC_CLUSTERS", "bar_chart", "where_to_push", "replay_csv", "replay_into", "run_interactive",
    "CRITERIA", "MODELS", "Session", "SessionOptions", "emg_choices", "resolve_emg_channels", "resolve_postures",
    "session_threads", "SessionInputs", "SessionResult", "write_session",
]
