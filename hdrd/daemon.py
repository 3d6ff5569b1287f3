"""``hdrd run``: the edge that wires source -> pipeline -> publishers (and the configuration,
bias and signal helpers that ``hdrd calibrate``, in :mod:`hdrd.calibrate_cmd`, shares).

Everything with a clock, a port, a socket or a signal lives here; the stages it wires are
pure (:mod:`hdrd.pipeline`). Behaviour under trouble, as gpsd does it: a lost device is
reported ("stale") and reopened with backoff, the heading carrying on; a publisher that
fails never stops the loop; SIGTERM/SIGINT end it cleanly (exit 0) within a second; SIGHUP
reloads the configuration, keeping the heading, and keeps the old one if the new one is
invalid (and a SIGHUP during start-up is a reload, not the end); systemd is told READY=1,
STATUS= and WATCHDOG=1 through ``$NOTIFY_SOCKET``.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import signal
import socket
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

from hdrd.calibrate import (
    BiasFileError,
    BiasRecord,
    StandstillLimits,
    load_bias,
)
from hdrd.config import EX_CONFIG, Config, ConfigError, apply_overrides, load_config

if TYPE_CHECKING:
    from hdrd.gyronoise import GyroNoise
    from hdrd.hdrplus import HdrPlusParams

__all__ = ["SdNotifier", "config_from_args", "default_bias_path", "main"]


class _LazyLogger:
    """``structlog.get_logger("hdrd")``, structlog imported on first use. Why: importing it
    costs ~30 ms (it brings asyncio), and ``hdrd replay`` imports this module for its
    configuration helpers without logging anything (tests/test_fastpaths.py checks)."""

    def __getattr__(self, name: str) -> Any:
        import structlog

        return getattr(structlog.get_logger("hdrd"), name)


log: Any = _LazyLogger()

# -- systemd notification -------------------------------------------------------------------


class SdNotifier:
    """sd_notify(3) over $NOTIFY_SOCKET (path or @abstract); silent no-op outside systemd."""

    def __init__(self, env: dict[str, str] | None = None) -> None:
        env = dict(os.environ) if env is None else env
        self._addr: str | bytes | None = None
        self._sock: socket.socket | None = None
        addr = env.get("NOTIFY_SOCKET", "")
        if addr:
            self._addr = "\0" + addr[1:] if addr.startswith("@") else addr
            try:
                # Non-blocking: a notification that cannot go at once is dropped (and the
                # next one tried), never a reason to hold up the loop.
                self._sock = socket.socket(
                    socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC | socket.SOCK_NONBLOCK
                )
            except OSError:
                self._sock = None
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        self.watchdog_s: float | None = None
        if usec.isdigit() and int(usec) > 0 and (not pid or pid == str(os.getpid())):
            self.watchdog_s = int(usec) / 1e6 / 2  # ping at half of WatchdogSec
        self.sent: int = 0

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, text: str) -> None:
        if self._sock is None or self._addr is None:
            return
        try:
            self._sock.sendto(text.encode("utf-8", "replace"), self._addr)
            self.sent += 1
        except OSError:
            pass  # systemd gone or socket full: never a reason to stop publishing

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


class WatchdogGate:
    """When the run loop may tell systemd ``WATCHDOG=1``. Pure: the caller passes the time.

    A ping says "the loop is doing its job", so it is sent (at most every *interval_s*, half
    of WatchdogSec) only if, since the previous ping, the loop has made **progress**
    (:meth:`progress`): it published a message (a step, or a stale report while the device
    is silent), or it found the source with nothing to hand out (everything that arrived is
    handled: the state while the device is unplugged, before it first appears, or when it
    sends only garbage). A loop that turns without either (a flood of other work keeps it
    from the frames that are waiting, so steps come late or never) stops pinging, and
    systemd restarts the daemon after WatchdogSec. Steps come every T, so WatchdogSec must
    be longer than T; at least 2 T leaves room (docs/operations.md).
    """

    __slots__ = ("_next", "_progress", "interval_s")

    def __init__(self, interval_s: float | None) -> None:
        self.interval_s = interval_s
        self._next = -math.inf
        self._progress = False

    def progress(self) -> None:
        """A message was published, or the source was idle."""
        self._progress = True

    def due(self, now: float) -> bool:
        """True when a ping should go now (and then it counts as sent)."""
        if self.interval_s is None or now < self._next or not self._progress:
            return False
        self._progress = False
        self._next = now + self.interval_s
        return True


# -- logging ------------------------------------------------------------------------------


def setup_logging(level: str = "info", fmt: str = "auto") -> None:
    """structlog to stderr: JSON lines when not on a terminal (journald), console otherwise."""
    import structlog

    use_json = fmt == "json" or (fmt == "auto" and not sys.stderr.isatty())
    renderer: Any = (
        structlog.processors.JSONRenderer()
        if use_json
        else structlog.dev.ConsoleRenderer(colors=False)
    )
    structlog.configure(
        processors=[
            structlog.processors.add_log_level,
            structlog.processors.TimeStamper(fmt="iso", utc=True),
            renderer,
        ],
        wrapper_class=structlog.make_filtering_bound_logger(getattr(logging, level.upper())),
        logger_factory=structlog.PrintLoggerFactory(file=sys.stderr),
        cache_logger_on_first_use=False,
    )


# -- configuration from the command line ----------------------------------------------------


def default_bias_path() -> Path:
    """$STATE_DIRECTORY/bias.yaml under systemd (StateDirectory=hdrd), else /var/lib/hdrd."""
    state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return Path(state or "/var/lib/hdrd") / "bias.yaml"


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    g = lambda name: getattr(args, name, None)  # noqa: E731
    o: dict[str, Any] = {
        "device.port": g("port"),
        "device.protocol": g("protocol"),
        "device.baud": g("baud"),
        "output.stdout": g("stdout"),
        "output.nmea_ths": g("nmea_ths"),
        "output.heading0_deg": g("heading0"),
        "hdr.method": g("method"),
        "log.format": g("log_format"),
        "log.level": g("log_level"),
        "simulate.drive": g("drive"),
        "simulate.speedup": g("speedup"),
        "calibration.bias_file": g("bias_file"),
    }
    if g("udp"):
        o["output.udp"] = tuple(args.udp)
    if g("nmea_udp"):
        o["output.nmea_udp"] = tuple(args.nmea_udp)
    if g("gpsd"):
        from hdrd.gpsd import parse_address

        try:
            host, port = parse_address(args.gpsd)
        except ValueError as e:
            allowed = f"{e}; give HOST, HOST:PORT, [IPv6] or [IPv6]:PORT (port default 2947)"
            raise ConfigError("--gpsd", args.gpsd, allowed) from None
        o["gpsd.enabled"] = True
        o["gpsd.host"] = host
        o["gpsd.port"] = port
    return o


def config_from_args(args: argparse.Namespace) -> tuple[Config, str]:
    """Load --config (or the default) and apply the command-line overrides; ConfigError."""
    cfg, where = load_config(getattr(args, "config", None))
    try:
        cfg = apply_overrides(cfg, _overrides(args))
    except ConfigError as e:
        raise e.with_source("command line") from None
    return cfg, where


# -- bias ---------------------------------------------------------------------------------


def check_bias_arg(value: float | None, cfg: Config) -> None:
    """``--bias`` must be a finite rate within +/- ``calibration.max_bias_dps`` (deg/s): a
    NaN or infinite bias would leave the daemon with no rate, yaw or heading. ConfigError
    (exit 78) naming the flag, the value and what is allowed."""
    if value is None:
        return
    limit = cfg.calibration.max_bias_dps
    if not (math.isfinite(value) and abs(value) <= limit):
        raise ConfigError(
            "--bias",
            value,
            f"must be a finite number within +/-{limit:g} deg/s (calibration.max_bias_dps)",
            "command line",
        )


@dataclass(frozen=True)
class BiasChoice:
    record: BiasRecord | None  # None: measure at start-up
    source: str  # "--bias", the file path, or "startup"


def choose_bias(cfg: Config, bias_arg: float | None) -> BiasChoice:
    """Where eps0 comes from: --bias, else the bias file, else a start-up measurement.

    A bias file named explicitly must exist. A corrupt or truncated file is an error
    (BiasFileError) unless calibration.on_bad_bias_file is "calibrate".
    """
    if bias_arg is not None:
        return BiasChoice(BiasRecord(bias_arg, 0.0, 0, 0.0), "--bias")
    explicit = bool(cfg.calibration.bias_file)
    path = Path(cfg.calibration.bias_file) if explicit else default_bias_path()
    if not explicit and not path.exists():
        return BiasChoice(None, "startup")
    try:
        return BiasChoice(load_bias(path, cfg.calibration.max_bias_dps), str(path))
    except BiasFileError as e:
        if cfg.calibration.on_bad_bias_file == "calibrate" and not (explicit and not path.exists()):
            log.warning(
                "bias_file_rejected", path=str(path), error=str(e), fallback="startup calibration"
            )
            return BiasChoice(None, "startup")
        raise


# -- the daemon ------------------------------------------------------------------------------


class _Signals:
    """Signal handlers only set flags; the loop acts on them."""

    def __init__(self) -> None:
        self.stop = False
        self.reload = False
        self._old: dict[int, Any] = {}

    def install(self) -> None:
        """Take over SIGTERM, SIGINT and SIGHUP (idempotent). A SIGHUP that came while
        ``hdrd.cli`` held it (between start and now) is a reload to do."""
        if self._old:
            return
        for sig, handler in (
            (signal.SIGTERM, self._on_stop),
            (signal.SIGINT, self._on_stop),
            (signal.SIGHUP, self._on_hup),
        ):
            self._old[sig] = signal.signal(sig, handler)
        from hdrd.cli import take_held_hangup

        if take_held_hangup():
            self.reload = True

    def restore(self) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()

    def _on_stop(self, signum: int, frame: FrameType | None) -> None:
        self.stop = True

    def _on_hup(self, signum: int, frame: FrameType | None) -> None:
        self.reload = True


def standstill_limits(cfg: Config) -> StandstillLimits:
    """The standstill test's thresholds from the calibration section (deg/s)."""
    c = cfg.calibration
    return StandstillLimits(c.max_std_dps, c.max_trend_dps, c.max_excursion_dps, c.max_bias_dps)


