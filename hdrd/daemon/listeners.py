"""The daemon's listeners: what the loop hands every batch of published messages to, in the
shape of python-can's Notifier and Listener.

The loop (:class:`hdrd.daemon.run.Daemon`) reads frames, steps the pipeline and gives what
comes out to each listener in turn: the GPS link (its mode and events in the log), the sensor
faults (:mod:`hdrd.daemon.faultlog`), the outputs (UDP JSON, NMEA 0183, stdout) and last the
loop's own liveness (systemd's watchdog, the step count). A listener never raises but to end
the loop (:class:`hdrd.io.net.publish.OutputClosed`: the stdout reader went away).
"""

from __future__ import annotations

from typing import Protocol

from hdrd.config import Config
from hdrd.daemon.sdnotify import WatchdogGate
from hdrd.io.logs import log
from hdrd.io.net.publish import (
    OutputClosed,
    Publisher,
    StdoutPublisher,
    UdpJsonPublisher,
    UdpNmeaPublisher,
    UdpPublisher,
    parse_hostport,
)
from hdrd.io.resolve import Resolver, default_resolver
from hdrd.io.wire.protocol import Message

__all__ = ["Listener", "Liveness", "Outputs", "build_publishers", "stop_publishers"]


class Listener(Protocol):
    def on_messages(self, msgs: list[Message], now: float, steps: bool) -> None:
        """Messages the loop published at host time ``now`` (monotonic s); ``steps``: False
        for a report that is not a step (stale)."""


class Outputs:
    """The configured outputs as one listener: every message to every publisher; one that
    fails is logged (``publish_failed``) and the others still get it."""

    def __init__(self, publishers: list[Publisher]) -> None:
        self.publishers = publishers

    @classmethod
    def from_config(cls, cfg: Config) -> Outputs:
        """The outputs ``cfg.output`` asks for (:func:`build_publishers`)."""
        return cls(build_publishers(cfg))

    def on_messages(self, msgs: list[Message], now: float, steps: bool) -> None:
        for m in msgs:
            for p in self.publishers:
                try:
                    p.on_message(m)
                except OutputClosed:
                    raise
                except Exception as e:  # noqa: BLE001 - one bad sink must not stop the others
                    log.warning("publish_failed", publisher=type(p).__name__, error=str(e))

    @property
    def dropped(self) -> int:
        """Messages dropped by the publishers so far (stdout with a stalled reader)."""
        return sum(int(getattr(p, "dropped", 0)) for p in self.publishers)

    def stop(self) -> None:
        """Each publisher flushed and stopped, the UDP destinations' counters logged."""
        stop_publishers(self.publishers)


class Liveness:
    """The loop doing its job: a published message (a step, or a stale report on time) tells
    systemd's watchdog; steps are counted, and when the last came (monotonic s)."""

    def __init__(self, watchdog: WatchdogGate, now: float = 0.0) -> None:
        self.watchdog = watchdog
        self.steps = 0
        self.last_step_at = now

    def on_messages(self, msgs: list[Message], now: float, steps: bool) -> None:
        if not msgs:
            return
        self.watchdog.progress()
        if steps:
            self.last_step_at = now
            self.steps += len(msgs)


# -- the publishers ----------------------------------------------------------------------------


def build_publishers(cfg: Config, resolver: Resolver | None = None) -> list[Publisher]:
    """Publishers for the configured outputs; stdout when nothing else is configured. Host
    names are looked up by ``resolver`` (the process's), never waiting on DNS: an address it
    already knows (before a SIGHUP) is used while the name is looked up again."""
    o = cfg.output
    pubs: list[Publisher] = []
    res = resolver or default_resolver()
    if o.udp:
        pubs.append(UdpJsonPublisher([parse_hostport(a) for a in o.udp], resolver=res))
    if o.nmea_udp:
        pubs.append(
            UdpNmeaPublisher(
                [parse_hostport(a) for a in o.nmea_udp],
                ths=o.nmea_ths,
                talker=o.nmea_talker,
                resolver=res,
            )
        )
    if o.stdout or not pubs:
        pubs.append(StdoutPublisher())
    return pubs


UDP_STATS_LINES = 10
"""At stop, up to this many UDP destinations of an output get a log line each; more are
summed up in one line (``output_udp_summary``) plus a line for each of the
``UDP_STATS_LINES`` that failed most."""


def stop_publishers(pubs: list[Publisher]) -> None:
    """Stop every publisher (each flushes), then log the UDP destinations' counters: what
    was sent, and what failed and why (a peer that refused, a name that never resolved). One
    line per destination, or, for an output with more than :data:`UDP_STATS_LINES`, one
    summary line and the lines of those that failed most."""
    for p in pubs:
        try:
            p.stop()
        except Exception as e:  # noqa: BLE001 - shutting down: report, never raise
            log.warning("publisher_stop_failed", publisher=type(p).__name__, error=str(e))
    for p in pubs:
        if isinstance(p, UdpPublisher):
            _log_udp_stats(p)


def _log_udp_stats(p: UdpPublisher) -> None:
    """Log one UDP output's destinations as :func:`stop_publishers` says."""
    output = "nmea_udp" if isinstance(p, UdpNmeaPublisher) else "udp"
    stats = p.stats()
    shown = stats
    if len(stats) > UDP_STATS_LINES:
        failing = [d for d in stats if d.errors or d.dropped]
        by_error: dict[str, int] = {}
        for d in failing:
            for kind, n in d.by_error.items():
                by_error[kind] = by_error.get(kind, 0) + n
        (log.warning if failing else log.info)(
            "output_udp_summary",
            output=output,
            destinations=len(stats),
            sent=sum(d.sent for d in stats),
            errors=sum(d.errors for d in stats),
            dropped=sum(d.dropped for d in stats),
            failing=len(failing),
            by_error=by_error,
        )
        failing.sort(key=lambda d: d.errors + d.dropped, reverse=True)
        shown = failing[:UDP_STATS_LINES]
    for d in shown:
        (log.warning if d.errors or d.dropped else log.info)(
            "output_udp_stats", output=output, **d.to_dict()
        )
