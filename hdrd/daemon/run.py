"""The daemon's run loop: the edge that wires source -> pipeline -> publishers (``hdrd run``,
:mod:`hdrd.commands.run`, starts it).

Everything with a clock, a port, a socket or a signal is at this edge; the stages it wires are
pure (:mod:`hdrd.daemon.pipeline`), and so are their set-up from a configuration
(:func:`hdrd.daemon.pipeline.pipeline_config`, :func:`hdrd.daemon.inputs.open_source`). Behaviour under
trouble, as gpsd does it: a lost device is reported ("stale") and reopened with backoff, the
heading carrying on; a publisher that fails never stops the loop; SIGTERM/SIGINT end it
cleanly (exit 0) within a second; SIGHUP reloads the configuration, keeping the heading, and
keeps the old one if the new one is invalid (and a SIGHUP during start-up is a reload, not
the end, :mod:`hdrd.daemon.signals`); systemd is told READY=1, STATUS= and WATCHDOG=1
(:mod:`hdrd.daemon.sdnotify`). At stop, each UDP destination's counters are logged.

Only the commands import this module.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from hdrd.config import Config, ConfigError
from hdrd.core.calibrate import BiasRecord
from hdrd.core.throttle import Throttle
from hdrd.daemon.faultlog import FaultLog
from hdrd.daemon.gpslink import GpsdLink
from hdrd.daemon.inputs import open_source
from hdrd.daemon.listeners import Listener, Liveness, Outputs
from hdrd.daemon.pacing import ReadPacer
from hdrd.daemon.pipeline import Pipeline, pipeline_config
from hdrd.daemon.reload import kept_until_restart
from hdrd.daemon.sdnotify import SdNotifier, WatchdogGate
from hdrd.daemon.signals import Signals
from hdrd.daemon.unitkeeper import UnitKeeper
from hdrd.io.files.access import default_bias_path
from hdrd.io.files.biasfile import BiasFileError, load_bias
from hdrd.io.logs import log
from hdrd.io.net.publish import OutputClosed
from hdrd.io.wire.clocks import WallClockCheck
from hdrd.io.wire.codec import Frame
from hdrd.io.wire.protocol import Message
from hdrd.io.wire.sources import (
    DeviceBack,
    DeviceLost,
    EndOfInput,
    SerialSource,
    Source,
    SourceEvent,
)

if TYPE_CHECKING:
    from hdrd.daemon.gpslink import GpsdLink

__all__ = ["BiasChoice", "Daemon", "choose_bias"]


def _clock_rate(cfg: Config, simulate: bool) -> float:
    """Device seconds per host second the input's clock keeps (0: not checked): the
    simulated gyro's ``simulate.speedup``, else ``device.clock_rate``."""
    return cfg.simulate.speedup if simulate else cfg.device.clock_rate


# -- bias ---------------------------------------------------------------------------------


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


# -- inputs and outputs ----------------------------------------------------------------------


def _gps_link(cfg: Config) -> GpsdLink | None:
    """The GPS aiding link that ``cfg.gpsd`` asks for, or None."""
    if not cfg.gpsd.enabled:
        return None

    return GpsdLink.from_config(cfg.gpsd, step_s=cfg.hdr.params.T)


