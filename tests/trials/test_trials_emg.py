"""EMG processing of Appendix A on signals with a known envelope."""

import numpy as np
import pandas as pd
import pytest

from neckstrength.io import DataValidationError
from neckstrength.trials.emg import envelope, envelope_values, normalise


def _trial_table(peaks):
    n = len(peaks)
    return pd.DataFrame({"row": np.arange(1, n + 1), "line": np.arange(2, n + 2), "participant": "P01",
                         "direction": "back", "block": "main", "trial": np.arange(1, n + 1), "peak_time_s": peaks})


def _signals(tmp_path, amps, fs=1000.0, dur=3.0, seed=3):
    rng = np.random.default_rng(seed)
    t = np.arange(0, dur, 1 / fs)
    rows = []
    for k, amp in enumerate(amps):
        a = amp * np.clip(t / 2.0, 0, 1)                            # ramp to full effort at 2 s
        x = a * np.sign(rng.standard_normal(len(t)))                 # |x| = amplitude exactly
        rows.append(pd.DataFrame({"participant": "P01", "direction": "back", "block": "main", "trial": k + 1,
                                  "time_s": t, "SCM_R": x + 0.3}))   # DC offset removed by the rectifier
    p = tmp_path / "signals.csv"
    pd.concat(rows).to_csv(p, index=False)
    return p


def test_envelope_of_constant_amplitude():
    t = np.arange(0, 1, 0.001)
    x = 2.0 * np.sign(np.sin(2 * np.pi * 50 * t + 0.1))
    env = envelope(t, x)
    assert np.allclose(env[200:800], 2.0, atol=0.02)


def test_values_250ms_before_peak_and_normalised(tmp_path):
    p = _signals(tmp_path, [1.0, 2.0])
    tr = envelope_values(p, _trial_table([2.5, 1.25]))
    # trial 1: read-out at 2.25 s (full effort: amplitude 1); trial 2: at 1.0 s (half way up the ramp: 1.0)
    assert tr.loc[0, "emg_SCM_R"] == pytest.approx(1.0, abs=0.03)
    assert tr.loc[1, "emg_SCM_R"] == pytest.approx(1.0, abs=0.03)
    assert tr.loc[1, "emgmax_SCM_R"] == pytest.approx(2.0, abs=0.03)
    n = normalise(tr)
    assert n.loc[0, "act_SCM_R"] == pytest.approx(0.5, abs=0.02) and n.loc[1, "act_SCM_R"] == pytest.approx(0.5,
                                                                                                           abs=0.02)


def test_signals_errors_name_row_and_field(tmp_path):
    p = _signals(tmp_path, [1.0])
    with pytest.raises(DataValidationError, match="not in the trial table") as e:
        envelope_values(p, _trial_table([2.5]).assign(trial=[7]))
    assert e.value.field == "trial" and e.value.row == 1
    with pytest.raises(DataValidationError, match="outside the recorded") as e:
        envelope_values(p, _trial_table([0.1]))
    with pytest.raises(DataValidationError, match="no peak_time_s") as e:
        envelope_values(p, _trial_table([np.nan]))
    assert e.value.field == "peak_time_s"
