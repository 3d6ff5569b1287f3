"""The gpsd client: a non-blocking TCP client of gpsd's JSON protocol, and where gpsd listens.

gpsd (https://gpsd.io, ``gpsd_json(5)``) speaks newline-delimited JSON objects tagged with
``"class"``; a client sends ``?WATCH={"enable":true,"json":true}`` and then receives, per GPS
cycle, a ``TPV`` report (course over ground, compass deg clockwise from true north; ground
speed, m/s). The lines are parsed by :mod:`hdrd.io.net.gpsdjson` (pure). :class:`GpsdClient`
owns a TCP socket that never blocks and never raises on I/O trouble: it connects, reconnects
with backoff, buffers partial lines, counts and skips bad ones; :meth:`GpsdClient.poll`
returns the fixes that arrived. :class:`hdrd.daemon.gpslink.GpsdLink` wires the client and
:class:`hdrd.daemon.aiding.GpsAiding` to the daemon's pipeline.
"""

from __future__ import annotations

import errno
import select
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from hdrd.io.logs import log
from hdrd.io.net.gpsdjson import (
    WATCH_COMMAND,
    Devices,
    Fix,
    GpsdError,
    GpsdProtocolError,
    Report,
    Version,
    parse_line,
)
from hdrd.io.resolve import Resolver, default_resolver

if TYPE_CHECKING:
    from typing_extensions import Self  # typing.Self from Python 3.11

__all__ = [
    "DEFAULT_HOST",
    "DEFAULT_PORT",
    "GpsdClient",
    "parse_address",
]

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 2947
MAX_LINE = 65536
"""Longest line we buffer, bytes; gpsd's reports are a few hundred bytes (SKY a few KiB)."""
READ_CHUNK = 16384
"""Most bytes read from gpsd per :meth:`GpsdClient.poll`: a poll's work is bounded whatever
the peer sends (a flooding peer is slowed by TCP flow control, not by the daemon's loop)."""
RESOLVE_POLL_S = 0.1
"""While the gpsd host's name is being looked up, how often a connection is tried again, s."""
LINES_PER_POLL = 32
"""Most lines parsed per :meth:`GpsdClient.poll`; gpsd sends a few lines per second, the
daemon polls every loop turn (at least 10 times a second), so these bounds never delay a
report from a real gpsd."""


def _split_bracketed(text: str) -> tuple[str, str | None]:
    """``[IPv6]`` or ``[IPv6]:PORT`` -> (host, port text or None when no port is given)."""
    end = text.find("]")
    if end < 0:
        raise ValueError("'[' without ']'")
    host, rest = text[1:end], text[end + 1 :]
    if not host:
        raise ValueError("empty host in []")
    if not rest:
        return host, None
    if not rest.startswith(":"):
        raise ValueError(f"unexpected {rest[:20]!r} after ']'")
    return host, rest[1:]