class Daemon:
    """The run loop. Construct, then :meth:`run` (returns the exit status).

    :meth:`run` starts (:meth:`_start`), turns the loop (:meth:`_turn`: one item from the
    source, then the periodic duties) until a stop signal, the end of the input or the stdout
    reader going away, and shuts down (:meth:`_shutdown`: the frames the port still holds, the
    open step, the outputs flushed, the counters logged).
    """

    RECV_TIMEOUT_S = 0.1
    READ_BATCH_S = 0.02
    """Longest pause before reading the serial port again while no step is about to close.
    Why: a read per frame costs a wake-up per frame, 50-150 us of CPU each on a busy 2-core
    machine, which was most of the daemon's cost at 1 kHz (bench/live.py); pausing lets the
    frames gather in the kernel's tty buffer and come in one read. 20 ms is 6 KB at 3 Mbaud,
    well inside what the tty layer buffers."""
    READ_GUARD_S = 0.002
    """Pausing stops this long before the step-closing frame can arrive (:mod:`hdrd.daemon.pacing`),
    so that frame is read as it arrives."""
    DROP_LOG_INTERVAL_S = 10.0
    """At most one ``output_dropped`` warning per this many seconds."""
    DRAIN_S = 0.25
    """At shutdown, frames the port already holds are read for at most this long (s)."""

    def __init__(
        self,
        cfg: Config,
        where: str,
        reload: Callable[[], tuple[Config, str]],
        bias: BiasChoice,
        signals: Signals | None = None,
        simulate: bool = False,
    ) -> None:
        self.cfg = cfg
        self.where = where
        self.reload = reload
        self.simulate = simulate
        self.bias_choice = bias
        from_file = bias.source not in ("--bias", "startup")
        self.unit = UnitKeeper(bias.source if from_file else None)
        """The unit's state file (its trips' learning), beside a bias file."""
        self.pipeline = Pipeline(pipeline_config(cfg, bias.record, self.unit.state))
        self.faults = FaultLog(cfg.sensor, cfg.log.bad_frame_interval_s)
        """The samples the gyro cannot have given, said in the log (rate-limited)."""
        self.signals = signals or Signals()
        self.notifier = SdNotifier()
        self.outputs = Outputs([])  # opened by _start
        self.ready = False
        self.status = ""
        self.reconnects = 0
        self.watchdog = WatchdogGate(self.notifier.watchdog_s)
        self.liveness = Liveness(self.watchdog)
        """The watchdog told of each published message; the steps counted, and when."""
        self.wallclock = WallClockCheck(_clock_rate(cfg, simulate))
        """The device clock against the host's: a frame whose clock disagrees is dropped."""
        interval = cfg.log.bad_frame_interval_s
        self._drops_log = Throttle(interval)  # frames dropped (not new, clock disagrees)
        self._drops_at_step = 0  # ... when the last step was published
        self._dropped_log = Throttle(self.DROP_LOG_INTERVAL_S)  # messages the outputs dropped
        self.gps = _gps_link(cfg)  # GPS aiding through gpsd: a stage of the pipeline
        self._aid_pipeline()
        # Set by _start: the input, its name, and the pacing of a serial port's reads.
        self.src: Source | None = None
        self.src_name = ""
        self.serial: SerialSource | None = None
        self.pacer: ReadPacer | None = None
        # The loop's clocks (time.monotonic, s) and counters between turns.
        self._last_data = 0.0  # the last frame kept
        self._lost_at: float | None = None
        self._stale = Throttle(cfg.hdr.params.T, last=0.0)  # a stale report per step at most
        self._bad_log = Throttle(interval, last=0.0)  # bad frames
        self._waiting_since: float | None = None  # the device has not been there since then
        self._waiting_log = Throttle(self.WAITING_LOG_INTERVAL_S, last=0.0)

    def run(self) -> int:
        src = self._start()
        try:
            while not self.signals.stop and self._turn(src):
                pass
        except OutputClosed:
            log.info("output_closed", reason="stdout reader went away")
        finally:
            self._shutdown(src)
        return 0

    # -- start and stop ------------------------------------------------------------------

    def _start(self) -> Source:
        """Signals, publishers, the ``start`` event, the input opened."""
        self.signals.install()
        self.outputs = Outputs.from_config(self.cfg)
        self.src_name = "simulated gyro" if self.simulate else self.cfg.device.port
        log.info(
            "start",
            config=self.where,
            source=self.src_name,
            protocol=self.cfg.device.protocol,
            method=self.cfg.hdr.method,
            bias=self.bias_choice.source,
            bias_dps=None if self.bias_choice.record is None else self.bias_choice.record.bias_dps,
        )
        if self.bias_choice.record is None:
            self._set_status(
                f"calibrating: measuring the bias over {self.cfg.calibration.startup_s:g} s at standstill"
            )
        src = self.src = open_source(self.cfg, self.simulate)
        # Batched reads of a serial port (hdrd.daemon.pacing); the other sources pace themselves.
        if isinstance(src, SerialSource):
            self.serial = src
            self.pacer = ReadPacer(self.READ_BATCH_S, self.READ_GUARD_S)
        self._last_data = self.liveness.last_step_at = time.monotonic()
        T = self.cfg.hdr.params.T
        wd = self.notifier.watchdog_s
        if wd is not None and T > wd:
            log.warning(
                "watchdog_too_short",
                watchdog_s=2 * wd,
                step_s=T,
                reason="WATCHDOG=1 follows published steps: make WatchdogSec at least 2 hdr.T",
            )
        return src

    def _shutdown(self, src: Source) -> None:
        """The frames the port already holds and the open step published, everything closed,
        the ``stop`` event with the counters."""
        self.notifier.notify("STOPPING=1")
        try:
            if self.serial is not None:
                self._drain_port(self.serial)
            self._publish(self.pipeline.finish(int(src.stats.bad_frames), time.time()))
        except OutputClosed:
            pass
        self.unit.save(self.pipeline.stepper, time.monotonic(), time.time())
        src.close()
        if self.gps is not None:
            self.gps.close()
        self.outputs.stop()
        log.info(
            "stop",
            steps=self.liveness.steps,
            bad_frames=int(src.stats.bad_frames),
            frames_dropped=self._frame_drops(src),
            reconnects=self.reconnects,
            output_dropped=self.outputs.dropped,
            supply_faults=self.faults.supply_faults,
            saturated=self.faults.saturated,
        )
        self.notifier.close()
        self.signals.restore()

    def _drain_port(self, src: SerialSource) -> None:
        """Flush at shutdown: publish the frames the kernel already holds for us (read
        without waiting; paced reads leave up to a few in the tty buffer), then stop."""
        deadline = time.monotonic() + self.DRAIN_S
        ended = False
        while time.monotonic() < deadline:
            item = src.recv(0.0)
            if item is None and not ended:
                src.end_input()  # the input ends here: frames the parser held back, decided
                ended = True
                continue
            if not isinstance(item, Frame):  # nothing left, or a device event
                return
            self._publish(self.pipeline.feed(item, src.bad_frames, time.time()))

    # -- one turn of the loop ------------------------------------------------------------

    def _turn(self, src: Source) -> bool:
        """Reload if asked, take one item from the source and publish what it closed, then the
        periodic duties. False when the input has ended (a capture or a simulated drive)."""
        if self.signals.reload:
            self.signals.reload = False
            self.reload_config()
        item = src.recv(self.RECV_TIMEOUT_S)
        if item is None:
            self.watchdog.progress()  # all input handled: idle, not stuck
        if self.gps is not None:
            # never blocks; bounded work per turn (hdrd.io.net.gpsd.LINES_PER_POLL)
            self.gps.poll(self.pipeline)
        now = time.monotonic()
        bad = src.bad_frames  # not src.stats: that copies every counter, per frame
        if isinstance(item, EndOfInput):
            self._publish(self.pipeline.finish(bad, time.time()))
            log.info("end_of_input", source=self.src_name)
            return False
        got_frame = isinstance(item, Frame)
        msgs = self._take(item, now, bad)
        if msgs:
            self._drain_events()
            self._publish(msgs)
            self._status_after(msgs[-1], bad)
        elif self.pipeline.events:
            self._drain_events()
        if not self.ready and self.pipeline.bias is not None and got_frame:
            self.ready = True  # the port delivers and the bias is known (given or measured)
            self.notifier.notify("READY=1")
        self._duties(now, bad)
        if got_frame:
            self._pace(now)
        return True

    def _take(self, item: Frame | SourceEvent | None, now: float, bad: int) -> list[Message]:
        """One item from the source (not the end of input): the messages of the steps it
        closed. A frame goes to the pipeline; a lost device is reported; a device back
        resynchronises the pipeline across the gap."""
        if item is None:
            return []
        if isinstance(item, DeviceLost):
            self._lost_at = now
            if self._never_opened():
                # At start: not a lost device, one that is not there (yet). Say so, and
                # that the daemon waits for it (as gpsd does), or it looks like a silent gyro.
                self._waiting_since = now
                self._log_waiting(now, item.reason)
                self._set_status(f"waiting for {self.src_name}: {item.reason}")
                return []
            log.warning("device_lost", port=self.src_name, reason=item.reason)
            self._set_status(f"stale: {self.src_name} lost ({item.reason}); reconnecting")
            return []
        if isinstance(item, DeviceBack):
            gap = now - (self._lost_at if self._lost_at is not None else self._last_data)
            self.wallclock.reset()  # a new connection: a new reference for the device clock
            self.liveness.last_step_at = now
            if self._waiting_since is not None:  # it appeared: opened for the first time
                log.info("device_open", port=self.src_name, waited_s=round(gap, 3))
                self._waiting_since = None
                self._lost_at = None
                self._last_data = now  # the stale clock starts now
                if self.pacer is not None:
                    self.pacer.reset()
                return []
            self.reconnects += 1
            log.info(
                "device_back",
                port=self.src_name,
                gap_s=round(gap, 3),
                reconnects=self.reconnects,
                **self._device_gap_field(gap),
            )
            msgs = self.pipeline.resync(self._device_s(gap), bad, time.time())
            self._lost_at = None
            if self.pacer is not None:
                self.pacer.reset()  # a new device clock
            return msgs
        assert isinstance(item, Frame)
        return self.take_frame(item, now, bad)

    def take_frame(self, frame: Frame, now: float, bad: int) -> list[Message]:
        """A frame in hand at host time ``now`` (monotonic s), ``bad`` frames so far: dropped
        if its device clock disagrees with the host's (counted in :attr:`wallclock`), else to
        the pipeline; the messages of the steps it closed. A device clock that jumped and runs
        at the rate since resynchronises the pipeline, the steps moving on by the host's
        clock. Public so that a test or a tool can feed frames without a port."""
        verdict = self.wallclock.check(frame.t_us, now)
        if verdict == WallClockCheck.DISAGREES:
            return []
        msgs: list[Message] = []
        if verdict == WallClockCheck.JUMPED:
            gap = now - self._last_data
            log.warning(
                "device_clock_jumped",
                port=self.src_name,
                gap_s=round(gap, 3),
                jumps=self.wallclock.jumps,
                reason="the device clock jumped (or went back: a restart) and runs at its "
                "rate since: steps go on by the host's clock",
                **self._device_gap_field(gap),
            )
            msgs = self.pipeline.resync(self._device_s(gap), bad, time.time())
            if self.pacer is not None:
                self.pacer.reset()
        self._last_data = now
        msgs.extend(self.pipeline.feed(frame, bad, time.time()))
        return msgs

    def _device_s(self, wall_s: float) -> float:
        """Device seconds that pass in ``wall_s`` host seconds: the device clock's rate
        (``device.clock_rate``; a simulated gyro's speed-up) times them; the wall clock's when
        the rate is not known (0). Across a gap the device clock cannot say it itself (it may
        have restarted), so steps and ``t`` move on by this."""
        rate = _clock_rate(self.cfg, self.simulate)
        return wall_s * rate if rate > 0 else wall_s

    def _device_gap_field(self, wall_s: float) -> dict[str, float]:
        """``device_gap_s`` for a log line, where it differs from the wall clock's gap."""
        dev = self._device_s(wall_s)
        return {} if dev == wall_s else {"device_gap_s": round(dev, 3)}

    WAITING_LOG_INTERVAL_S = 60.0
    """While the device has never been there, ``device_waiting`` is logged again this often."""

    def _never_opened(self) -> bool:
        """The serial device has not been open once since start (not there yet)."""
        return self.serial is not None and not self.serial.reader.opened_once

    def _log_waiting(self, now: float, reason: str | None) -> None:
        s = self.cfg.device
        log.warning(
            "device_waiting",
            port=self.src_name,
            reason=reason,
            waiting=f"hdrd opens {self.src_name} when it appears (tried every "
            f"{s.reconnect_min_s:g} s, backing off to {s.reconnect_max_s:g} s)",
            waited_s=round(now - (self._waiting_since or now), 1),
        )
        self._waiting_log.last = now

    def _status_after(self, last: Message, bad: int) -> None:
        """systemd's status line after publishing steps (once the bias is known)."""
        if self.src is not None:
            self._drops_at_step = sum(self._frame_drops(self.src).values())
        bias = self.pipeline.bias
        if bias is not None:
            self._set_status(
                f"{last['status']}: heading {last.get('heading', float('nan')):.1f} deg, "
                f"bias {bias.bias_dps:+.4f} deg/s, bad frames {bad}"
            )

    def _duties(self, now: float, bad: int) -> None:
        """Every turn: a stale report while no frame is kept or no step comes (the device
        silent, or its frames dropped), the bad-frames and dropped-frames warnings, the
        watchdog ping, the output-dropped warning, each at most as often as allowed."""
        last_step = self.liveness.last_step_at
        silent = max(now - self._last_data, now - last_step - self.cfg.hdr.params.T)
        if silent > self.cfg.device.stale_after_s and self._stale.due(now):
            self._publish_stale(silent, bad)
        new_bad = self._bad_log.count(bad, now)
        if new_bad:
            log.warning("bad_frames", total=bad, new=new_bad)
        if self.watchdog.due(now):
            self.notifier.notify("WATCHDOG=1")
        if self.unit.due(now) and self.liveness.steps:
            self.unit.save(self.pipeline.stepper, now, time.time())
        self._log_frame_drops(now)
        self._log_drops(now)
        if self._waiting_since is not None and self._never_opened() and self._waiting_log.due(now):
            assert self.serial is not None
            self._log_waiting(now, self.serial.reader.last_error)

    def _pace(self, now: float) -> None:
        """After a frame, with everything read processed: let the next frames gather in the
        serial port's buffer (READ_BATCH_S), short of the frame that closes the step."""
        if self.pacer is None or self.serial is None or self.serial.pending:
            return
        t_dev = self.pipeline.clock.last_us
        if t_dev is not None:
            pl = self.pipeline
            pause = self.pacer.pause(
                now, t_dev / 1e6, pl.until_step_s(), time.monotonic(), pl.sample_interval_s()
            )
            if pause:
                time.sleep(pause)

    def _aid_pipeline(self) -> None:
        """The gpsd link's aiding as the pipeline's stage (none without a link), on the
        monotonic clock the link stamps fixes with."""
        aiding = self.gps.aiding if self.gps is not None else None
        self.pipeline.set_aiding(aiding, time.monotonic if aiding is not None else None)

    # -- publishing ------------------------------------------------------------------------

    # systemd status line, like gpsd's: what a `systemctl status hdrd` reader wants to see
    def _set_status(self, text: str) -> None:
        if text != self.status:
            self.status = text
            self.notifier.notify(f"STATUS={text}")

    def listeners(self) -> list[Listener]:
        """Who gets each published batch, in order: the GPS link (the aiding is the
        pipeline's: its mode and events in the log), the sensor faults, the outputs, and
        last the loop's liveness (:mod:`hdrd.daemon.listeners`)."""
        gps: list[Listener] = [self.gps] if self.gps is not None else []
        return [*gps, self.faults, self.outputs, self.liveness]

    def _publish(self, msgs: list[Message], steps: bool = True) -> None:
        now = time.monotonic()
        for listener in self.listeners():
            listener.on_messages(msgs, now, steps)

    def _publish_stale(self, silent: float, bad: int) -> None:
        msg = self.pipeline.stale_message(time.time(), round(silent, 3), bad)
        drops = self._frame_drops(self.src) if self.src is not None else {}
        if sum(drops.values()) > self._drops_at_step:
            shown = ", ".join(f"{k} {v}" for k, v in drops.items() if v)
            self._set_status(f"stale: no usable data for {silent:.0f} s, frames dropped ({shown})")
        else:
            self._set_status(f"stale: no data for {silent:.0f} s")
        self._publish([msg], steps=False)  # a stale report is not a step

    def _frame_drops(self, src: Source) -> dict[str, int]:
        """Frames dropped as not new or with a clock that disagrees, by reason: the parser's
        (:class:`hdrd.io.wire.tracker.FrameTracker`) and the host clock's (:attr:`wallclock`)."""
        st = src.stats
        return {
            "seq_repeats": int(getattr(st, "seq_repeats", 0)),
            "seq_clock_mismatch": int(getattr(st, "seq_clock_mismatch", 0)),
            "wall_clock_mismatch": self.wallclock.mismatches,
        }

    def _log_frame_drops(self, now: float) -> None:
        """``frames_dropped`` at most every ``log.bad_frame_interval_s``, with the counts."""
        if self.src is None or not self._drops_log.due(now):
            return  # looked at no more often than that (src.stats copies)
        drops = self._frame_drops(self.src)
        total = sum(drops.values())
        new = total - self._drops_log.said
        if new <= 0:
            return
        extra = {}
        if drops["wall_clock_mismatch"]:
            extra["hint"] = (
                "the device clock disagrees with the wall clock; a feed faster than real time "
                "needs device.clock_rate (--clock-rate)"
            )
        log.warning("frames_dropped", total=total, new=new, **drops, **extra)
        self._drops_log.said = total

    def _log_drops(self, now: float) -> None:
        total = self.outputs.dropped
        if total < self._dropped_log.said:  # the publishers were rebuilt (SIGHUP)
            self._dropped_log.restart()
        new = self._dropped_log.count(total, now)
        if new:
            log.warning(
                "output_dropped",
                output="stdout",
                reason="the reader does not keep up",
                total=total,
                new=new,
            )

    def _drain_events(self) -> None:
        for name, fields in self.pipeline.events:
            # rejections are worth a warning; calibrations and bias updates are news
            (log.warning if name.endswith("_rejected") else log.info)(name, **fields)
        self.pipeline.events.clear()

    # -- SIGHUP --------------------------------------------------------------------------

    def reload_config(self) -> None:
        """What SIGHUP does: read the configuration again and apply it (the device, ``hdr.T``
        and ``output.heading0_deg``, the heading at start, only at a restart: each kept is a
        ``config_reload_partial`` warning), or log ``config_reload_failed`` and keep the
        running one.
        Public so that a test or a tool can reload without sending a signal."""
        try:
            cfg, where = self.reload()
        except ConfigError as e:
            log.error("config_reload_failed", error=str(e), kept=self.where)
            return
        old = self.cfg
        cfg = kept_until_restart(old, cfg, self.simulate)
        self.pipeline.reconfigure(pipeline_config(cfg, self.pipeline.bias, self.unit.state))
        interval = cfg.log.bad_frame_interval_s
        self.faults.sensor, self.faults.interval_s = cfg.sensor, interval
        self._bad_log.interval_s = self._drops_log.interval_s = interval
        if cfg.output != old.output:
            self.outputs.stop()
            self.outputs = Outputs.from_config(cfg)
        if cfg.gpsd != old.gpsd:  # a new gpsd connection and aiding state, or none
            if self.gps is not None:
                self.gps.close()
            self.gps = _gps_link(cfg)
            self._aid_pipeline()
            log.info(
                "gpsd_reconfigured",
                enabled=cfg.gpsd.enabled,
                host=cfg.gpsd.host,
                port=cfg.gpsd.port,
            )
        self.cfg, self.where = cfg, where
        log.info("config_reloaded", source=where, method=cfg.hdr.method, **cfg.hdr.params.as_dict())
