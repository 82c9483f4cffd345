"""Pipeline stage of ``workflow/rules/trials.smk``: the trial import (rule, script and function share a name)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

from neckstrength.config import plain
from neckstrength.pipeline.common import load_directions
from neckstrength.trials import ImportSettings, import_trials, write_import


def trials_import(config: Mapping, trialset: str, trials_csv: str | Path, directions_csv: str | Path,
                  outputs: Mapping[str, str | Path]) -> dict:
    """Import one trial table (config ``trials.datasets``) with config ``trials.settings`` and the optional EMG
    signals file ``trials.signals.<trialset>``; write ``outputs``."""
    t = config["trials"]
    settings = plain(t["settings"]) if "settings" in t else None
    signals_csv = t["signals"].get(trialset) if "signals" in t else None
    res = import_trials(trials_csv, load_directions(directions_csv), ImportSettings.from_mapping(settings),
                        signals_csv)
    write_import(res, outputs)
    s = res.summary
    print(f"{s['trials']} trials, {s['participants']} participants: {s['matched']} matched, {s['kept']} kept, "
          f"{s['excluded_trials']} not used ({s['excluded_mismatch']} not matched), {s['missing_directions']} "
          f"direction(s) without a value; fatigued: {', '.join(s['fatigued']) or 'none'}")
    return s
