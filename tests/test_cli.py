"""The ``hdrd`` command line (hdrd/cli.py): usage errors, exit statuses, help texts."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from hdrd import config
from hdrd.cli import COMMANDS, DRIVES, build_parser, main


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_a_misspelt_option_shows_the_subcommands_usage(capsys: pytest.CaptureFixture[str]) -> None:
    # Was the top-level usage ("hdrd [-h] [--version] COMMAND ..."), which does not help.
    with pytest.raises(SystemExit) as e:
        main(["run", "--simualte"])
    err = capsys.readouterr().err
    assert e.value.code == 2
    assert err.startswith("usage: hdrd run ") and "[--simulate]" in err
    assert err.rstrip().endswith("hdrd run: error: unrecognized arguments: --simualte")
    with pytest.raises(SystemExit) as e:
        main(["replay", "a.cap", "b.cap"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "hdrd replay: error: unrecognized arguments: b.cap" in err


@pytest.mark.parametrize("command", ["run", "simulate"])
def test_an_unknown_drive_is_a_usage_error_everywhere(command: str) -> None:
    # Was exit 2 in simulate but 78 in run (a config error). A word not in an option's list
    # is a usage error (2) wherever it is typed; the same word in a config file is 78.
    p = subprocess.run(
        [sys.executable, "-m", "hdrd", command, "--drive", "moon"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 2 and len(p.stderr.splitlines()) <= 12 and "Traceback" not in p.stderr
    assert p.stderr.startswith(f"usage: hdrd {command}" if command == "run" else "hdrd simulate")
    assert "'moon'" in p.stderr and "mixed" in p.stderr  # says what is allowed


def test_the_drive_lists_agree() -> None:
    from hdrd.sim.vehicle import DRIVE_TYPES

    assert DRIVES == config.DRIVES == tuple(DRIVE_TYPES)


def test_every_option_says_what_it_is() -> None:
    missing = []
    for name, sub in _subparsers().items():
        for a in sub._actions:
            if isinstance(a, argparse._HelpAction):
                continue
            if not a.help:
                missing.append(f"{name} {'/'.join(a.option_strings) or a.dest}")
    assert missing == []


@pytest.mark.parametrize(
    "command, option, shown",
    [
        ("run", "--port", "/dev/hdrd-gyro"),
        ("calibrate", "--port", "/dev/hdrd-gyro"),
        ("run", "--baud", "115200"),
        ("tune", "--candidates", "2000"),
        ("tune", "--seed", "0"),
        ("fakegyro", "--seed", "1"),
        ("fakegyro", "--minutes", "20"),
        ("simulate", "--minutes", "20"),
        ("record", "--baud", "115200"),
    ],
)
def test_defaults_are_shown(command: str, option: str, shown: str) -> None:
    sub = _subparsers()[command]
    action = next(a for a in sub._actions if option in a.option_strings)
    assert action.help and f"default {shown}" in action.help.replace("default device.port, ", "default ").replace("default device.baud, ", "default ")  # fmt: skip


@pytest.mark.parametrize("command", ["run", "calibrate"])
def test_log_level_is_an_option(command: str) -> None:
    sub = _subparsers()[command]
    action = next(a for a in sub._actions if "--log-level" in a.option_strings)
    assert tuple(action.choices or ()) == ("debug", "info", "warning", "error")


def test_every_command_is_registered_with_a_target() -> None:
    assert set(_subparsers()) == set(COMMANDS)
    assert COMMANDS["calibrate"][0] == "hdrd.calibrate_cmd:main"