def _gps_link(cfg: Config) -> Any:
    """The GPS aiding link that ``cfg.gpsd`` asks for (:class:`hdrd.gpsd.GpsdLink`), or None."""
    if not cfg.gpsd.enabled:
        return None
    from hdrd.gpsd import GpsdLink

    return GpsdLink.from_config(cfg.gpsd, step_s=cfg.hdr.params.T)


def _pipeline_config(cfg: Config, bias: BiasRecord | None) -> Any:
    from hdrd.pipeline import PipelineConfig

    return PipelineConfig(
        sensor=cfg.sensor,
        params=cfg.hdr.params,
        method=cfg.hdr.method,
        bias_dps=None if bias is None else bias.bias_dps,
        bias_record=bias,
        startup_s=cfg.calibration.startup_s,
        limits=standstill_limits(cfg),
        heading0_deg=cfg.output.heading0_deg,
        plus=plus_params(cfg),
        noise=plus_noise(cfg, bias),
    )


def plus_params(cfg: Config) -> HdrPlusParams:
    """HDR+'s parameters with the config's ``standstill.*`` keys applied (run, replay and
    evaluate use the same)."""
    from hdrd.hdrplus import HdrPlusParams

    plus = HdrPlusParams()
    return plus.with_(
        standstill=replace(
            plus.standstill, enabled=cfg.standstill.enabled, gyro_only=cfg.standstill.from_gyro
        )
    )


