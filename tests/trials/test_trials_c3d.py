"""C3D import: channel units, the 100 ms window and the peak, and a file round trip through ezc3d."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from neckstrength.io import DataValidationError
from neckstrength.trials import default_frames, import_trials
from neckstrength.trials.c3d import c3d_to_tables, trial_from_analogs

LABELS = ["Fx", "Fy", "Fz", "Mx", "My", "Mz", "SCM_R"]


def _analogs(peak_s=1.5, rate=1000.0, dur=2.5, moment_unit_scale=1.0, seed=0):
    t = np.arange(0, dur, 1 / rate)
    ramp = np.exp(-0.5 * ((t - peak_s) / 0.3) ** 2)
    F = np.array([-120.0, -16.0, 0.0])[:, None] * ramp                 # 'back': posterior force
    M = np.array([0.0, 0.0, 5.6])[:, None] * ramp * moment_unit_scale
    rng = np.random.default_rng(seed)
    emg = (0.2 + ramp) * np.sign(rng.standard_normal(len(t)))
    return np.vstack([F, M, emg]), t


def test_peak_units_and_window(directions):
    from neckstrength.trials.resolve import target_wrenches

    u = target_wrenches(directions)["back"][0]
    data, t = _analogs(moment_unit_scale=1000.0)
    row, sig = trial_from_analogs(LABELS, ["N", "N", "N", "Nmm", "Nmm", "Nmm", "V"], 1000.0, data, u,
                                  default_frames()["skull"])
    assert row["peak_time_s"] == pytest.approx(1.5, abs=0.01)
    assert row["Mz"] == pytest.approx(5.6, rel=0.01) and row["Fx"] == pytest.approx(-120.0, rel=0.01)
    assert list(sig.columns) == ["time_s", "SCM_R"] and len(sig) == len(t)
    with pytest.raises(DataValidationError, match="unit 'V' of channel 'Mx'"):
        trial_from_analogs(LABELS, ["N", "N", "N", "V", "V", "V", "V"], 1000.0, data, u, default_frames()["skull"])
    with pytest.raises(DataValidationError, match="no analog channel 'Force.Fx1'") as e:
        trial_from_analogs(LABELS, [""] * 7, 1000.0, data, u, default_frames()["skull"], {"Fx": "Force.Fx1"})
    assert e.value.field == "Fx"


_WRITER = """
import json, sys
import numpy as np
import ezc3d

