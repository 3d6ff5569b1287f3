"""The daemon's GPS link (``hdrd run --gpsd``): the gpsd client, the aiding, and the pipeline's
hooks, wired together. An edge: it reads gpsd's socket (through :class:`hdrd.io.net.gpsd.GpsdClient`),
stamps fixes with the monotonic clock and logs state changes; the aiding itself is pure
(:class:`hdrd.daemon.aiding.GpsAiding`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from hdrd.core.throttle import Throttle
from hdrd.daemon.aiding import AidingConfig, GpsAiding
from hdrd.io.logs import log
from hdrd.io.net.gpsd import GpsdClient
from hdrd.io.wire.protocol import Message

if TYPE_CHECKING:
    from hdrd.config import GpsdConfig

__all__ = ["AidedPipeline", "GpsdLink", "aiding_config"]


def aiding_config(gpsd_cfg: GpsdConfig, step_s: float = 1.0) -> AidingConfig:
    """The :class:`hdrd.daemon.aiding.AidingConfig` that a :class:`hdrd.config.GpsdConfig` names
    (``gpsd.min_speed_mps``, ``max_fix_age_s``, ``max_epd_deg``, ``align_gain``,
    ``bias_window_s``, ``bias_gain``, ``device``: empty = the first receiver with a fix), with
    the HDR step period ``step_s``, s."""
    return AidingConfig(
        device=gpsd_cfg.device or None,
        min_speed_mps=gpsd_cfg.min_speed_mps,
        max_fix_age_s=gpsd_cfg.max_fix_age_s,
        max_epd_deg=gpsd_cfg.max_epd_deg,
        align_gain=gpsd_cfg.align_gain,
        bias_window_s=gpsd_cfg.bias_window_s,
        bias_gain=gpsd_cfg.bias_gain,
        step_s=step_s,
    )


class AidedPipeline(Protocol):
    """What :class:`GpsdLink` tells the pipeline (:class:`hdrd.daemon.pipeline.Pipeline`)."""

    def set_speed(self, speed_mps: float | None) -> None: ...


class GpsdLink:
    """What ``hdrd run --gpsd`` adds to the run loop (edge).

    :meth:`poll` every loop turn: reads the fixes, stamps them with the monotonic clock,
    and feeds the GPS speed to the pipeline (``Pipeline.set_speed``; None when no fresh
    fix); lines that could not be used are logged (``gpsd_bad_lines``, at most every 10 s).
    The aiding itself (:class:`hdrd.daemon.aiding.GpsAiding`) is a stage of the pipeline,
    which it is given to (``Pipeline.set_aiding``): the messages come out of the pipeline
    aided. :meth:`log_mode` on each batch logs a change of mode and the aiding's events:
    ``gps_device`` (the receiver followed) and ``gps_realigned`` each time;
    ``gps_course_rejected``, ``gps_courses_disagree`` and ``gps_fix_refused`` at most every
    10 s each, with the count since the last one.
    """

    def __init__(
        self, client: GpsdClient, aiding: GpsAiding, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.client = client
        self.aiding = aiding
        self._clock = clock
        self._mode: str | None = None
        self._bad = Throttle(self.BAD_LOG_INTERVAL_S)
        # The events that come with each fix or step, as many as a receiver sends: at most
        # one warning each per BAD_LOG_INTERVAL_S, with the count since the last.
        self._counted = {name: Throttle(self.BAD_LOG_INTERVAL_S) for name in self.COUNTED}

    @classmethod
    def from_config(cls, gpsd_cfg: GpsdConfig, step_s: float = 1.0) -> GpsdLink:
        """From :class:`hdrd.config.GpsdConfig`: host, port and the aiding's thresholds and
        gains (the rest of :class:`hdrd.daemon.aiding.AidingConfig` keeps its defaults)."""
        client = GpsdClient(gpsd_cfg.host, gpsd_cfg.port)
        return cls(client, GpsAiding(aiding_config(gpsd_cfg, step_s)))

    BAD_LOG_INTERVAL_S = 10.0
    """At most one ``gpsd_bad_lines`` warning per this many seconds."""

    def poll(self, pipeline: AidedPipeline, now: float | None = None) -> None:
        now = self._clock() if now is None else now
        for f in self.client.poll():
            self.aiding.on_fix(f, now)
        self._log_events(now)
        pipeline.set_speed(self.aiding.speed(now))
        bad = self.client.stats.bad_lines
        new = self._bad.count(bad, now)
        if new:
            errors = self.client.stats.errors
            log.warning("gpsd_bad_lines", total=bad, new=new, last=errors[-1] if errors else None)

    def log_mode(self, msgs: list[Message], now: float | None = None) -> None:
        """Log a change of the aiding's mode (``gps_mode``) in the published messages, and the
        aiding's events."""
        now = self._clock() if now is None else now
        for m in msgs:
            mode = m.get("mode")
            if mode is not None and mode != self._mode:
                self._mode = mode
                fields_ = {k: m[k] for k in ("heading", "gps_course", "gps_speed") if k in m}
                log.info("gps_mode", mode=mode, **fields_)
        self._log_events(now)

    def on_messages(self, msgs: list[Message], now: float, steps: bool = True) -> None:
        """As a listener of the loop (:mod:`hdrd.daemon.listeners`): :meth:`log_mode`."""
        self.log_mode(msgs, now)

    COUNTED = {
        "gps_course_rejected": "courses_rejected",
        "gps_courses_disagree": "courses_disagreeing",
        "gps_fix_refused": "fixes_refused",
    }
    """The aiding's events that may come with every fix or step, and the aiding's counter of
    each: logged at most every BAD_LOG_INTERVAL_S, with the total and the count since."""

    def _log_events(self, now: float) -> None:
        """Log the aiding's events (the counted ones at most every BAD_LOG_INTERVAL_S)."""
        a = self.aiding
        for name, fields_ in a.events:
            counter = self.COUNTED.get(name)
            if counter is None:
                (log.warning if name == "gps_realigned" else log.info)(name, **fields_)
                continue
            total = getattr(a, counter)
            new = self._counted[name].count(total, now)
            if new:
                log.warning(name, total=total, new=new, **fields_)
        a.events.clear()

    def close(self) -> None:
        self.client.close()
