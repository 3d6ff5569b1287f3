"""hdrd.daemon.run: the run loop in this process: where the bias comes from, which publishers
a configuration makes, a whole run on the built-in simulated gyro (every step published,
systemd told on a real NOTIFY_SOCKET, the signal handlers put back), and what a reload takes
and what it keeps.

``hdrd run`` as a process (a fake gyro on a pty, signals, cable pulls, start-up under
trouble): test_daemon.py, test_daemon_startup.py, test_rel_daemon.py, test_run_stress.py.
"""

from __future__ import annotations

import json
import signal
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from hdrd.config import Config, ConfigError
from hdrd.configload import apply_overrides
from hdrd.core.calibrate import BiasRecord
from hdrd.daemon.listeners import Outputs, build_publishers
from hdrd.daemon.run import BiasChoice, Daemon, choose_bias
from hdrd.io.files.biasfile import BiasFileError, save_bias
from hdrd.io.net.publish import StdoutPublisher, UdpJsonPublisher

WAIT_S = 60.0  # upper bound for a run that should take a second or two

# -- where the bias comes from -------------------------------------------------------------


@pytest.fixture
def state_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The unit's state directory (where the default bias file is), empty."""
    d = tmp_path / "state"
    d.mkdir()
    monkeypatch.setenv("STATE_DIRECTORY", str(d))
    return d


def test_bias_from_the_command_line_wins(state_dir: Path) -> None:
    save_bias(state_dir / "bias.yaml", BiasRecord(0.5, 0.01, 300, 30.0))
    choice = choose_bias(Config(), -0.125)
    assert choice.source == "--bias" and choice.record is not None
    assert choice.record.bias_dps == -0.125


def test_bias_from_the_default_file_else_measured_at_start(state_dir: Path) -> None:
    assert choose_bias(Config(), None) == BiasChoice(None, "startup")
    rec = BiasRecord(0.5, 0.01, 300, 30.0, 21.0, 1.7e9)
    save_bias(state_dir / "bias.yaml", rec)
    assert choose_bias(Config(), None) == BiasChoice(rec, str(state_dir / "bias.yaml"))


def test_a_named_bias_file_must_exist(state_dir: Path, tmp_path: Path) -> None:
    named = tmp_path / "mine.yaml"
    cfg = apply_overrides(Config(), {"calibration.bias_file": str(named)})
    with pytest.raises(BiasFileError, match="not found"):
        choose_bias(cfg, None)
    # ... even when a bad file may fall back to measuring: a typo is not a bad file
    lenient = apply_overrides(cfg, {"calibration.on_bad_bias_file": "calibrate"})
    with pytest.raises(BiasFileError, match="not found"):
        choose_bias(lenient, None)
    rec = BiasRecord(0.25, 0.01, 300, 30.0)
    save_bias(named, rec)
    assert choose_bias(cfg, None) == BiasChoice(rec, str(named))


def test_a_bad_bias_file_stops_the_start_unless_told_to_measure(state_dir: Path) -> None:
    (state_dir / "bias.yaml").write_text("bias_dps: 0.5\n")  # truncated: no "# end"
    with pytest.raises(BiasFileError, match="truncated"):
        choose_bias(Config(), None)
    lenient = apply_overrides(Config(), {"calibration.on_bad_bias_file": "calibrate"})
    assert choose_bias(lenient, None) == BiasChoice(None, "startup")


def test_a_bias_beyond_the_configured_limit_is_a_bad_file(state_dir: Path) -> None:
    save_bias(state_dir / "bias.yaml", BiasRecord(2.5, 0.01, 300, 30.0))
    cfg = apply_overrides(Config(), {"calibration.max_bias_dps": 2.0})
    with pytest.raises(BiasFileError, match="beyond"):
        choose_bias(cfg, None)


# -- a whole run ---------------------------------------------------------------------------


class Receiver:
    """A UDP socket on 127.0.0.1 read by a thread into ``lines``, until :meth:`close`."""

    def __init__(self, kind: int = socket.SOCK_DGRAM, family: int = socket.AF_INET) -> None:
        self.sock = socket.socket(family, kind)
        self.lines: list[str] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self.sock.settimeout(0.05)
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            self.lines += data.decode().splitlines()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(WAIT_S)
        self.sock.close()


# -- publishers ----------------------------------------------------------------------------

