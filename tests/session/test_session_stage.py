"""The session as a stage (src/neckstrength/session/stage.py, config.session_stage): the settings and inputs are
built once in config.py and the engine reads no config (a session built from them runs with its config file gone);
Session.result() is what a stop writes (write_session's files hold the result's tables). p2m7, thesis scheme,
N_F 2,000: a few seconds."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.config import load_config, session_stage
from neckstrength.session import Session, SessionInputs, SessionOptions, SessionResult, write_session
from neckstrength.session.settings import SessionSettings

ROOT = Path(__file__).resolve().parents[2]
CFG = str(ROOT / "config" / "config.ci.yaml")


def test_engine_reads_no_config_and_result_is_what_is_written(tmp_path):
    opts = SessionOptions(model="p2m7", participant="P01", config=CFG, n_candidates=2000, criterion="thesis",
                          cache=str(tmp_path / "cache"))
    settings, inputs = session_stage(load_config(CFG), opts)
    assert isinstance(settings, SessionSettings) and isinstance(inputs, SessionInputs)
    assert inputs.postures is None and inputs.pset is None
    assert list(inputs.directions["name"]) == list(inputs.push) and len(inputs.U) == len(inputs.push)
    # the engine with the config file gone: nothing is read from it after session_stage
    out = tmp_path / "s"
    out.mkdir()
    s = Session(out, replace(opts, config=str(tmp_path / "no_such_config.yaml")), settings, inputs)
    s.tell(s.parse("150"))
    s.tell(s.parse("90"))
    res = s.result()
    assert isinstance(res, SessionResult)
    assert list(res.estimate["muscle"]) == s.muscles and res.header[0].startswith("clinician session: participant P01")
    assert sorted(res.steps["step"].unique()) == [0, 1, 2] and list(res.measurements["force_N"]) == [150.0, 90.0]
    paths = write_session(res, out)
    assert set(paths) == {"summary_csv", "summary_png", "steps_csv", "measurements_csv"}
    back = pd.read_csv(paths["summary_csv"], comment="#")
    np.testing.assert_allclose(back["f_c"], res.estimate["f_c"], rtol=1e-5)
    assert len(pd.read_csv(paths["steps_csv"], comment="#")) == len(res.steps)
    # a session opened the usual way (create) from the same options gives the same result
    s2 = Session.create(tmp_path / "s2", opts)
    for line in ("150", "90"):
        s2.tell(s2.parse(line))
    pd.testing.assert_frame_equal(s2.result().estimate, res.estimate)
