"""Publishers: where each HDR step's message goes (``hdrd tail`` and ``hdrd web`` read it, :mod:`hdrd.io.net.datagrams`).

A message is the dict the pipeline builds once per HDR step (schema in ``docs/protocol.md``,
"Published messages", and :mod:`hdrd.io.wire.protocol`):
``{"class": "HDR", "v": 1, "time": ..., "omega": ..., "heading": ...}``.
Yaw rates are deg/s, positive counter-clockwise seen from above (a left turn); yaw is degrees
CCW since start; heading is compass degrees, clockwise from north, in [0, 360). A value that
is not known is absent from the dict, never None or 0; keys we do not know are passed through.

The pure formatting (a JSON line, NMEA sentences) is :mod:`hdrd.io.net.formats`'s, as in pyubx2
(pure codec); here are the sinks, with the python-can listener shape (``on_message(msg)``,
``stop()`` that flushes; a sink's failures are its own counters, not exceptions handed back to
it): :class:`UdpJsonPublisher`, :class:`UdpNmeaPublisher`, :class:`StdoutPublisher`.

No publisher blocks the caller, so none can hold up another. A UDP destination that is
down, refuses (ICMP port unreachable), is unreachable or whose name does not resolve never
blocks and never raises: the failure is counted per destination (:meth:`UdpPublisher.stats`)
for the daemon to log; names are looked up off the caller's thread (:mod:`hdrd.io.resolve`). Standard output is written by a thread of its own: a reader that
stalls costs dropped (counted) lines, never a late step elsewhere; when its reader goes away
(``hdrd run --stdout | head``) :class:`StdoutPublisher` raises :class:`OutputClosed` so that
the daemon ends cleanly with exit status 0.
"""

from __future__ import annotations

import errno
import os
import select
import socket
import struct
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, BinaryIO, Protocol

from hdrd.errors import HdrdError
from hdrd.io.net.display import for_display
from hdrd.io.net.formats import format_json, nmea_sentences
from hdrd.io.resolve import Resolver, default_resolver
from hdrd.io.wire.protocol import NMEA_TALKER

if TYPE_CHECKING:
    from typing_extensions import Self  # typing.Self from Python 3.11

__all__ = [
    "DestinationStats",
    "OutputClosed",
    "Publisher",
    "StdoutPublisher",
    "UdpJsonPublisher",
    "UdpNmeaPublisher",
    "UdpPublisher",
    "parse_hostport",
]


class OutputClosed(HdrdError):
    """The reader of an output stream went away (EPIPE): the daemon should end, exit 0."""


class Publisher(Protocol):
    """A sink for per-step messages (the python-can ``Listener`` shape)."""

    def on_message(self, msg: Mapping[str, Any]) -> None: ...

    def stop(self) -> None: ...


# ICMP error on an unconnected UDP socket at all; with it, the pending error also fails the
# *next* sendto, whatever its destination, so we drain the queue and retry (see _send).
_RECVERR: dict[int, tuple[int, int]] = {
    socket.AF_INET: (socket.IPPROTO_IP, 11),
    socket.AF_INET6: (socket.IPPROTO_IPV6, 25),
}
_HAVE_RECVERR = sys.platform.startswith("linux")
_ASYNC_ERRNOS = frozenset(
    {errno.ECONNREFUSED, errno.EHOSTUNREACH, errno.ENETUNREACH, errno.EHOSTDOWN, errno.EMSGSIZE}
)


