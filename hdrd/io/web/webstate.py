"""What ``hdrd web`` keeps and pushes, pure: the latest HDR message, a trace of the last ten
minutes, and the server-sent events (SSE) that carry them (docs/web.md).

Datagrams are validated by :func:`hdrd.io.net.datagrams.read_datagram`, as ``hdrd tail`` validates
them; of what passes, only JSON objects of class ``HDR`` are kept (NMEA sentences and other
classes are counted and ignored). A message is pushed re-encoded by :mod:`json` (ASCII only,
no NaN or infinity: such a message is refused), so no byte of a datagram reaches a browser
unchecked and no event can break the stream's framing (an event is one ``data:`` line). The
page renders every string in it as text.

Events (``event:`` name, one JSON ``data:`` line each):

- ``hello``: ``{"now": UNIX s, "udp": "HOST:PORT", "version": "...", "history_s": 600}``, first
  on every connection (the page resets its state on it: the server may have restarted).
- ``history``: ``{"points": [[rx, omega, dgps], ...]}``, the trace so far (below).
- ``msg``: ``{"rx": UNIX s, "msg": {...}}``, an HDR message as received at ``rx`` (the server's
  clock); after ``hello`` a new connection gets the latest one at once.

The trace keeps a point per received message at most every :data:`TRACE_STEP_S` over the last
:data:`HISTORY_S`: ``rx``, the yaw rate ``omega`` (deg/s, + = counter-clockwise) and, while
aided, the heading minus the GPS course (deg, wrapped to [-180, 180)); ``null`` where unknown.
"""

from __future__ import annotations

import json
import math
from collections import deque
from typing import Any

from hdrd.core.angles import wrap180
from hdrd.io.net.datagrams import implausible, read_datagram
from hdrd.io.wire.protocol import MESSAGE_CLASS

__all__ = [
    "HISTORY_S",
    "MAX_EVENT_BYTES",
    "TRACE_STEP_S",
    "LiveState",
    "Point",
    "sse_event",
    "trace_point",
]

HISTORY_S = 600.0
"""The trace covers this much of the past, s (ten minutes)."""
TRACE_STEP_S = 0.5
"""At most one trace point per this many seconds (the daemon sends one step a second; a
replay or a simulation at a speed-up is thinned out): at most 1,200 points."""
MAX_EVENT_BYTES = 16_384
"""A message longer than this once encoded is refused (the daemon's are ~600 bytes)."""


def sse_event(name: str, data: Any) -> bytes:
    """One server-sent event: ``event: NAME``, one ``data:`` line of ASCII JSON (no NaN: a
    ValueError), a blank line."""
    text = json.dumps(data, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    return f"event: {name}\ndata: {text}\n\n".encode("ascii")


def _number(v: Any) -> float | None:
    """A finite JSON number as a float; None for anything else (a bool, a string, NaN)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    try:
        f = float(v)
    except OverflowError:  # an integer beyond float range
        return None
    return f if math.isfinite(f) else None


Point = tuple[float, "float | None", "float | None"]
"""A trace point: rx (UNIX s), omega (deg/s), heading minus GPS course (deg)."""


def trace_point(msg: dict[str, Any], rx: float) -> Point:
    """``[rx, omega, dgps]`` of a message: the yaw rate (deg/s) and, while aided, heading minus
    GPS course (deg, [-180, 180)); None where the message does not say."""
    omega = _number(msg.get("omega"))
    heading, course = _number(msg.get("heading")), _number(msg.get("gps_course"))
    dgps = None
    if msg.get("mode") == "aided" and heading is not None and course is not None:
        diff = heading - course  # inf only for values implausible() refuses
        dgps = round(wrap180(diff), 3) if math.isfinite(diff) else None
    return (round(rx, 3), None if omega is None else round(omega, 4), dgps)


class LiveState:
    """The latest HDR message and the trace, from datagrams (see the module doc). Pure: the
    caller passes the time of reception and sends the events returned."""

    def __init__(self, udp: str = "", version: str = "") -> None:
        self.udp = udp
        self.version = version
        self.latest: bytes | None = None
        """The last ``msg`` event, for a new connection."""
        self.trace: deque[Point] = deque()
        self.received = 0
        """HDR messages taken."""
        self.ignored = 0
        """Lines and messages refused or not shown (not valid, not HDR, too long)."""
        self.last_reason = ""
        """Why the last one was ignored (printable: from :func:`read_datagram`'s notes)."""

    def take(self, data: bytes, sender: str, rx: float) -> list[bytes]:
        """A datagram received at ``rx`` (UNIX s) from ``sender``: the events to push."""
        items, notes = read_datagram(data, sender, "hdrd web")
        if notes:
            self.ignored += len(notes)
            self.last_reason = notes[-1]
        out: list[bytes] = []
        for item in items:
            msg = item.msg
            if msg is None or msg.get("class") != MESSAGE_CLASS:
                self.ignored += 1
                self.last_reason = f"hdrd web: ignored what is not an HDR message from {sender}"
                continue
            event = self._event(msg, sender, rx)
            if event is not None:
                out.append(event)
        return out

    def _event(self, msg: dict[str, Any], sender: str, rx: float) -> bytes | None:
        why = implausible(msg)
        event = b""
        if why is None:
            try:
                event = sse_event("msg", {"rx": round(rx, 3), "msg": msg})
            except (ValueError, TypeError, RecursionError):
                why = "not finite or nested too deeply"  # not JSON a browser reads
            if len(event) > MAX_EVENT_BYTES:
                why = "too long"
        if why is not None:
            self.ignored += 1
            self.last_reason = f"hdrd web: ignored an HDR message from {sender}: {why}"
            return None
        self.received += 1
        self.latest = event
        self._add_point(trace_point(msg, rx))
        return event

    def _add_point(self, point: Point) -> None:
        trace = self.trace
        rx = point[0]  # to the millisecond, as every point before it
        if trace and rx < trace[-1][0]:
            trace.clear()  # the clock went back: the old points would be drawn in the future
        if trace and rx - trace[-1][0] < TRACE_STEP_S:
            return
        trace.append(point)
        while trace and rx - trace[0][0] > HISTORY_S:
            trace.popleft()

    def snapshot(self, now: float) -> bytes:
        """What a new connection gets first: ``hello``, ``history`` and the latest ``msg``."""
        hello = {"now": round(now, 3), "udp": self.udp, "version": self.version}
        points = [p for p in self.trace if now - p[0] <= HISTORY_S]
        parts = [
            sse_event("hello", {**hello, "history_s": HISTORY_S}),
            sse_event("history", {"points": points}),
        ]
        if self.latest is not None:
            parts.append(self.latest)
        return b"".join(parts)
