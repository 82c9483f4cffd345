"""The command line's front door: ``--version``, a description and a runnable example in every subcommand's help,
every option name that existed keeps working, and every ``neckstrength`` command of the README parses."""

import argparse
import re
import shlex
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest

from neckstrength.cli import COMMANDS, build_parser

ROOT = Path(__file__).resolve().parents[1]

# Every option of every subcommand before descriptions and aliases were added: none may disappear.
OPTIONS = {
    "derive-model": ["--multifidus-osim", "--osim", "--out", "--postures"],
    "directions": ["--config", "--out"],
    "max-wrench": ["--config", "--direction", "--model", "--strengths"],
    "validate": ["--config", "--signals"],
    "session start": ["--cache", "--config", "--criterion", "--model", "--n-candidates", "--out", "--participant",
                      "--posture-change-cost", "--postures", "--prior-scale", "--priority", "--seed", "--stop-frac",
                      "--threads"],
    "session replay": ["--cache", "--config", "--criterion", "--csv", "--model", "--n-candidates", "--out",
                       "--participant", "--posture-change-cost", "--postures", "--prior-scale", "--priority", "--seed",
                       "--stop-frac", "--threads"],
    "session resume": ["--out", "--threads"],
    "diagnose": ["--config", "--dataset", "--effects", "--extra-trials", "--measurements", "--model", "--out",
                 "--workers"],
    "import-trials": ["--angle-deg", "--config", "--mismatch", "--out", "--pad-offset", "--ratio-tol", "--signals"],
    "estimate": ["--activations", "--angle-deg", "--config", "--criterion", "--emg", "--max-iter", "--measurements",
                 "--method", "--mismatch", "--model", "--no-figures", "--out", "--pad-offset", "--participant",
                 "--ratio-tol", "--seed", "--signals", "--threads", "--trials"],
    "c3d-to-trials": ["--channel", "--config", "--out"],
    "example-lab": ["--config", "--out", "--seed"],
}


def _subparsers(parser, prefix=""):
    """command name ('session start', ...) -> its parser, for every level."""
    out = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                full = f"{prefix} {name}".strip()
                out[full] = sub
                out.update(_subparsers(sub, full))
    return out


SUBS = _subparsers(build_parser())


def test_version():
    r = subprocess.run([sys.executable, "-m", "neckstrength.cli", "--version"], capture_output=True, text=True,
                       cwd=ROOT, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"neckstrength {version('neckstrength')}"


def test_python_m_neckstrength():
    """``python -m neckstrength`` is the installed script (the package has a ``__main__``)."""
    r = subprocess.run([sys.executable, "-m", "neckstrength", "--version"], capture_output=True, text=True,
                       cwd=ROOT, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"neckstrength {version('neckstrength')}"


def test_every_command_is_described():
    assert set(SUBS) == set(COMMANDS), "COMMANDS and the parser's subcommands differ"
    assert set(OPTIONS) <= set(SUBS)


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_help_has_description_and_example(command):
    text = SUBS[command].format_help()
    description, example = COMMANDS[command]
    assert description.split()[0] in text and len(description) > 40
    assert "example:" in text and example in text
    assert example.startswith(f"neckstrength {command}")


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_example_parses(command):
    """The example in the help uses options that exist (argparse exits with 2 on an unknown one)."""
    args = build_parser().parse_args(shlex.split(COMMANDS[command][1])[1:])
    assert callable(args.func)


@pytest.mark.parametrize("command", sorted(OPTIONS))
def test_option_names_kept(command):
    have = {o for a in SUBS[command]._actions for o in a.option_strings}
    missing = set(OPTIONS[command]) - have
    assert not missing, f"{command}: options removed: {sorted(missing)}"


def test_aliases_give_one_name_per_concept():
    p = build_parser()
    a = p.parse_args(["diagnose", "--participant", "P01", "--threads", "1"])
    b = p.parse_args(["diagnose", "--dataset", "P01", "--workers", "1"])
    assert (a.dataset, a.workers) == (b.dataset, b.workers) == ("P01", 1)


def _readme_commands():
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)```", text, re.S)
    lines = "\n".join(blocks).replace("\\\n", " ").splitlines()
    inline = re.findall(r"`(\.venv/bin/neckstrength [^`]+)`", text)
    cmds = [line.split("#", 1)[0].strip() for line in lines] + inline
    return [c for c in cmds if c.startswith(".venv/bin/neckstrength ") and "<" not in c]


def test_readme_commands_parse():
    """Every `neckstrength` command the README tells users to run is accepted by the parser (not run)."""
    cmds = _readme_commands()
    assert len(cmds) >= 8
    for cmd in cmds:
        argv = shlex.split(cmd)[1:]
        if argv in (["--help"], ["--version"]):
            continue
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as exc:
            pytest.fail(f"README command does not parse ({exc.code}): {cmd}")
        assert callable(args.func), cmd