def plus_noise(cfg: Config, bias: BiasRecord | None) -> GyroNoise | None:
    """The gyro error model HDR+ is fitted to: the noise parameters recorded in the bias file,
    else the config's ``plus.*`` (:func:`hdrd.gyronoise.noise_in_force`; run, replay and
    evaluate use the same)."""
    from dataclasses import asdict

    from hdrd.gyronoise import noise_in_force

    given = {k: v for k, v in asdict(cfg.plus).items() if k != "grade"}
    return noise_in_force(cfg.plus.grade, given, None if bias is None else bias.noise)


def open_source(cfg: Config, simulate: bool) -> Any:
    """The configured input: the serial device, or the built-in simulated gyro."""
    from hdrd import source

    if simulate:
        s = cfg.simulate
        return source.SimulatedSource(
            drive=s.drive,
            seed=s.seed,
            hz=s.rate_hz,
            speedup=s.speedup,
            sensor=cfg.sensor,
            grade=s.grade,
        )
    d = cfg.device
    return source.SerialSource(
        d.port,
        protocol=d.protocol,
        baud=d.baud,
        reconnect_min_s=d.reconnect_min_s,
        reconnect_max_s=d.reconnect_max_s,
    )


def build_publishers(cfg: Config) -> list[Any]:
    """Publishers for the configured outputs; stdout when nothing else is configured."""
    from hdrd import publish
    from hdrd.config import parse_hostport

    o = cfg.output
    pubs: list[Any] = []
    if o.udp:
        pubs.append(publish.UdpJsonPublisher([parse_hostport(a) for a in o.udp]))
    if o.nmea_udp:
        pubs.append(
            publish.UdpNmeaPublisher(
                [parse_hostport(a) for a in o.nmea_udp], ths=o.nmea_ths, talker=o.nmea_talker
            )
        )
    if o.stdout or not pubs:
        pubs.append(publish.StdoutPublisher())
    return pubs


