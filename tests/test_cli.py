"""The ``hdrd`` command line (hdrd/cli.py): usage errors, exit statuses, help texts."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from hdrd import config, configload
from hdrd.cli import build_parser, main
from hdrd.cliargs import DRIVES
from hdrd.clicommands import COMMANDS


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


def test_the_drives_are_the_simulators_own_list() -> None:
    # One home (hdrd.sim.vehicle.DRIVE_TYPES), read lazily by the command line and the
    # configuration; an unknown drive is refused naming the simulator's list.
    from hdrd.sim.vehicle import DRIVE_TYPES

    assert tuple(DRIVES) == tuple(DRIVE_TYPES) and "moon" not in DRIVES
    with pytest.raises(config.ConfigError, match="one of " + ", ".join(DRIVE_TYPES)):
        configload.parse_config({"simulate": {"drive": "moon"}})
    assert configload.parse_config({"simulate": {"drive": "city"}}).simulate.drive == "city"


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
    assert COMMANDS["calibrate"][0] == "hdrd.commands.calibrate:main"


def _documents(help_text: str, default: object) -> bool:
    """Whether an option's expanded help gives ``default``: the word and the value (a number
    in any spelling: 20 for 20.0; an empty list as "none")."""
    import re

    if "default" not in help_text:
        return False
    if isinstance(default, (list, tuple)) and not default:
        return "none" in help_text
    if str(default) in help_text:
        return True
    if isinstance(default, (int, float)) and not isinstance(default, bool):
        numbers = re.findall(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", help_text)
        return any(float(n) == float(default) for n in numbers)
    return False


def test_every_option_with_a_default_shows_it() -> None:
    """The README promises that `hdrd COMMAND --help` lists every option and its default:
    each option that takes a value and has a default (not None) must give it in its help,
    whatever the command, including options added later. A switch is off unless given; an
    option whose default is None says in its own words where its default comes from."""
    missing = []
    for name, sub in _subparsers().items():
        formatter = sub._get_formatter()
        for a in sub._actions:
            if not a.option_strings or a.nargs == 0 or a.default in (None, argparse.SUPPRESS):
                continue
            text = formatter._expand_help(a) if a.help else ""
            if not _documents(" ".join(text.split()), a.default):
                missing.append(f"hdrd {name} {'/'.join(a.option_strings)}: {text!r}")
    assert missing == []


def test_help_output_ends_each_such_option_with_its_default() -> None:
    """What a user sees: the default appended where the help did not give it."""
    p = subprocess.run(
        [sys.executable, "-m", "hdrd", "fakegyro", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    text = " ".join(p.stdout.split())
    assert "--garbage P probability of garbage bytes before a frame (default: 0.0)" in text
    assert "--pull-for S how long a pull lasts, s (default: 5.0)" in text
    assert "(default: None)" not in text and "(default: False)" not in text


def _run_overrides() -> dict[str, str]:
    """Configuration key -> the `hdrd run` option (dest) that overrides it (hdrd.cliconfig)."""
    from hdrd.cliconfig import config_overrides

    sub = _subparsers()["run"]
    dests = {a.dest for a in sub._actions if a.option_strings}
    marked = argparse.Namespace(**{d: f"@{d}" for d in dests if d != "gpsd"}, gpsd=None)
    out = {}
    for key, value in config_overrides(marked).items():
        text = "".join(value) if isinstance(value, tuple) else value
        if isinstance(text, str) and text.startswith("@"):
            out[key] = text[1:]
    return out


def test_run_help_names_each_configuration_default() -> None:
    """`hdrd run`'s options override configuration keys; each says which key, and that key's
    built-in default, as the configuration has it (so the help cannot drift from it)."""
    from hdrd.config import Config

    def shown(v: object) -> str:
        if isinstance(v, bool):
            return "on" if v else "off"
        if isinstance(v, tuple) and not v:
            return "none"
        if isinstance(v, float):
            return f"{v:g}"
        return str(v)

    sub = _subparsers()["run"]
    helps = {a.dest: " ".join((a.help or "").split()) for a in sub._actions}
    mapping = _run_overrides()
    assert len(mapping) >= 12, mapping
    wrong = []
    for key, dest in mapping.items():
        section, name = key.split(".")
        sec = getattr(Config(), section)
        default = getattr(sec.params if section == "hdr" and name != "method" else sec, name)
        want = key if default == "" else f"{key}, {shown(default)}"
        if want not in helps[dest]:
            wrong.append(f"--{dest}: wants {want!r}: {helps[dest]!r}")
    assert wrong == []