path, npy, meta = sys.argv[1:4]
data = np.load(npy)
labels, units, rate = json.loads(meta)
c = ezc3d.c3d()
n = data.shape[1]
c["parameters"]["POINT"]["RATE"]["value"] = [rate / 10]
c["parameters"]["POINT"]["LABELS"]["value"] = ("none",)
c["data"]["points"] = np.zeros((4, 1, n // 10))
c["parameters"]["ANALOG"]["RATE"]["value"] = [rate]
c["parameters"]["ANALOG"]["LABELS"]["value"] = tuple(labels)
c["parameters"]["ANALOG"]["UNITS"]["value"] = tuple(units)
c["data"]["analogs"] = data[None, :, :]
c.write(path)
"""


def _write_c3d(path, data, labels, units, rate=1000.0):
    # Written in a fresh process: ezc3d and opensim are both SWIG modules, and once opensim is loaded (the model
    # derivation tests run earlier in the same pytest process) ezc3d's writer fails its C++ overload resolution
    # (TypeError in Parameter_set). Reading is not affected; users do not load both in one process.
    import json
    import subprocess
    import sys

    npy = Path(str(path) + ".npy")
    np.save(npy, data)
    r = subprocess.run([sys.executable, "-c", _WRITER, str(path), str(npy), json.dumps([labels, units, rate])],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr


def test_c3d_round_trip_to_import(tmp_path, directions):
    rows = []
    for k, peak in enumerate((1.5, 1.2)):
        data, _ = _analogs(peak_s=peak, seed=k)
        data[:3] *= 1.0 + 0.05 * k
        _write_c3d(tmp_path / f"t{k + 1}.c3d", data, ["F1", "F2", "F3", "M1", "M2", "M3", "emg1"],
                   ["N", "N", "N", "N*m", "N*m", "N*m", "V"])
        rows.append({"path": f"t{k + 1}.c3d", "participant": "P01", "direction": "back", "block": "main",
                     "trial": k + 1, "frame": "skull"})
    pd.DataFrame(rows).to_csv(tmp_path / "manifest.csv", index=False)
    chans = {"Fx": "F1", "Fy": "F2", "Fz": "F3", "Mx": "M1", "My": "M2", "Mz": "M3", "SCM_R": "emg1"}
    trials, signals = c3d_to_tables(tmp_path / "manifest.csv", directions, chans)
    assert list(trials["peak_time_s"].round(2)) == [1.5, 1.2]
    trials.to_csv(tmp_path / "trials.csv", index=False)
    signals.to_csv(tmp_path / "signals.csv", index=False)
    res = import_trials(tmp_path / "trials.csv", directions, signals_csv=tmp_path / "signals.csv")
    sel = res.selected
    assert list(sel["kept"]) == [False, True] and sel["matched"].all()
    # EMG read 250 ms before each peak, normalised to the largest envelope over both trials
    assert 0.5 < sel.loc[1, "act_SCM_R"] < 1.0
    assert res.max_force.set_index("direction").loc["back", "P01"] == pytest.approx(sel.loc[1, "force_N"])


def _manifest(tmp_path, name="manifest.csv", n=1):
    rows = []
    for k in range(n):
        data, _ = _analogs(seed=k)
        _write_c3d(tmp_path / f"t{k + 1}.c3d", data, LABELS, ["N", "N", "N", "N*m", "N*m", "N*m", "V"])
        rows.append({"path": f"t{k + 1}.c3d", "participant": "P01", "direction": "back", "block": "main",
                     "trial": k + 1, "frame": "skull"})
    pd.DataFrame(rows).to_csv(tmp_path / name, index=False)
    return tmp_path / name


def test_c3d_to_trials_never_overwrites_its_manifest(tmp_path, capsys, monkeypatch):
    from neckstrength.cli import main

    monkeypatch.chdir(Path(__file__).resolve().parents[2])
    manifest = _manifest(tmp_path, "trials.csv")
    before = manifest.read_bytes()
    for extra in ([], ["--force"]):
        assert main(["c3d-to-trials", str(manifest), "--out", str(tmp_path)] + extra) == 2
        assert f"{manifest}: is an input of this command and is never overwritten" in capsys.readouterr().err
        assert manifest.read_bytes() == before
    # another folder: written; a second run there needs --force
    assert main(["c3d-to-trials", str(manifest), "--out", str(tmp_path / "out")]) == 0
    assert main(["c3d-to-trials", str(manifest), "--out", str(tmp_path / "out")]) == 2
    assert "trials.csv: exists (and 1 more output(s)); give --force" in capsys.readouterr().err
    assert main(["c3d-to-trials", str(manifest), "--out", str(tmp_path / "out"), "--force"]) == 0


def test_manifest_entry_that_is_a_folder_is_refused_at_once(tmp_path):
    import subprocess
    import sys

    manifest = _manifest(tmp_path, n=2)
    (tmp_path / "t2.c3d").unlink()
    (tmp_path / "t2.c3d").mkdir()                   # the second entry names a folder
    root = Path(__file__).resolve().parents[2]
    r = subprocess.run([sys.executable, "-m", "neckstrength.cli", "c3d-to-trials", str(manifest), "--out",
                        str(tmp_path / "out")], cwd=root, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert f"{manifest}, row 2 (line 3), field 'path': {tmp_path / 't2.c3d'}: is a folder, not a C3D file" in r.stderr
    assert not (tmp_path / "out").exists()


def test_truncated_c3d_is_refused(tmp_path, directions):
    manifest = _manifest(tmp_path)
    full = (tmp_path / "t1.c3d").read_bytes()
    trials, _ = c3d_to_tables(manifest, directions)
    assert trials.loc[0, "peak_time_s"] == pytest.approx(1.5, abs=0.01)
    (tmp_path / "t1.c3d").write_bytes(full[: len(full) // 2])       # cut at half its length
    with pytest.raises(DataValidationError, match=r"t1.c3d: truncated: the header announces 250 frames, which need "
                                                  rf"\d+ bytes; the file has {len(full) // 2}"):
        c3d_to_tables(manifest, directions)
