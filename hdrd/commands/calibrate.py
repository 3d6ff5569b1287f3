"""``hdrd calibrate``: the static bias eps0 measured at standstill and saved to the bias file.

The edge around :class:`hdrd.core.calibrate.StartupWindow`, the start-up window the daemon's
pipeline and ``hdrd evaluate`` measure through too: it opens the port (exclusively, as the
daemon does: a port in use is an error at once), gathers the samples in the window, times it
by the device clock (:class:`hdrd.io.wire.clocks.SampleClock`, which a glitched timestamp cannot end
early), gives up when no frame comes for ``calibration.no_data_timeout_s``, and writes the
file atomically. Progress goes to stdout; a reader that goes away (``| head -1``) does not stop
the measurement, and the result is then said on stderr.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

from hdrd.cliconfig import config_from_args
from hdrd.config import Config, ConfigError
from hdrd.configload import RULES
from hdrd.core.calibrate import BiasRecord, MotionDetected, StartupWindow
from hdrd.core.gyronoise import ALLAN_MIN_S, GyroNoise, measure_noise
from hdrd.daemon.inputs import open_source
from hdrd.daemon.pipeline import standstill_limits
from hdrd.daemon.signals import Signals
from hdrd.errors import EX_CONFIG
from hdrd.io.files.access import default_bias_path
from hdrd.io.files.biasfile import save_bias
from hdrd.io.logs import log, setup_logging
from hdrd.io.wire.clocks import SampleClock
from hdrd.io.wire.codec import Frame
from hdrd.io.wire.sources import DeviceBack, DeviceLost, EndOfInput, SerialSource, Source

__all__ = ["main"]


class _Progress:
    """``hdrd calibrate``'s lines on stdout. If the reader goes away (``| head -1``) the
    measurement goes on and the result is said on stderr instead: the bias file is what was
    promised, not the lines."""

    def __init__(self) -> None:
        self.gone = sys.stdout is None

    def say(self, text: str) -> None:
        if not self.gone:
            try:
                print(text, flush=True)
                return
            except (BrokenPipeError, ValueError, OSError):
                self.gone = True
                _quiet_stdout()
        # progress is not worth saying elsewhere; only the final result is (see done)

    def done(self, text: str) -> None:
        if self.gone:
            print(text, file=sys.stderr, flush=True)
        else:
            self.say(text)
            if self.gone:
                print(text, file=sys.stderr, flush=True)


def _noise_of(window: StartupWindow, duration_s: float) -> GyroNoise | None:
    """The error model the window shows (:func:`hdrd.core.gyronoise.measure_noise`), recorded
    beside the bias for HDR+; None when the window is too short to tell a rate."""
    n = window.n
    if n < 2 or not duration_s > 0.0:
        return None
    return measure_noise(window.omega_dps, n / duration_s)


def _noise_line(noise: GyroNoise | None) -> str:
    """What the result line says of the recorded error model."""
    if noise is None:
        return ""
    if noise.known():
        return (
            f"; noise recorded: white {noise.white_dps_per_rthz:.3g} deg/s/sqrt(Hz), bias "
            f"random walk {noise.bias_q():.2g} (deg/s)^2/s (HDR+ uses it)"
        )
    return (
        f"; noise recorded: white {noise.white_dps_per_rthz:.3g} deg/s/sqrt(Hz) (a standstill "
        f"of {ALLAN_MIN_S / 60:g} min or more also shows how the bias wanders)"
    )


def _quiet_stdout() -> None:
    """Point fd 1 at /dev/null so that Python's final flush of the lost pipe stays quiet."""
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 1)
        os.close(null)
    except OSError:
        pass


def main(args: argparse.Namespace) -> int:
    """``hdrd calibrate``: static bias over --seconds at standstill, saved atomically.

    Exit 0 with the bias file written; 1 when it is not (motion, a bias beyond
    calibration.max_bias_dps, a busy port, no data for calibration.no_data_timeout_s, the
    input ended, an unwritable file), with one line saying why; 78 for a bad value.
    """
    try:
        cfg, _ = config_from_args(args)
        seconds = args.seconds if args.seconds is not None else cfg.calibration.t_bias_s
        check, allowed = RULES["calibration.t_bias_s"]
        if not (math.isfinite(seconds) and check(seconds)):
            raise ConfigError("--seconds", seconds, f"must be {allowed}", "command line")
    except ConfigError as e:
        print(f"hdrd: {e}", file=sys.stderr)
        return EX_CONFIG
    setup_logging(cfg.log.level, cfg.log.format)
    path = (
        Path(args.bias_file)
        if args.bias_file
        else (Path(cfg.calibration.bias_file) if cfg.calibration.bias_file else default_bias_path())
    )
    signals = Signals()
    signals.install()
    try:
        return _calibrate(cfg, args, seconds, path, signals)
    finally:
        signals.restore()


def _fail(why: str) -> int:
    print(f"hdrd calibrate: {why}; bias file not written", file=sys.stderr, flush=True)
    return 1


