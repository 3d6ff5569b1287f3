"""Regression tests for defects that fuzzing (bench/fuzz.py) and review found in the input
handling: each input here gave a traceback or a wrong answer before its fix."""

from __future__ import annotations

from pathlib import Path

import pytest

from hdrd.calibrate import BiasFileError, load_bias
from hdrd.cli import main
from hdrd.config import ConfigError, load_config
from hdrd.inputfiles import InputFileError, load_yaml

BIAS_HEAD = "# hdrd static bias (eps0), written by `hdrd calibrate`; rates in deg/s, + = CCW\n"


def _bias_body(bias: str = "0.25") -> str:
    return (
        f"{BIAS_HEAD}bias_dps: {bias}\nstd_dps: 0.01\nn: 300\nduration_s: 30.0\n"
        "temp_c: null\ntime: 1700000000.0\n# end\n"
    )


@pytest.fixture
def capture(tmp_path: Path) -> Path:
    from hdrd.frames import Frame, encode_bin

    p = tmp_path / "c.bin"
    p.write_bytes(b"".join(encode_bin(Frame(i, i * 100_000, 32768, 0, None)) for i in range(30)))
    return p


# -- a control character in a YAML file -----------------------------------------------------
# PyYAML's reader refuses control characters (NUL, ESC, ...) when the loader is built, which
# load_yaml did outside its error handling: a traceback and exit 1 at start, and on SIGHUP the
# running daemon died (the reload handler only takes ConfigError).


@pytest.mark.parametrize("char", ["\x00", "\x1b", "\x07", "\ufffe"])
def test_yaml_with_a_control_character_is_one_input_error(char: str) -> None:
    with pytest.raises(InputFileError) as ei:
        load_yaml(f"hdr:\n  method: a{char}b\n")
    assert f"#x{ord(char):04x}" in str(ei.value)
    assert ei.value.where == "line 2, column 12"


def test_config_with_a_control_character_is_exit_78_with_one_line(
    tmp_path: Path, capture: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    p = tmp_path / "hdrd.yaml"
    p.write_bytes(b'hdr:\n  method: "a\x1bb"\n')
    with pytest.raises(ConfigError, match=r"\(yaml\) = 'line 2, column 13'.*#x001b"):
        load_config(p)
    assert main(["replay", str(capture), "--config", str(p)]) == 78
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "#x001b" in err and "\x1b" not in err


def test_bias_file_with_a_control_character_is_refused_in_one_line(
    tmp_path: Path, capture: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    p = tmp_path / "bias.yaml"
    p.write_text(_bias_body("0.25\x00"))
    with pytest.raises(BiasFileError, match=r"not valid YAML at line 2, column 15: .*#x0000"):
        load_bias(p)
    assert main(["replay", "--bias-file", str(p), str(capture)]) == 1
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "#x0000" in err


def test_sighup_with_a_control_character_keeps_the_running_configuration(tmp_path: Path) -> None:
    import argparse

    from hdrd.config import Config
    from hdrd.daemon import BiasChoice, Daemon

    p = tmp_path / "hdrd.yaml"
    p.write_text("hdr:\n  method: none\n")
    args = argparse.Namespace(config=str(p))
    d = Daemon(Config(), "built-in defaults", args, BiasChoice(None, "startup"))
    p.write_bytes(b"hdr:\n  method: hdr+\n  c1: \x00\n")
    before = d.cfg
    d._reload()  # the SIGHUP handler's body: used to raise ReaderError
    assert d.cfg is before


# -- a NUL character in a path from the configuration ---------------------------------------
# os.open() raises ValueError for a path with a NUL: `calibration.bias_file: "a\0b"` was a
# traceback at start (run, replay, calibrate); `device.port` made the daemon retry for ever.


@pytest.mark.parametrize(
    "text, key",
    [
        ('calibration:\n  bias_file: "/tmp/a\\0b"\n', "calibration.bias_file"),
        ('device:\n  port: "/dev/tty\\0USB0"\n', "device.port"),
    ],
)
def test_a_path_with_a_nul_character_is_a_config_error(
    tmp_path: Path, capture: Path, capsys: pytest.CaptureFixture[str], text: str, key: str
) -> None:
    p = tmp_path / "hdrd.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=rf"{key} = .*without a NUL character"):
        load_config(p)
    assert main(["replay", str(capture), "--config", str(p)]) == 78
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and key in err


# -- a YAML tag whose constructor fails in an unforeseen way --------------------------------
# `!!timestamp 'not a time'` made PyYAML's timestamp constructor raise AttributeError, which
# the loader's guard (ValueError, OverflowError) let through: a traceback, and a daemon that
# died on SIGHUP.


@pytest.mark.parametrize("tag", ["!!timestamp 'not a time'", "!!timestamp 12"])
def test_a_yaml_value_its_tag_cannot_take_is_one_input_error(
    tmp_path: Path, capture: Path, capsys: pytest.CaptureFixture[str], tag: str
) -> None:
    with pytest.raises(
        InputFileError, match=r"value cannot be converted \(not a valid timestamp\)"
    ):
        load_yaml(f"hdr:\n  c1: {tag}\n")
    p = tmp_path / "hdrd.yaml"
    p.write_text(f"hdr:\n  c1: {tag}\n")
    assert main(["replay", str(capture), "--config", str(p)]) == 78
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "line 2, column 7" in err
    b = tmp_path / "bias.yaml"
    b.write_text(_bias_body(tag))
    with pytest.raises(BiasFileError, match="not a valid timestamp"):
        load_bias(b)


# -- a long unknown key -----------------------------------------------------------------------
# The value shown in a config error was cut to 60 characters but the key was not: a 500-
# character key (YAML allows 1024) made a 600-character line.


def test_a_long_unknown_key_is_cut_in_the_error(tmp_path: Path) -> None:
    p = tmp_path / "hdrd.yaml"
    p.write_text("hdr:\n  " + "k" * 1000 + ": 1\n")
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    msg = str(ei.value)
    assert "hdr.kkk" in msg and "k" * 100 not in msg and "unknown key" in msg
    assert len(msg) < 300