def parse_address(text: str) -> tuple[str, int]:
    """Where gpsd listens, as ``hdrd run --gpsd`` takes it -> (host, port).

    ``HOST``, ``HOST:PORT``, ``:PORT`` (host 127.0.0.1), ``[IPv6]``, ``[IPv6]:PORT``, or a
    bare IPv6 address (``::1``: more than one colon and no brackets, so no port); the port
    defaults to 2947 (:data:`DEFAULT_PORT`) and must be 1..65535. ValueError says what is
    wrong.
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError("empty address")
    if any(c.isspace() or not c.isprintable() for c in text):
        raise ValueError("an address has no spaces or control characters")
    host, port_s = text, None  # None: no port given
    if text.startswith("["):
        host, port_s = _split_bracketed(text)
    elif text.count(":") == 1:
        host, _, port_s = text.partition(":")
        host = host or DEFAULT_HOST
    if "[" in host or "]" in host:
        raise ValueError("brackets belong around a whole IPv6 address")
    if port_s is None:
        return host, DEFAULT_PORT
    if not port_s.isdigit() or len(port_s) > 5 or not 0 < int(port_s) < 65536:
        raise ValueError(f"port {port_s[:20]!r} is not 1..65535")
    return host, int(port_s)


# -- the client (edge) ------------------------------------------------------------------------


@dataclass
class ClientStats:
    """Counters of a :class:`GpsdClient`."""

    attempts: int = 0
    """Connection attempts started."""
    connects: int = 0
    disconnects: int = 0
    lines: int = 0
    bad_lines: int = 0
    fixes: int = 0
    errors: list[str] = field(default_factory=list)
    """The last few gpsd ERROR messages and bad lines (for a log or a test)."""

    def note(self, text: str) -> None:
        self.errors.append(text)
        del self.errors[:-10]


class GpsdClient:
    """A gpsd JSON client that never blocks and never raises on I/O trouble.

    Call :meth:`poll` often (the daemon: every loop turn): it connects when due, sends
    ``?WATCH={"enable":true,"json":true}``, reads what is there (at most :data:`READ_CHUNK`
    bytes and :data:`LINES_PER_POLL` lines per call, so a peer that floods cannot hold up
    the caller), and returns the fixes (TPV) received since the last call. A refused or lost
    connection is retried after ``reconnect_min_s``, doubling up to ``reconnect_max_s``. Other
    reports are kept: ``version`` and ``devices`` (the latest of each); :meth:`poll_reports`
    returns every report. Host names are resolved by *resolver*
    (:func:`hdrd.io.resolve.default_resolver`) off the caller's thread: while a lookup runs,
    :meth:`poll` returns at once, a lookup slow or failed is a failed attempt (backoff), and an
    address found before is used while the name is looked up again.
    """

    def __init__(
        self,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        *,
        reconnect_min_s: float = 0.5,
        reconnect_max_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
        resolver: Resolver | None = None,
    ) -> None:
        self.host, self.port = host, port
        self._resolver = resolver or default_resolver()
        self.reconnect_min_s, self.reconnect_max_s = reconnect_min_s, reconnect_max_s
        self._clock = clock
        self._sock: socket.socket | None = None
        self._connecting = False
        self._buf = bytearray()
        self._skip_line = False  # dropping the rest of a line longer than MAX_LINE
        self._next_try = 0.0
        self._backoff = reconnect_min_s
        self._last_failure: str | None = None
        self.connected = False
        self.closed = False
        self.stats = ClientStats()
        self.version: Version | None = None
        self.devices: Devices | None = None

    def __repr__(self) -> str:
        return f"GpsdClient({self.host!r}, {self.port})"

    # -- connection --
    def _fail(self, reason: str) -> None:
        was = self.connected
        if self._sock is not None:
            try:
                self._sock.close()
            except OSError:
                pass
        self._sock = None
        self._connecting = False
        self.connected = False
        self._buf.clear()
        self._skip_line = False
        self._next_try = self._clock() + self._backoff
        self._backoff = min(self._backoff * 2, self.reconnect_max_s)
        if was:
            self.stats.disconnects += 1
            log.warning("gpsd_lost", host=self.host, port=self.port, reason=reason)
        elif reason != self._last_failure:
            log.warning(
                "gpsd_unavailable",
                host=self.host,
                port=self.port,
                reason=reason,
                retry_s=round(self._next_try - self._clock(), 3),
            )
        self._last_failure = reason

    def _start_connect(self) -> None:
        found = self._resolver.lookup(self.host, self.port, socket.SOCK_STREAM, refresh=True)
        if not found.infos:
            if found.pending and found.error is None:  # being looked up: look again soon
                self._next_try = self._clock() + RESOLVE_POLL_S
            else:
                self._fail(found.error or f"cannot resolve {self.host}")
            return
        family, stype, proto, _, addr = found.infos[0]
        try:
            s = socket.socket(family, stype | socket.SOCK_CLOEXEC, proto)
        except OSError as e:
            self._fail(f"socket: {e.strerror or e}")
            return
        s.setblocking(False)
        self._sock = s
        self.stats.attempts += 1
        rc = s.connect_ex(addr)
        if rc in (0, errno.EINPROGRESS, errno.EWOULDBLOCK, errno.EALREADY):
            self._connecting = True
            if rc == 0:
                self._on_connected()
        else:
            self._fail(f"connect: {errno.errorcode.get(rc, rc)}")

    def _on_connected(self) -> None:
        assert self._sock is not None
        self._connecting = False
        try:
            self._sock.send(WATCH_COMMAND)  # 36 bytes into an empty socket buffer: all of it
        except OSError as e:
            self._fail(f"send: {e.strerror or e}")
            return
        self.connected = True
        self._backoff = self.reconnect_min_s
        self._last_failure = None
        self.stats.connects += 1
        log.info("gpsd_connected", host=self.host, port=self.port, connects=self.stats.connects)

    def _check_connect(self) -> None:
        assert self._sock is not None
        try:
            _, w, _ = select.select([], [self._sock], [], 0)
        except (OSError, ValueError) as e:
            self._fail(f"select: {e}")
            return
        if not w:
            return
        err = self._sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
        if err:
            self._fail(f"connect: {errno.errorcode.get(err, str(err))}")
            return
        self._on_connected()

    # -- reading --
    def _read(self) -> list[bytes]:
        """At most :data:`LINES_PER_POLL` complete lines, reading at most one chunk of
        :data:`READ_CHUNK` bytes, and only when fewer than a chunk's worth of bytes or no
        complete line is buffered (so the buffer stays under MAX_LINE + READ_CHUNK)."""
        buf = self._buf
        if (len(buf) < READ_CHUNK or buf.find(b"\n") < 0) and not self._receive():
            return []
        lines: list[bytes] = []
        pos = 0
        while len(lines) < LINES_PER_POLL:
            nl = buf.find(b"\n", pos)
            if nl < 0:
                break
            if nl - pos > MAX_LINE:
                self._too_long()
            else:
                lines.append(bytes(buf[pos:nl]))
            pos = nl + 1
        del buf[:pos]
        if len(buf) > MAX_LINE and buf.find(b"\n") < 0:
            self._too_long()
            buf.clear()
            self._skip_line = True
        return lines

    def _receive(self) -> bool:
        """Read at most one chunk into the buffer, without the rest of a line too long to
        keep; False when the connection failed or the chunk was all such a rest."""
        assert self._sock is not None
        try:
            chunk = self._sock.recv(READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return True
        except OSError as e:
            self._fail(f"recv: {e.strerror or e}")
            return False
        if not chunk:
            self._fail("gpsd closed the connection")
            return False
        if self._skip_line:  # the rest of a line too long to keep
            nl = chunk.find(b"\n")
            if nl < 0:
                return False
            chunk = chunk[nl + 1 :]
            self._skip_line = False
        self._buf += chunk
        return True

    def _too_long(self) -> None:
        self.stats.bad_lines += 1
        self.stats.note(f"a line longer than {MAX_LINE} bytes dropped")

    def poll_reports(self) -> list[Report]:
        """The reports received since the last call, oldest first: at most
        :data:`LINES_PER_POLL` lines are parsed per call, the rest wait for the next ones.
        Never blocks, never raises (bad lines are counted in ``stats`` and skipped)."""
        if not self._ready():
            return []
        out: list[Report] = []
        for raw in self._read():
            if not raw.strip():
                continue
            self.stats.lines += 1
            try:
                rep = parse_line(raw)
            except GpsdProtocolError as e:
                self.stats.bad_lines += 1
                self.stats.note(f"bad line ({e}): {raw[:80]!r}")
                continue
            if rep is not None:
                self._keep(rep)
                out.append(rep)
        return out

    def _ready(self) -> bool:
        """Connected, after connecting when due; False while not (or closed)."""
        if self.closed:
            return False
        if self._sock is None:
            if self._clock() < self._next_try:
                return False
            self._start_connect()
            if self._sock is None:
                return False
        if self._connecting:
            self._check_connect()
            if not self.connected:
                return False
        return True

    def _keep(self, rep: Report) -> None:
        """Count a fix; keep the latest version and devices; note an error."""
        if isinstance(rep, Fix):
            self.stats.fixes += 1
        elif isinstance(rep, Version):
            self.version = rep
        elif isinstance(rep, Devices):
            self.devices = rep
        elif isinstance(rep, GpsdError):
            self.stats.note(f"gpsd error: {rep.message}")

    def poll(self) -> list[Fix]:
        """The fixes (TPV reports) received since the last call, oldest first."""
        return [r for r in self.poll_reports() if isinstance(r, Fix)]

    def close(self) -> None:
        """Close the connection (idempotent); poll() then returns nothing."""
        self.closed = True
        if self._sock is not None:
            try:
                self._sock.close()
            except OSError:
                pass
            self._sock = None
        self.connected = False

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