class _Measurement:
    """The samples of the window as they come: timed by the device clock (a glitched
    timestamp neither ends the window nor counts), progress said each second, restarted when
    the device comes back, given up after ``calibration.no_data_timeout_s`` without data."""

    def __init__(self, cfg: Config, seconds: float, port: str, out: _Progress) -> None:
        self.cfg, self.seconds, self.port, self.out = cfg, seconds, port, out
        self.timeout = cfg.calibration.no_data_timeout_s
        self.clock = SampleClock()
        self.window = StartupWindow(1, standstill_limits(cfg))  # ended by device time
        self.last_data = time.monotonic()
        self.lost: str | None = None
        self.ended = False
        self.next_report = 1.0

    def run(self, src: Source, signals: Signals) -> int | None:
        """Gather until the window is over, the input ends or a stop signal; the exit status
        when it cannot go on, else None."""
        while not signals.stop:
            item = src.recv(0.1)
            now = time.monotonic()
            if item is None or isinstance(item, DeviceLost):
                status = self._no_data(src, item, now)
                if status is not None:
                    return status
                continue
            if isinstance(item, DeviceBack):
                print("device back; restarting the measurement", file=sys.stderr, flush=True)
                self.clock, self.next_report = SampleClock(), 1.0
                self.window.clear()
                self.lost, self.last_data = None, now
                continue
            if isinstance(item, EndOfInput):
                self.ended = True
                break
            self.last_data = now
            if self._add(item):
                break
        return None

    def _no_data(self, src: Source, lost: DeviceLost | None, now: float) -> int | None:
        """Nothing came (or the device was lost, said on stderr); the exit status once
        nothing has come for too long."""
        timeout = self.timeout
        if lost is not None:
            self.lost = lost.reason
            never = isinstance(src, SerialSource) and not src.reader.opened_once
            print(
                f"{lost.reason}; waiting up to {timeout:g} s for it to appear"
                if never
                else f"device lost ({lost.reason}); waiting for it to come back",
                file=sys.stderr,
                flush=True,
            )
        if now - self.last_data > timeout:
            why = f" ({self.lost})" if self.lost else ""
            return _fail(
                f"no data from {self.port} for {timeout:g} s{why} "
                "(calibration.no_data_timeout_s); is the gyro connected and sending?"
            )
        return None

    def _add(self, item: Frame) -> bool:
        """Take a frame into the window; True when it starts the time after the window."""
        if not self.clock.accept(item.t_us):
            return False  # a glitched timestamp: neither its time nor its rate counts
        elapsed = self.clock.elapsed_us / 1e6
        if elapsed >= self.seconds:
            return True
        window = self.window
        window.add(self.cfg.sensor.to_dps_scalar(item.rate, item.ref), item.temp_c)
        if elapsed >= self.next_report:
            self.out.say(
                f"  {elapsed:5.1f} / {self.seconds:g} s  mean {window.mean_dps:+.4f} deg/s"
                f"  n {window.n}"
            )
            self.next_report += 1.0
        return False


def _calibrate(
    cfg: Config, args: argparse.Namespace, seconds: float, path: Path, signals: Signals
) -> int:
    simulate = bool(getattr(args, "simulate", False))
    src = open_source(cfg, simulate)
    port = "the simulated gyro" if simulate else cfg.device.port
    if isinstance(src, SerialSource) and src.reader.busy:
        src.close()
        return _fail(src.reader.last_error or "the port is in use")
    out = _Progress()
    m = _Measurement(cfg, seconds, port, out)
    out.say(f"calibrating: keep the vehicle still for {seconds:g} s")
    try:
        status = m.run(src, signals)
        if status is not None:
            return status
    finally:
        src.close()
    if signals.stop:
        print("calibration interrupted; bias file not written", file=sys.stderr)
        return 0
    duration = m.clock.elapsed_us / 1e6
    if duration < seconds * 0.99:
        what = "input ended" if m.ended else "measurement stopped"
        return _fail(f"{what} after {duration:.1f} s of the {seconds:g} s needed")
    try:
        rec = m.window.measure(when=time.time())
    except MotionDetected as e:
        print(
            f"hdrd calibrate: refused: {e}; keep the vehicle still and try again", file=sys.stderr
        )
        return 1
    rec = replace(rec, duration_s=duration, noise=_noise_of(m.window, duration))
    if not _saved(path, rec):
        return 1
    out.done(
        f"bias {rec.bias_dps:+.5f} deg/s (std {rec.std_dps:.4f}, n {rec.n}, {rec.duration_s:.1f} s"
        + (f", {rec.temp_c:.1f} degC" if rec.temp_c is not None else "")
        + f") written to {path}"
        + (
            f"; {m.clock.glitches} frame(s) with a bad timestamp skipped"
            if m.clock.glitches
            else ""
        )
        + _noise_line(rec.noise)
    )
    log.info(
        "calibrated",
        bias_dps=rec.bias_dps,
        std_dps=rec.std_dps,
        samples=rec.n,
        path=str(path),
        source="calibrate",
    )
    return 0


def _saved(path: Path, rec: BiasRecord) -> bool:
    """Write the bias file; False, with why on stderr, when it cannot be written."""
    try:
        save_bias(path, rec)
    except OSError as e:
        # e.g. "cannot write /var/lib/hdrd/bias.yaml: Permission denied (/var/lib/hdrd)"
        where = ""
        if e.filename is not None and str(e.filename) != str(path):
            f = Path(str(e.filename))
            temp = f.parent == path.parent and f.name.startswith(f".{path.name}.")
            where = f" (its temporary file in {path.parent})" if temp else f" ({f})"
        print(
            f"hdrd calibrate: cannot write {path}: {e.strerror or e}{where}; bias file not written",
            file=sys.stderr,
        )
        return False
    return True