STEP = {"class": "HDR", "v": 1, "step": 7, "omega": 0.25, "heading": 12.5, "status": "ok"}


def receivers(n: int) -> list[Receiver]:
    out = [Receiver() for _ in range(n)]
    for r in out:
        r.sock.bind(("127.0.0.1", 0))
        r.start()
    return out


def at(r: Receiver) -> str:
    return f"127.0.0.1:{r.sock.getsockname()[1]}"


def publish_one(cfg: Config) -> None:
    """STEP handed to the publishers ``cfg`` makes, which are then stopped (flushed)."""
    pubs = build_publishers(cfg)
    try:
        for p in pubs:
            p.on_message(STEP)
    finally:
        for p in pubs:
            p.stop()


def test_stdout_when_nothing_else_is_configured(capfd: pytest.CaptureFixture[str]) -> None:
    (pub,) = build_publishers(Config())
    assert isinstance(pub, StdoutPublisher)
    publish_one(Config())
    assert [json.loads(x) for x in capfd.readouterr().out.splitlines()] == [STEP]


def test_each_configured_output_gets_its_publisher(capfd: pytest.CaptureFixture[str]) -> None:
    """A step handed to the publishers arrives at every configured output: one JSON datagram
    at output.udp's address, the NMEA sentences at output.nmea_udp's, a JSON line on stdout;
    with only output.udp, nothing on stdout."""
    json_rx, nmea_rx = receivers(2)
    try:
        cfg = {"output.udp": [at(json_rx)], "output.nmea_udp": [at(nmea_rx)]}
        publish_one(apply_overrides(Config(), {**cfg, "output.stdout": True}))
        wait_for(lambda: json_rx.lines and len(nmea_rx.lines) >= 2, "the datagrams")
        assert [json.loads(x) for x in capfd.readouterr().out.splitlines()] == [STEP]
        publish_one(apply_overrides(Config(), {"output.udp": [at(json_rx)]}))
        wait_for(lambda: len(json_rx.lines) >= 2, "the second datagram")
        assert capfd.readouterr().out == ""  # no stdout then
    finally:
        json_rx.close()
        nmea_rx.close()
    assert [json.loads(x) for x in json_rx.lines] == [STEP, STEP]
    assert [x.split(",")[0] for x in nmea_rx.lines] == ["$HNHDT", "$HNROT"]


@pytest.fixture
def udp() -> Iterator[Receiver]:
    r = Receiver()
    r.sock.bind(("127.0.0.1", 0))
    r.start()
    yield r
    r.close()


@pytest.fixture
def notify(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Receiver]:
    r = Receiver(family=socket.AF_UNIX)
    path = tmp_path / "notify.sock"
    r.sock.bind(str(path))
    r.start()
    monkeypatch.setenv("NOTIFY_SOCKET", str(path))
    monkeypatch.delenv("WATCHDOG_USEC", raising=False)
    yield r
    r.close()


def simulated(**more: object) -> Config:
    return apply_overrides(
        Config(),
        {
            "simulate.drive": "standstill",  # 20 minutes, played as fast as the loop goes
            "simulate.rate_hz": 10.0,
            "simulate.speedup": 1_000_000.0,
            **more,
        },
    )


def wait_for(cond: object, what: str) -> None:
    import time

    deadline = time.monotonic() + WAIT_S
    while not cond():  # type: ignore[operator]
        assert time.monotonic() < deadline, what
        time.sleep(0.01)


def test_a_run_on_the_simulated_gyro_publishes_every_step(
    capfd: pytest.CaptureFixture[str],
) -> None:
    """Published on stdout (captured here; over UDP a burst of 1,230 datagrams could overflow
    the receiver's buffer, and a test that loses some proves nothing)."""
    handlers = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)}
    cfg = simulated(**{"output.stdout": True})
    d = Daemon(cfg, "test", lambda: (cfg, "test"), BiasChoice(None, "startup"), simulate=True)
    assert d.run() == 0
    out = capfd.readouterr().out.splitlines()
    msgs = [json.loads(x) for x in out if x.startswith("{")]  # not the log lines (structlog's)
    steps = [m["step"] for m in msgs if m["class"] == "HDR"]
    # the drive's 1,230 s (a 30 s lead-in and 20 minutes) at 10 Hz: a step a second
    assert d.liveness.steps == len(steps) == 1230
    assert steps == list(range(steps[0], steps[0] + len(steps)))  # none lost, none twice
    status = [m["status"] for m in msgs if m["class"] == "HDR"]
    assert status[0] == "calibrating" and set(status[1:]) == {"ok"}  # the first step measures
    # the handlers it took over are put back at the end
    assert {s: signal.getsignal(s) for s in handlers} == handlers