def parse_hostport(text: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """'HOST:PORT', '[v6]:PORT' or ':PORT' -> (host, port); ValueError if malformed.

    An IPv6 address must be in brackets: ``::1:7400`` could be the address ``::1:7400`` with
    no port as well as ``::1`` port 7400, so it is refused, saying to write ``[::1]:7400``."""
    if not isinstance(text, str) or ":" not in text:
        raise ValueError("expected HOST:PORT")
    host, _, port_s = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
        if not host:
            raise ValueError("empty host in []")
    elif ":" in host:
        raise ValueError(f"an IPv6 address goes in brackets: [{host}]:{port_s}")
    if "[" in host or "]" in host:
        raise ValueError("brackets belong around a whole IPv6 address: [::1]:PORT")
    if not port_s.isdigit() or not 0 < int(port_s) < 65536:
        raise ValueError("port must be 1..65535")
    if any(c.isspace() for c in host):
        raise ValueError("host must not contain spaces")
    return host or default_host, int(port_s)


def _errname(e: int | None) -> str:
    return errno.errorcode.get(e or 0, f"errno {e}")


@dataclass(slots=True)
class DestinationStats:
    """Counters of one UDP destination since the publisher started.

    sent: datagrams handed to the kernel. errors: failures (a send refused or impossible,
    an ICMP error reported back, a name that did not resolve); by_error counts them by kind
    ("ECONNREFUSED", "EHOSTUNREACH", "resolve", ...). dropped: datagrams not sent because
    the name was not resolved (yet). address: the resolved IP address, or None.
    """

    host: str
    port: int
    address: str | None = None
    sent: int = 0
    errors: int = 0
    dropped: int = 0
    by_error: dict[str, int] = field(default_factory=dict)
    last_error: str | None = None

    def count(self, kind: str, detail: str) -> None:
        self.errors += 1
        self.by_error[kind] = self.by_error.get(kind, 0) + 1
        self.last_error = detail

    def to_dict(self) -> dict[str, Any]:
        return {
            "dest": f"{self.host}:{self.port}",
            "address": self.address,
            "sent": self.sent,
            "errors": self.errors,
            "dropped": self.dropped,
            "by_error": dict(self.by_error),
            "last_error": self.last_error,
        }


@dataclass(slots=True)
class _Destination:
    stats: DestinationStats
    family: int | None = None
    sockaddr: tuple[Any, ...] | None = None
    watch: bool = True  # asking the resolver each message: no address yet, or a refresh running
    failures_seen: int = 0  # the resolver's failures of this name already counted here


Formatter = Callable[[Mapping[str, Any]], "bytes | Sequence[bytes]"]


class UdpPublisher:
    """Sends each message, formatted by *formatter* (bytes = one datagram, or a sequence of
    datagrams), to every destination ``(host, port)``.

    One non-blocking UDP socket per address family, unconnected. Host names are resolved by
    *resolver* (:func:`hdrd.io.resolve.default_resolver`), off the caller's thread: a name
    whose address is not known yet drops its datagrams (counted) until it is, one known from
    before (a SIGHUP rebuilt the publishers) is used while it is looked up again; so a slow or
    dead DNS never delays a step. A name resolving to both IPv4 and IPv6 is sent to its IPv4
    address (where ``hdrd tail`` listens by default), write ``[::1]:PORT`` for IPv6. A failed
    or slow lookup is counted per destination (``resolve``, ``resolve_slow``). Send errors
    are counted per destination and swallowed: :meth:`on_message` never blocks and never
    raises an OSError.
    """

    def __init__(
        self,
        destinations: Iterable[tuple[str, int]],
        formatter: Formatter,
        *,
        resolver: Resolver | None = None,
    ) -> None:
        self._formatter = formatter
        self._resolver = resolver or default_resolver()
        self._socks: dict[int, socket.socket | None] = {}
        self._dests = [_Destination(DestinationStats(h, int(p))) for h, p in destinations]
        self._stopped = False
        for d in self._dests:
            self._resolve(d, refresh=True)

    # -- name resolution --
    def _resolve(self, d: _Destination, refresh: bool = False) -> None:
        """The destination's address as the resolver knows it now (never waits); its new
        failures counted."""
        found = self._resolver.lookup(d.stats.host, d.stats.port, socket.SOCK_DGRAM, refresh)
        if found.failures > d.failures_seen:
            d.failures_seen = found.failures
            d.stats.count("resolve_slow" if found.slow else "resolve", found.error or "")
        if found.infos:
            best = next((i for i in found.infos if i[0] == socket.AF_INET), found.infos[0])
            d.family, d.sockaddr = best[0], best[4]
            d.stats.address = str(best[4][0])
        d.watch = found.pending or not found.infos

    # -- sockets --
    def _socket(self, family: int) -> socket.socket | None:
        if family not in self._socks:
            try:
                s = socket.socket(family, socket.SOCK_DGRAM)
                s.setblocking(False)
                if _HAVE_RECVERR:
                    level, opt = _RECVERR[family]
                    try:
                        s.setsockopt(level, opt, 1)
                    except OSError:
                        pass  # no error reports then; sends still work
                self._socks[family] = s
            except OSError:
                self._socks[family] = None  # e.g. IPv6 disabled; counted per send below
        return self._socks[family]

    def _drain_errors(self, sock: socket.socket) -> int:
        """Read the socket's ICMP error queue, counting each report against the destination
        whose datagram caused it. Returns the number of reports."""
        if not _HAVE_RECVERR:
            return 0
        n = 0
        while True:
            try:
                _, anc, _, addr = sock.recvmsg(1, 512, socket.MSG_ERRQUEUE | socket.MSG_DONTWAIT)
            except (BlockingIOError, InterruptedError):
                return n
            except OSError:
                return n
            n += 1
            code = 0
            for level, kind, data in anc:
                if (level, kind) in _RECVERR.values() and len(data) >= 4:
                    code = struct.unpack_from("=I", data)[0]
            key = (str(addr[0]), int(addr[1])) if addr else None
            for d in self._dests:
                if d.sockaddr is not None and (str(d.sockaddr[0]), int(d.sockaddr[1])) == key:
                    name = _errname(code)
                    d.stats.count(name, f"{name} from {key[0]}:{key[1]} ({os.strerror(code)})")
                    break

    def _drain_all(self) -> None:
        for s in self._socks.values():
            if s is not None:
                self._drain_errors(s)

    def _send(self, d: _Destination, datagram: bytes) -> None:
        assert d.family is not None and d.sockaddr is not None
        sock = self._socket(d.family)
        if sock is None:
            d.stats.count("socket", f"cannot open a socket of family {d.family}")
            return
        for attempt in (0, 1):
            try:
                sock.sendto(datagram, d.sockaddr)
                d.stats.sent += 1
                return
            except OSError as e:
                # A pending ICMP error from an earlier datagram (maybe to another
                # destination) fails this send: account it to its owner and retry once.
                if attempt == 0 and e.errno in _ASYNC_ERRNOS and self._drain_errors(sock):
                    continue
                name = _errname(e.errno)
                d.stats.count(name, f"send to {d.stats.host}:{d.stats.port}: {e.strerror or e}")
                return

    # -- listener interface --
    def on_message(self, msg: Mapping[str, Any]) -> None:
        """Format *msg* and send it to every resolved destination; never raises OSError."""
        if self._stopped:
            return
        out = self._formatter(msg)
        datagrams = [out] if isinstance(out, (bytes, bytearray)) else list(out)
        self._drain_all()
        for d in self._dests:
            if d.watch:
                self._resolve(d)
            if d.sockaddr is None:
                d.stats.dropped += len(datagrams)
                continue
            for dg in datagrams:
                self._send(d, bytes(dg))

    def stop(self) -> None:
        """Collect the last error reports and close the sockets (idempotent)."""
        if self._stopped:
            return
        self._drain_all()
        self._stopped = True
        for s in self._socks.values():
            if s is not None:
                s.close()
        self._socks.clear()

    def stats(self) -> list[DestinationStats]:
        """A snapshot of every destination's counters (ICMP reports read first)."""
        if not self._stopped:
            self._drain_all()
            for d in self._dests:
                if d.watch:
                    self._resolve(d)
        return [replace(d.stats, by_error=dict(d.stats.by_error)) for d in self._dests]

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def __repr__(self) -> str:
        dests = ", ".join(f"{d.stats.host}:{d.stats.port}" for d in self._dests)
        return f"{type(self).__name__}([{dests}])"


class UdpJsonPublisher(UdpPublisher):
    """JSON lines (:func:`format_json`), one datagram per message."""

    def __init__(self, destinations: Iterable[tuple[str, int]], **kw: Any) -> None:
        super().__init__(destinations, format_json, **kw)


class UdpNmeaPublisher(UdpPublisher):
    """NMEA 0183 (:func:`nmea_sentences`), one datagram per sentence, as OpenCPN and gpsd's
    ``udp://`` source expect."""

    def __init__(
        self,
        destinations: Iterable[tuple[str, int]],
        ths: bool = False,
        talker: str = NMEA_TALKER,
        **kw: Any,
    ) -> None:
        self.ths = ths
        self.talker = talker
        super().__init__(
            destinations, lambda m: nmea_sentences(m, ths=self.ths, talker=self.talker), **kw
        )


# -- stdout -------------------------------------------------------------------------------

_CLOSED_ERRNOS = frozenset({errno.EPIPE, errno.ECONNRESET})
_CLOSED_MESSAGE = "the reader of standard output went away"


class StdoutPublisher:
    """JSON lines on a binary stream (default: standard output), never blocking the caller.

    :meth:`on_message` formats the line and queues it; a background thread writes the
    queue out in order, as fast as the reader takes it. A reader that stalls (a full pipe,
    a terminal on XOFF) therefore holds up only that thread, never the daemon's loop or the
    other publishers: once ``max_queue_bytes`` are waiting, further lines are dropped and
    counted (``dropped``) until the reader catches up. When the reader goes away (EPIPE)
    the next :meth:`on_message` (or :meth:`flush`) raises :class:`OutputClosed`; the
    stream's descriptor is then pointed at /dev/null so that no later flush (at interpreter
    exit) prints a traceback. Other write errors (a full disk) are counted and swallowed.
    :meth:`stop` waits at most ``stop_wait_s`` for the queue to be written.

    The thread writes with ``os.write`` on the stream's descriptor (never through the
    stream's own buffer, whose lock a blocked write would hold at interpreter exit); a
    stream without a descriptor is written through ``write``/``flush``.

    *display*: print the numbers as a person reads them (:func:`hdrd.io.net.display.for_display`:
    rounded to what they mean) instead of with full precision; None (the default): when the
    stream is a terminal. A pipe or a file gets full precision.
    """

    def __init__(
        self,
        stream: BinaryIO | None = None,
        *,
        max_queue_bytes: int = 256 * 1024,
        stop_wait_s: float = 0.5,
        display: bool | None = None,
    ) -> None:
        self._stream: BinaryIO = stream if stream is not None else sys.stdout.buffer
        if display is None:
            try:
                display = self._stream.isatty()
            except (AttributeError, ValueError, OSError):
                display = False
        self.display = display
        self.max_queue_bytes = max_queue_bytes
        self.stop_wait_s = stop_wait_s
        self.closed = False
        self.written = 0
        """Lines written."""
        self.dropped = 0
        """Lines not written: the queue was full (a stalled reader), or left at stop."""
        self.errors = 0
        self.last_error: str | None = None
        self._queue: deque[bytes] = deque()
        self._queued_bytes = 0
        self._busy = 0  # lines being written by the thread
        self._stopping = False
        self._abandoned = False
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None

    # -- the caller's side --
    def on_message(self, msg: Mapping[str, Any]) -> None:
        """Queue one JSON line (never blocks); OutputClosed once the reader has gone."""
        if self.closed:
            raise OutputClosed(_CLOSED_MESSAGE)
        line = format_json(for_display(msg) if self.display else msg)
        with self._cond:
            if self.closed:
                raise OutputClosed(_CLOSED_MESSAGE)
            if self._stopping:
                self.dropped += 1
                return
            if self._queue and self._queued_bytes + len(line) > self.max_queue_bytes:
                self.dropped += 1
                return
            self._queue.append(line)
            self._queued_bytes += len(line)
            self._cond.notify()
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="hdrd-stdout", daemon=True)
            self._thread.start()

    def flush(self, timeout: float | None = None) -> bool:
        """Wait until every queued line is written (True) or *timeout* s pass (False);
        OutputClosed if the reader went away."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while (self._queue or self._busy) and not self.closed:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return False
                self._cond.wait(left)
            if self.closed:
                raise OutputClosed(_CLOSED_MESSAGE)
        return True

    def stop(self) -> None:
        """Write what is queued, waiting at most ``stop_wait_s``; what is still queued then
        (a stalled reader) is counted as dropped. A reader that went away is not an error
        here. Idempotent."""
        try:
            done = self.flush(self.stop_wait_s)
        except OutputClosed:
            done = True
        with self._cond:
            self._stopping = True
            if not done:  # the lines being written count as lost: they may never be
                self.dropped += len(self._queue) + self._busy
                self._queue.clear()
                self._queued_bytes = 0
                self._busy = 0
                self._abandoned = True
            self._cond.notify_all()
        if self._thread is None and not self.closed:  # nothing written: flush the stream
            try:
                self._stream.flush()
            except (OSError, ValueError):
                pass

    # -- the writer thread --
    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._stopping:
                    self._cond.wait()
                if not self._queue:
                    return
                lines = list(self._queue)
                self._queue.clear()
                self._queued_bytes = 0
                self._busy = len(lines)
            ok = self._write(b"".join(lines))
            with self._cond:
                self._busy = 0
                if self._abandoned:  # stop() gave up on (and counted) these lines
                    return
                if ok:
                    self.written += len(lines)
                elif not self.closed:
                    self.dropped += len(lines)
                self._cond.notify_all()
                if self.closed:
                    self.dropped += len(self._queue)
                    self._queue.clear()
                    return

    def _write(self, data: bytes) -> bool:
        """Write *data* whole (blocking this thread only); False on an error."""
        try:
            fd = self._stream.fileno()
        except (OSError, ValueError, AttributeError):
            fd = None
        try:
            if fd is None:
                self._stream.write(data)
                self._stream.flush()
                return True
            view = memoryview(data)
            while view:
                try:
                    n = os.write(fd, view)
                except BlockingIOError:  # someone set O_NONBLOCK on a shared descriptor
                    select.select([], [fd], [], 0.1)
                    continue
                view = view[n:]
            return True
        except BrokenPipeError:
            self._reader_gone()
        except ValueError:  # the stream object was closed
            self._reader_gone()
        except OSError as e:
            if e.errno in _CLOSED_ERRNOS or e.errno == errno.EBADF:
                self._reader_gone()
            else:
                with self._cond:
                    self.errors += 1
                    self.last_error = f"{_errname(e.errno)}: {e.strerror or e}"
        return False

    def _reader_gone(self) -> None:
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(devnull, self._stream.fileno())
            finally:
                os.close(devnull)
        except (OSError, ValueError, AttributeError):
            pass
        with self._cond:
            self.closed = True
            self._cond.notify_all()
