"""Regression tests for defects that fuzzing (tools/fuzz) and review found in the input
handling: each input here gave a traceback or a wrong answer before its fix."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import pytest

from hdrd.cli import main
from hdrd.config import ConfigError
from hdrd.configload import load_config
from hdrd.io.files.access import InputFileError, load_yaml
from hdrd.io.files.biasfile import BiasFileError, load_bias

BIAS_HEAD = "# hdrd static bias (eps0), written by `hdrd calibrate`; rates in deg/s, + = CCW\n"


def _bias_body(bias: str = "0.25") -> str:
    return (
        f"{BIAS_HEAD}bias_dps: {bias}\nstd_dps: 0.01\nn: 300\nduration_s: 30.0\n"
        "temp_c: null\ntime: 1700000000.0\n# end\n"
    )


@pytest.fixture
def capture(tmp_path: Path) -> Path:
    from hdrd.io.wire.codec import Frame, encode_bin

    p = tmp_path / "c.bin"
    p.write_bytes(b"".join(encode_bin(Frame(i, i * 100_000, 32768, 0, None)) for i in range(30)))
    return p


# -- a control character in a YAML file -----------------------------------------------------
# PyYAML's reader refuses control characters (NUL, ESC, ...) when the loader is built, which
# load_yaml did outside its error handling: a traceback and exit 1 at start, and on SIGHUP the
# running daemon died (the reload handler only takes ConfigError). load_yaml alone on each such
# character: test_files.py.


def test_config_with_a_control_character_is_exit_78_with_one_line(
    tmp_path: Path, capture: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    p = tmp_path / "hdrd.yaml"
    p.write_bytes(b'hdr:\n  method: "a\x1bb"\n')
    with pytest.raises(ConfigError, match=r"\.yaml, line 2, column 13: .*#x001b"):
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
    from hdrd.config import Config
    from hdrd.configload import load_config
    from hdrd.daemon.run import BiasChoice, Daemon

    p = tmp_path / "hdrd.yaml"
    p.write_text("hdr:\n  method: none\n")
    d = Daemon(Config(), "built-in defaults", lambda: load_config(p), BiasChoice(None, "startup"))
    p.write_bytes(b"hdr:\n  method: hdr+\n  c1: \x00\n")
    before = d.cfg
    d.reload_config()  # the SIGHUP handler's body: used to raise ReaderError
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
    assert len(msg) - len(str(p)) < 300


# -- hdrd simulate: sizes and the model file ----------------------------------------------------


@pytest.mark.parametrize(
    "argv, why",
    [
        (["--minutes", "1e308"], "is inf samples; at most 5,000,000 are simulated"),
        (["--minutes", "1e9"], "is 6e+11 samples; at most 5,000,000"),
        (["--hz", "1e308"], "at 1e+308 Hz is inf samples"),
        (["--seed", "-1"], "--seed must be >= 0, got -1"),
        (["--benchmark", "train", "--hz", "1e308"], "the longest benchmark drive of 52.1 min"),
    ],
)
def test_simulate_refuses_a_drive_it_cannot_make(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], why: str
) -> None:
    # Before: an OverflowError traceback (1e308), or the memory filled (1e6 minutes).
    out = tmp_path / "d.csv"
    assert main(["simulate", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and why in err and err.startswith("hdrd simulate: ")
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "made"),
    [
        (["--minutes", "0.1", "--out", "{d}/no/x.csv"], "no/x.csv"),
        (["--minutes", "0.1", "--out", "{d}/no/x.parquet"], "no/x.parquet"),
        (["--minutes", "0.1", "--out", "{d}/no/fleet", "--format", "dataset"], "no/fleet"),
        (["--benchmark", "test", "--out", "{d}/no/bench"], "no/bench/city3.csv"),
    ],
)
def test_simulate_makes_the_folders_its_out_needs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], made: str
) -> None:
    # As --json, --report and --trace do: the README's `--out drives/train` in an empty
    # folder once failed ("the folder drives does not exist"), and every example after it.
    if "x.parquet" in made or "fleet" in made:
        pytest.importorskip("pyarrow")
    rc = main(["simulate", *(a.format(d=tmp_path) for a in args)])
    assert rc == 0, capsys.readouterr().err
    assert (tmp_path / made).exists()


def test_simulate_makes_a_drive_just_inside_the_limit_of_its_arguments() -> None:
    from hdrd.sim.drive import LEAD_IN_S, MAX_SAMPLES, too_big

    longest = (MAX_SAMPLES / 10.0 - LEAD_IN_S) / 60.0  # minutes at 10 Hz, 30 s lead-in
    assert too_big(longest * 0.99999, 10.0) is None
    assert "at most 5,000,000" in str(too_big(longest * 1.001, 10.0))
    assert too_big(float("inf"), 10.0) is None  # a bad number is said where it is checked


def _unblock_later(fifo: Path, after_s: float = 3.0) -> Callable[[], None]:
    """If a reader is still blocked opening *fifo* after a while (the defect), give it a
    model to read, so that the test fails instead of hanging. Returns the function that
    ends the watch (the test calls it when done)."""
    import os
    import threading

    done = threading.Event()

    def unblock() -> None:
        if done.wait(after_s):
            return
        try:
            fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)  # ENXIO: no reader waits
        except OSError:
            return
        os.write(fd, b"effects: []\n")
        os.close(fd)

    t = threading.Thread(target=unblock, daemon=True)
    t.start()

    def stop() -> None:
        done.set()
        t.join()

    return stop


def _model_cases(tmp_path: Path, request: pytest.FixtureRequest) -> list[tuple[Path, str]]:
    import os

    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)  # used to block `hdrd simulate --model` until a writer came
    request.addfinalizer(_unblock_later(fifo))
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * (1 << 20) + "\neffects: []\n")
    cases = [
        (fifo, "is a FIFO, not a regular file"),
        (Path("/dev/zero"), "is a character device"),  # used to fill the memory
        (big, "larger than the 1 MiB allowed"),
    ]
    for name, text, why in (
        ("deep", "effects: " + "[" * 2000 + "]" * 2000 + "\n", "nested deeper than 32 levels"),
        ("digits", "effects: [{name: static_bias, bias_dps: " + "1" * 5000 + "}]\n", "converted"),
        ("esc", 'effects: [{name: "static\x1b"}]\n', "#x001b"),
        ("unhashable", "effects: [{name: [1]}]\n", "unknown effect name(s): [1]"),
        ("keys", "effects: [{name: white_noise, 1: 2, b: 3}]\n", "unknown parameter(s) 1, b"),
    ):
        p = tmp_path / f"{name}.yaml"
        p.write_text(text)
        cases.append((p, why))
    return cases


def test_simulate_model_is_read_as_the_configuration_is(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], request: pytest.FixtureRequest
) -> None:
    # The model went through open() and yaml.safe_load: a FIFO blocked, /dev/zero filled the
    # memory, nesting 2,000 deep was a RecursionError, an unhashable name a TypeError.
    from hdrd.sim.gyro import load_model

    for path, why in _model_cases(tmp_path, request):
        with pytest.raises(ValueError, match=re.escape(why)) as ei:
            load_model(path)
        assert "\n" not in str(ei.value) and str(path) in str(ei.value)
        out = tmp_path / "d.csv"
        assert main(["simulate", "--minutes", "1", "--model", str(path), "--out", str(out)]) == 78
        err = capsys.readouterr().err
        assert len(err.splitlines()) == 1 and why in err


def test_simulate_model_still_reads_a_saved_model(tmp_path: Path) -> None:
    from hdrd.sim.gyro import crs03_default_model, load_model, save_model

    p = tmp_path / "m.yaml"
    save_model(crs03_default_model(), p)
    assert load_model(p) == crs03_default_model()


# -- output.nmea_talker's documentation follows docs/protocol.md ---------------------------------


def test_nmea_talker_docs_recommend_what_protocol_md_recommends() -> None:
    # config.py's docstring and the shipped config said gpsd reads HC; docs/protocol.md
    # recommends II (an instrument; HC claims a magnetic compass).
    import re

    root = Path(__file__).resolve().parent.parent
    proto = (root / "docs" / "protocol.md").read_text()
    m = re.search(r"\*\*For gpsd, set\s+`output\.nmea_talker: (\w\w)`\*\*", proto)
    assert m, "docs/protocol.md no longer says which talker gpsd needs"
    talker = m.group(1)
    src = (root / "hdrd" / "config.py").read_text()
    doc = re.search(r'nmea_talker: str = (?:"HN"|NMEA_TALKER)\n\s+"""(.*?)"""', src, re.DOTALL)
    assert doc and f"for gpsd use {talker}" in " ".join(doc.group(1).split())
    assert "reads HC" not in doc.group(1)
    shipped = (root / "config" / "hdrd.yaml").read_text()
    comment = shipped[: shipped.index("nmea_talker:")].rsplit("nmea_ths", 1)[1]
    assert f"for gpsd use {talker}" in " ".join(comment.replace("#", " ").split())
    from hdrd import configload

    assert talker in str(configload.RULES["output.nmea_talker"][1])


def test_a_yaml_problem_quoting_a_huge_tag_is_still_a_short_line(tmp_path: Path) -> None:
    # PyYAML quotes the unknown tag whole: a bias file (or config) with a 900-character tag
    # gave a 952-character error line (found by tools/fuzz, bias surface).
    tag = "!!python/object:" + "hd" + "r" * 900
    p = tmp_path / "bias.yaml"
    p.write_text(f"bias_dps: 0.1\nstd_dps: {tag} 1\n# end\n")
    with pytest.raises(BiasFileError) as ei:
        load_bias(p)
    msg = str(ei.value)
    assert "could not determine a constructor" in msg and "\n" not in msg
    assert len(msg) - len(str(p)) < 300 and msg.endswith("...")


def _dead_ports(n: int) -> list[int]:
    """n UDP ports on 127.0.0.1 where nothing listens (bound, then closed)."""
    import socket

    socks = []
    for _ in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        socks.append(s)
    ports = [int(s.getsockname()[1]) for s in socks]
    for s in socks:
        s.close()
    return ports


def test_thousands_of_udp_destinations_are_summed_up_at_stop() -> None:
    """5,000 destinations used to log 5,000 lines at stop: now one summary line and the
    lines of the destinations that failed most (at most UDP_STATS_LINES)."""
    import socket
    import time

    from structlog.testing import capture_logs

    from hdrd.daemon import listeners as daemon_mod
    from hdrd.io.net.publish import UdpJsonPublisher, UdpNmeaPublisher

    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    good = ("127.0.0.1", int(rx.getsockname()[1]))
    dead = [("127.0.0.1", p) for p in _dead_ports(15)]
    many = UdpJsonPublisher([good] * (5000 - len(dead)) + dead)
    few = UdpNmeaPublisher([good, dead[0]])
    try:
        for step in range(3):
            msg = {"class": "HDR", "v": 1, "step": step, "heading": 1.0, "status": "ok"}
            many.on_message(msg)
            few.on_message(msg)
            time.sleep(0.05)  # lets the ICMP errors come back
        with capture_logs() as logs:
            daemon_mod.stop_publishers([many, few])
    finally:
        rx.close()
    assert len(logs) < 20, len(logs)  # a screenful, not 5,002 lines
    limit = daemon_mod.UDP_STATS_LINES
    summary = [e for e in logs if e["event"] == "output_udp_summary"]
    lines = [e for e in logs if e["event"] == "output_udp_stats"]
    assert len(logs) <= limit + 3, len(logs)
    (s,) = summary
    assert s["output"] == "udp" and s["destinations"] == 5000 and s["sent"] == 3 * 5000
    assert s["failing"] >= 1 and s["by_error"].get("ECONNREFUSED", 0) >= 1
    assert s["log_level"] == "warning"
    udp_lines = [e for e in lines if e["output"] == "udp"]
    assert 1 <= len(udp_lines) <= limit
    assert all(e["errors"] >= 1 for e in udp_lines)  # the failing ones, not the 4,985 good
    # a few destinations: one line each, as before
    assert sorted(e["dest"] for e in lines if e["output"] == "nmea_udp") == sorted(
        f"{h}:{p}" for h, p in (good, dead[0])
    )