def _stop_all(pubs: list[Any]) -> None:
    for p in pubs:
        try:
            p.stop()
        except Exception as e:  # noqa: BLE001 - shutting down: report, never raise
            log.warning("publisher_stop_failed", publisher=type(p).__name__, error=str(e))


def main(args: argparse.Namespace) -> int:
    """``hdrd run``."""
    # First of all: from here on SIGHUP reloads and SIGTERM stops, even during start-up
    # (hdrd.cli holds SIGHUP from argument parsing until here).
    signals = _Signals()
    signals.install()
    try:
        cfg, where = config_from_args(args)
        check_bias_arg(getattr(args, "bias", None), cfg)
    except ConfigError as e:
        print(f"hdrd: {e}", file=sys.stderr)
        signals.restore()
        return EX_CONFIG
    problem = _closed_stdio(cfg)
    if problem:
        print(f"hdrd: {problem}", file=sys.stderr)
        signals.restore()
        return 1
    setup_logging(cfg.log.level, cfg.log.format)
    try:
        bias = choose_bias(cfg, getattr(args, "bias", None))
    except BiasFileError as e:
        log.error("bias_file_invalid", error=str(e))
        print(f"hdrd: {e}", file=sys.stderr)
        signals.restore()
        return 1
    return Daemon(cfg, where, args, bias, signals).run()


def _closed_stdio(cfg: Config) -> str | None:
    """Started with stdout or stderr closed (``hdrd run >&-``): Python leaves sys.stdout
    None. Publishing to stdout is then impossible (the message says so); otherwise the
    descriptor is pointed at /dev/null, so that no port or socket opened later becomes
    fd 1 or 2 and receives stray output. stderr likewise, for the log."""
    o = cfg.output
    if sys.stdout is None and (o.stdout or not (o.udp or o.nmea_udp)):
        return (
            "stdout is closed and is the only output configured; give --udp or --nmea-udp "
            "(or output.udp / output.nmea_udp), or start hdrd with stdout open"
        )
    for fd, name in ((1, "stdout"), (2, "stderr")):
        if getattr(sys, name) is not None:
            continue
        try:
            os.fstat(fd)
            continue  # the number is taken already (not ours to close)
        except OSError:
            pass
        null = os.open(os.devnull, os.O_WRONLY | os.O_CLOEXEC)
        if null != fd:
            os.dup2(null, fd, inheritable=False)
            os.close(null)
        setattr(sys, name, open(fd, "w", closefd=False))  # noqa: SIM115 - for the process
    return None