def test_a_stop_request_ends_the_run_cleanly_and_systemd_is_told(
    udp: Receiver, notify: Receiver
) -> None:
    """SIGTERM's handler only sets a flag; the loop ends at its next turn and shuts down.
    systemd hears STATUS while calibrating, READY=1 once the bias is known, then STATUS with
    the heading, and STOPPING=1 last (100 steps a second: no burst for its socket to drop)."""
    port = udp.sock.getsockname()[1]
    cfg = simulated(**{"simulate.speedup": 100.0, "output.udp": [f"127.0.0.1:{port}"]})
    d = Daemon(cfg, "test", lambda: (cfg, "test"), BiasChoice(None, "startup"), simulate=True)

    def stop_after_three_steps() -> None:
        wait_for(lambda: len(udp.lines) >= 3 and "READY=1" in notify.lines, "three steps")
        d.signals.stop = True  # what SIGTERM's handler does (test_signals.py)

    stopper = threading.Thread(target=stop_after_three_steps)
    stopper.start()
    try:
        assert d.run() == 0
    finally:
        stopper.join(WAIT_S)
    assert d.signals.stop and 3 <= d.liveness.steps < 1230  # ended by the request, not by the drive
    wait_for(lambda: "STOPPING=1" in notify.lines, "STOPPING=1")
    said = notify.lines
    assert said[0] == "STATUS=calibrating: measuring the bias over 1 s at standstill"
    assert said.count("READY=1") == 1 and said[-1] == "STOPPING=1"
    assert any(x.startswith("STATUS=ok: heading ") for x in said[said.index("READY=1") :])


# -- a reload ------------------------------------------------------------------------------


def test_a_reload_takes_the_new_method_and_keeps_what_needs_a_restart() -> None:
    old = Config()
    new = apply_overrides(
        Config(),
        {"hdr.method": "hdr+", "hdr.T": 2.0, "device.port": "/dev/ttyUSB7"},
    )
    d = Daemon(old, "old.yaml", lambda: (new, "new.yaml"), BiasChoice(None, "startup"))
    d.reload_config()
    assert d.where == "new.yaml" and d.cfg.hdr.method == "hdr+"
    assert d.cfg.hdr.params.T == old.hdr.params.T  # a step period needs a restart
    assert d.cfg.device == old.device  # so does the device
    assert d.pipeline.config.method == "hdr+"


def test_a_reload_that_fails_keeps_the_running_configuration() -> None:
    cfg = Config()

    def broken() -> tuple[Config, str]:
        raise ConfigError("hdr.c1", "x", "must be a number")

    d = Daemon(cfg, "old.yaml", broken, BiasChoice(BiasRecord(0.1, 0.0, 0, 0.0), "--bias"))
    pipeline_config = d.pipeline.config
    d.reload_config()
    assert d.cfg is cfg and d.where == "old.yaml" and d.pipeline.config == pipeline_config


def test_a_reload_with_other_outputs_makes_new_publishers(
    udp: Receiver, capfd: pytest.CaptureFixture[str]
) -> None:
    new = apply_overrides(Config(), {"output.udp": [at(udp)]})
    d = Daemon(Config(), "old.yaml", lambda: (new, "new.yaml"), BiasChoice(None, "startup"))
    d.outputs = Outputs.from_config(d.cfg)
    assert [type(p) for p in d.outputs.publishers] == [StdoutPublisher]
    d.reload_config()
    try:
        for p in d.outputs.publishers:
            p.on_message(STEP)
        wait_for(lambda: udp.lines, "the step on the new output")
    finally:
        for p in d.outputs.publishers:
            p.stop()
    assert [json.loads(x) for x in udp.lines] == [STEP]
    assert [type(p) for p in d.outputs.publishers] == [UdpJsonPublisher]
    assert json.dumps(STEP) not in capfd.readouterr().out  # the old stdout publisher is gone
