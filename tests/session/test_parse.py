"""Parsing the clinician's entries (src/neckstrength/session/parse.py): forces in newtons only, activations in
[0, 1] of model muscles, directions known and untested; every rejection carries the message shown at the prompt."""

import pytest

from neckstrength.io import MAX_PLAUSIBLE_FORCE_N
from neckstrength.session import InputError, parse_activations, parse_entry, parse_force

DIRS = ["forehead", "backHigh", "chinFront", "chinUnder", "backLow", "back", "noseBelow"]
MUSCLES = ["TC-E", "TC-F", "TS-B", "TS-E", "TS-F", "CS-E", "CS-F"]


@pytest.mark.parametrize("text, value", [("142", 142.0), ("142 N", 142.0), ("142N", 142.0), (" 1.5e2 ", 150.0),
                                         (f"{MAX_PLAUSIBLE_FORCE_N:g}", MAX_PLAUSIBLE_FORCE_N)])
def test_parse_force_accepts_newtons(text, value):
    assert parse_force(text) == value


@pytest.mark.parametrize("text, message", [
    ("abc", "not a number"), ("-5", "negative"), ("0", "force 0 N"), ("nan", "not a"),
    ("5000", f"bound {MAX_PLAUSIBLE_FORCE_N:g} N"), ("120 kN", "wrong unit 'kN'"), ("12 Nm", "a moment"),
    ("12 N m", "a moment"), ("30 lbf", "wrong unit 'lbf'"), ("20kg", "wrong unit 'kg'")])
def test_parse_force_rejects_with_message(text, message):
    with pytest.raises(InputError, match=message):
        parse_force(text)


def test_parse_activations():
    assert parse_activations("act=TS-B:0.4,TS-E:1", MUSCLES) == {"TS-B": 0.4, "TS-E": 1.0}
    for bad, msg in [("act=TS-B:1.5", r"outside \[0, 1\]"), ("act=TS-B:-0.1", "outside"), ("act=XX:0.2", "unknown muscle"),
                     ("act=TS-B", "MUSCLE:VALUE"), ("act=TS-B:x", "not a number"), ("act=TS-B:0.1,TS-B:0.2", "twice")]:
        with pytest.raises(InputError, match=msg):
            parse_activations(bad, MUSCLES)


def test_parse_entry_directions():
    e = parse_entry("measure chinFront 90 act=TS-B:0.3", "back", DIRS, ["forehead"], MUSCLES)
    assert (e.kind, e.direction, e.force, e.activations) == ("measure", "chinFront", 90.0, {"TS-B": 0.3})
    assert parse_entry("120", "back", DIRS, [], MUSCLES).direction == "back"
    assert parse_entry("skip", "back", DIRS, [], MUSCLES).direction == "back"
    with pytest.raises(InputError, match="unknown direction 'chinfrnt'.*did you mean chinFront"):
        parse_entry("measure chinfrnt 90", "back", DIRS, [], MUSCLES)
    with pytest.raises(InputError, match="already been tested"):
        parse_entry("measure forehead 90", "back", DIRS, ["forehead"], MUSCLES)
    with pytest.raises(InputError, match="force is missing"):
        parse_entry("measure chinFront", "back", DIRS, [], MUSCLES)


def test_emg_channels_offered_and_resolved():
    """The EMG channels of a model (surface: the configured groups, both sides; deep: the decision's group) and the
    --emg choice: names, 'surface', 'deep', 'all', none; an unknown channel names the allowed ones."""
    import pytest

    from neckstrength.session import emg_choices, resolve_emg_channels

    muscles = ["hyoids-R", "hyoids-L", "SCM-R", "SCM-L", "mf-R", "mf-L", "trap-R", "trap-L"]
    ch = emg_choices(muscles, ("SCM", "trap", "mf"), [5, 4])
    assert ch == {"surface": ["SCM-R", "SCM-L", "trap-R", "trap-L"], "deep": ["mf-R", "mf-L"]}
    assert resolve_emg_channels(None, ch) is None
    assert resolve_emg_channels("none", ch) == resolve_emg_channels([], ch) == []
    assert resolve_emg_channels("deep", ch) == ["mf-R", "mf-L"]
    assert resolve_emg_channels("trap-L, SCM-R", ch) == ["SCM-R", "trap-L"]
    assert resolve_emg_channels(["all"], ch) == ch["surface"] + ch["deep"]
    with pytest.raises(ValueError, match="did you mean SCM-R.*allowed: SCM-R"):
        resolve_emg_channels("SCM-r", ch)
    with pytest.raises(ValueError, match="not an EMG channel"):
        resolve_emg_channels("hyoids-R", ch)