class Daemon:
    """The run loop. Construct, then :meth:`run` (returns the exit status)."""

    RECV_TIMEOUT_S = 0.1
    READ_BATCH_S = 0.02
    """Longest pause before reading the serial port again while no step is about to close.
    Why: a read per frame costs a wake-up per frame, 50-150 us of CPU each on a busy 2-core
    machine, which was most of the daemon's cost at 1 kHz (bench/live.py); pausing lets the
    frames gather in the kernel's tty buffer and come in one read. 20 ms is 6 KB at 3 Mbaud,
    well inside what the tty layer buffers."""
    READ_GUARD_S = 0.002
    """Pausing stops this long before the step-closing frame can arrive (:mod:`hdrd.pacing`),
    so that frame is read as it arrives."""

    def __init__(
        self,
        cfg: Config,
        where: str,
        args: argparse.Namespace,
        bias: BiasChoice,
        signals: _Signals | None = None,
    ) -> None:
        from hdrd.pipeline import Pipeline

        self.cfg = cfg
        self.where = where
        self.args = args
        self.simulate = bool(getattr(args, "simulate", False))
        self.bias_choice = bias
        self.pipeline = Pipeline(_pipeline_config(cfg, bias.record))
        self.signals = signals or _Signals()
        self.notifier = SdNotifier()
        self.publishers: list[Any] = []
        self.ready = False
        self.status = ""
        self.steps = 0
        self.reconnects = 0
        self.watchdog = WatchdogGate(self.notifier.watchdog_s)
        self._dropped_logged = 0
        self._dropped_log_at = -math.inf
        self.gps: Any = _gps_link(cfg)  # GPS aiding through gpsd (hdrd.gpsd.GpsdLink), issue 9

    # systemd status line, like gpsd's: what a `systemctl status hdrd` reader wants to see
    def _set_status(self, text: str) -> None:
        if text != self.status:
            self.status = text
            self.notifier.notify(f"STATUS={text}")

    def _publish(self, msgs: list[dict[str, Any]], steps: bool = True) -> None:
        from hdrd.publish import OutputClosed

        if msgs:
            self.watchdog.progress()
        if self.gps is not None:  # mode, GPS-aligned heading; learned bias -> pipeline
            msgs = self.gps.aid(msgs, self.pipeline)
        for m in msgs:
            for p in self.publishers:
                try:
                    p.on_message(m)
                except OutputClosed:
                    raise
                except Exception as e:  # noqa: BLE001 - one bad sink must not stop the others
                    log.warning("publish_failed", publisher=type(p).__name__, error=str(e))
        if steps:
            self.steps += len(msgs)

    def _reload(self) -> None:
        try:
            cfg, where = config_from_args(self.args)
        except ConfigError as e:
            log.error("config_reload_failed", error=str(e), kept=self.where)
            return
        from hdrd.pipeline import PipelineConfig

        old = self.cfg
        if cfg.device != old.device and not self.simulate:
            log.warning(
                "config_reload_partial",
                reason="device settings need a restart",
                kept=str(old.device.port),
            )
            cfg = replace(cfg, device=old.device)
        if cfg.hdr.params.T != old.hdr.params.T:
            log.warning(
                "config_reload_partial", reason="hdr.T needs a restart", kept=old.hdr.params.T
            )
            cfg = replace(
                cfg, hdr=replace(cfg.hdr, params=replace(cfg.hdr.params, T=old.hdr.params.T))
            )
        pc: PipelineConfig = _pipeline_config(cfg, self.pipeline.bias)
        self.pipeline.reconfigure(pc)
        if cfg.output != old.output:
            _stop_all(self.publishers)
            self.publishers = build_publishers(cfg)
        if cfg.gpsd != old.gpsd:  # a new gpsd connection and aiding state, or none
            if self.gps is not None:
                self.gps.close()
            self.gps = _gps_link(cfg)
            log.info(
                "gpsd_reconfigured",
                enabled=cfg.gpsd.enabled,
                host=cfg.gpsd.host,
                port=cfg.gpsd.port,
            )
        self.cfg, self.where = cfg, where
        log.info("config_reloaded", source=where, method=cfg.hdr.method, **cfg.hdr.params.as_dict())

    DROP_LOG_INTERVAL_S = 10.0
    """At most one ``output_dropped`` warning per this many seconds."""

    def _dropped(self) -> int:
        """Messages dropped by the publishers so far (stdout with a stalled reader)."""
        return sum(int(getattr(p, "dropped", 0)) for p in self.publishers)

    def _log_drops(self, now: float) -> None:
        if now - self._dropped_log_at < self.DROP_LOG_INTERVAL_S:
            return
        total = self._dropped()
        if total < self._dropped_logged:  # the publishers were rebuilt (SIGHUP)
            self._dropped_logged = 0
        if total > self._dropped_logged:
            log.warning(
                "output_dropped",
                output="stdout",
                reason="the reader does not keep up",
                total=total,
                new=total - self._dropped_logged,
            )
            self._dropped_logged, self._dropped_log_at = total, now

    def _drain_events(self) -> None:
        for name, fields in self.pipeline.events:
            # rejections are worth a warning; calibrations and bias updates are news
            (log.warning if name.endswith("_rejected") else log.info)(name, **fields)
        self.pipeline.events.clear()

    def run(self) -> int:
        from hdrd.pacing import ReadPacer
        from hdrd.publish import OutputClosed
        from hdrd.source import DeviceBack, DeviceLost, EndOfInput, SerialSource

        self.signals.install()
        self.publishers = build_publishers(self.cfg)
        src_name = "simulated gyro" if self.simulate else self.cfg.device.port
        log.info(
            "start",
            config=self.where,
            source=src_name,
            protocol=self.cfg.device.protocol,
            method=self.cfg.hdr.method,
            bias=self.bias_choice.source,
            bias_dps=None if self.bias_choice.record is None else self.bias_choice.record.bias_dps,
        )
        if self.bias_choice.record is None:
            self._set_status(
                f"calibrating: measuring the bias over {self.cfg.calibration.startup_s:g} s at standstill"
            )
        src = open_source(self.cfg, self.simulate)
        # Batched reads of a serial port (hdrd.pacing); the other sources pace themselves.
        pacer = (
            ReadPacer(self.READ_BATCH_S, self.READ_GUARD_S)
            if isinstance(src, SerialSource)
            else None
        )
        T = self.cfg.hdr.params.T
        mono = time.monotonic
        last_data = mono()
        lost_at: float | None = None
        last_stale = 0.0
        last_bad = 0
        last_bad_log = 0.0
        wd = self.notifier.watchdog_s
        if wd is not None and T > wd:
            log.warning(
                "watchdog_too_short",
                watchdog_s=2 * wd,
                step_s=T,
                reason="WATCHDOG=1 follows published steps: make WatchdogSec at least 2 hdr.T",
            )
        try:
            while not self.signals.stop:
                if self.signals.reload:
                    self.signals.reload = False
                    self._reload()
                item = src.recv(self.RECV_TIMEOUT_S)
                if item is None:
                    self.watchdog.progress()  # all input handled: idle, not stuck
                if self.gps is not None:
                    # never blocks; bounded work per turn (hdrd.gpsd.LINES_PER_POLL)
                    self.gps.poll(self.pipeline)
                now_m = mono()
                bad = src.bad_frames  # not src.stats: that copies every counter, per frame
                msgs: list[dict[str, Any]] = []
                got_frame = False
                if item is None:
                    pass
                elif isinstance(item, DeviceLost):
                    lost_at = now_m
                    log.warning("device_lost", port=src_name, reason=item.reason)
                    self._set_status(f"stale: {src_name} lost ({item.reason}); reconnecting")
                elif isinstance(item, DeviceBack):
                    gap = now_m - (lost_at if lost_at is not None else last_data)
                    self.reconnects += 1
                    log.info(
                        "device_back",
                        port=src_name,
                        gap_s=round(gap, 3),
                        reconnects=self.reconnects,
                    )
                    msgs = self.pipeline.resync(gap, bad, time.time())
                    lost_at = None
                    if pacer is not None:
                        pacer.reset()  # a new device clock
                elif isinstance(item, EndOfInput):
                    msgs = self.pipeline.finish(bad, time.time())
                    self._publish(msgs)
                    log.info("end_of_input", source=src_name)
                    break
                else:
                    last_data = now_m
                    got_frame = True
                    msgs = self.pipeline.feed(item, bad, time.time())
                if msgs:
                    self._drain_events()
                    self._publish(msgs)
                    last = msgs[-1]
                    if self.pipeline.bias is not None:
                        self._set_status(
                            f"{last['status']}: heading {last.get('heading', float('nan')):.1f} deg, "
                            f"bias {self.pipeline.bias.bias_dps:+.4f} deg/s, bad frames {bad}"
                        )
                elif self.pipeline.events:
                    self._drain_events()
                if not self.ready and self.pipeline.bias is not None and got_frame:
                    self.ready = True  # the port delivers and the bias is known (given or measured)
                    self.notifier.notify("READY=1")
                silent = now_m - last_data
                if silent > self.cfg.device.stale_after_s and now_m - last_stale >= T:
                    last_stale = now_m
                    self._publish_stale(silent, bad)
                if bad > last_bad and now_m - last_bad_log >= self.cfg.log.bad_frame_interval_s:
                    log.warning("bad_frames", total=bad, new=bad - last_bad)
                    last_bad, last_bad_log = bad, now_m
                if self.watchdog.due(now_m):
                    self.notifier.notify("WATCHDOG=1")
                self._log_drops(now_m)
                if got_frame and pacer is not None and not src.pending:
                    # Everything read is processed: let the next frames gather (READ_BATCH_S).
                    t_dev = self.pipeline.clock.last_us
                    if t_dev is not None:
                        pl = self.pipeline
                        pause = pacer.pause(
                            now_m, t_dev / 1e6, pl.until_step_s(), mono(), pl.sample_interval_s()
                        )
                        if pause:
                            time.sleep(pause)
        except OutputClosed:
            log.info("output_closed", reason="stdout reader went away")
        finally:
            self.notifier.notify("STOPPING=1")
            try:
                if pacer is not None:
                    self._drain_port(src)
                self._publish(self.pipeline.finish(int(src.stats.bad_frames), time.time()))
            except OutputClosed:
                pass
            src.close()
            if self.gps is not None:
                self.gps.close()
            _stop_all(self.publishers)
            log.info(
                "stop",
                steps=self.steps,
                bad_frames=int(src.stats.bad_frames),
                reconnects=self.reconnects,
                output_dropped=self._dropped(),
            )
            self.notifier.close()
            self.signals.restore()
        return 0

    DRAIN_S = 0.25
    """At shutdown, frames the port already holds are read for at most this long (s)."""

    def _drain_port(self, src: Any) -> None:
        """Flush at shutdown: publish the frames the kernel already holds for us (read
        without waiting; paced reads leave up to a few in the tty buffer), then stop."""
        deadline = time.monotonic() + self.DRAIN_S
        ended = False
        while time.monotonic() < deadline:
            item = src.recv(0.0)
            if item is None and not ended and hasattr(src, "end_input"):
                src.end_input()  # the input ends here: frames the parser held back, decided
                ended = True
                continue
            if item is None or not hasattr(item, "t_us"):  # nothing left, or a device event
                return
            self._publish(self.pipeline.feed(item, src.bad_frames, time.time()))

    def _publish_stale(self, silent: float, bad: int) -> None:
        msg = self.pipeline.stale_message(time.time(), round(silent, 3), bad)
        self._set_status(f"stale: no data for {silent:.0f} s")
        self._publish([msg], steps=False)  # a stale report is not a step
