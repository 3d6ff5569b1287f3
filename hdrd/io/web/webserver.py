"""``hdrd web``'s server: the daemon's UDP JSON in, one read-only page and a stream of
server-sent events out (docs/web.md). Standard library only: asyncio, in one thread.

What it serves, to ``GET`` only: the page (``/``), its script, style sheet and icon (package
data, read once at start), and the stream (``/events``, ``text/event-stream``, the events of
:mod:`hdrd.io.web.webstate`). Any other method is refused (405), any other path is 404; nothing
changes anything. Every response carries a content security policy that lets the page run
only its own script and connect only to its own server.

Whom it trusts: nobody who connects. A request's head must arrive whole within
``head_timeout_s`` and fit in :data:`MAX_HEAD_BYTES` (else 408, 431); a malformed one is 400.
While it listens on a loopback address, a request whose ``Host`` is not a loopback name or
address is refused (403): a web site in the viewer's browser cannot reach the page by
rebinding its own name to 127.0.0.1. At most ``max_clients`` streams at once (more: 503).
Connections still waiting for their request's head are bounded per peer
(:data:`PEER_PENDING`) and in total (:data:`EXTRA_CONNECTIONS`): beyond, the oldest of that
peer, or of the peer with the most, is closed (once what came with them is read), so
connections that never ask for anything (a slowloris) cannot keep a page load from another
peer out; and the total of connections is bounded
(``max_connections``: more are closed at once). A stream's writes never
wait: each goes to the kernel, or to the connection's queue when the kernel's buffer (set to
``send_buffer`` bytes) is full; a client whose queue holds more than ``queue_bytes`` when the
next event comes is disconnected (its browser reconnects and starts afresh), so a stalled or
slow client costs the others nothing. :func:`descriptors` fits ``max_clients`` to the
process's descriptor limit; should accepting run out of descriptors all the same, that is one
warning every :data:`LOG_INTERVAL_S`, not a traceback per retry. Datagrams are taken from
whoever can send to the UDP address (loopback by default), validated as ``hdrd tail``
validates them.
"""

from __future__ import annotations

import asyncio
import errno
import os
import resource
import socket
import time
from dataclasses import dataclass
from importlib import resources
from typing import Any

from hdrd.core.throttle import Throttle
from hdrd.io.logs import log
from hdrd.io.net.datagrams import bound_socket, shown_address
from hdrd.io.web.http import (
    STREAM_HEAD,
    Request,
    host_allowed,
    http_response,
    is_loopback,
    parse_request,
    peer_key,
)
from hdrd.io.web.webstate import LiveState

__all__ = [
    "ASSETS",
    "DEFAULT_MAX_CLIENTS",
    "DEFAULT_WEB_LISTEN",
    "EXTRA_CONNECTIONS",
    "MAX_HEAD_BYTES",
    "PEER_PENDING",
    "WebServer",
    "WebSettings",
    "descriptors",
    "fitted_max_clients",
    "load_assets",
    "tcp_listener",
]

DEFAULT_WEB_LISTEN = "127.0.0.1:8080"
"""Where ``hdrd web`` serves the page by default (this computer only)."""
DEFAULT_MAX_CLIENTS = 16
"""Streams served at once by default (``--max-clients``)."""
MAX_HEAD_BYTES = 8192
"""The longest request line and headers taken, bytes."""
EXTRA_CONNECTIONS = 16
"""Connections waiting for their request's head, in all (page loads: short-lived)."""
PEER_PENDING = 8
"""Connections waiting for their request's head from one peer (an address; IPv6: its /64). A
browser opens at most 6 at once to a server."""
SPARE_DESCRIPTORS = 16
"""Descriptors kept beyond the connections: the event loop's (3), and connections accepted
but not yet counted (asyncio accepts a burst of them at once)."""
LOG_INTERVAL_S = 10.0
"""At most one log line per this many seconds for each kind of repeated trouble."""

ASSETS: dict[str, tuple[str, str]] = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/app.js": ("app.js", "text/javascript; charset=utf-8"),
    "/style.css": ("style.css", "text/css; charset=utf-8"),
    "/favicon.svg": ("favicon.svg", "image/svg+xml"),
}
"""Path -> (file in ``hdrd/io/web/webpage/``, content type)."""
STREAM_PATH = "/events"


@dataclass(frozen=True)
class WebSettings:
    """The server's bounds (units in the names)."""

    max_clients: int = DEFAULT_MAX_CLIENTS
    """Streams at once (``--max-clients``)."""
    queue_bytes: int = 65_536
    """A stream client with more than this waiting for it is disconnected."""
    send_buffer: int = 32_768
    """The kernel's send buffer of each connection (``SO_SNDBUF``; Linux doubles it)."""
    head_timeout_s: float = 5.0
    """A request's head must arrive within this (a browser sends it at once)."""
    linger_s: float = 30.0
    """A page response not taken by then is dropped."""
    keepalive_s: float = 15.0
    """A comment line goes to every stream this often (finds dead connections)."""

    def __post_init__(self) -> None:
        if not 1 <= self.max_clients <= 10_000:
            raise ValueError(f"max_clients must be 1..10000, got {self.max_clients!r}")

    @property
    def max_connections(self) -> int:
        """Connections open at once, at most: the streams, those waiting for a request, and as
        many again for responses on their way out (more are closed at once)."""
        return self.max_clients + 2 * EXTRA_CONNECTIONS


def load_assets() -> dict[str, tuple[bytes, str]]:
    """Path -> (body, content type) of the page's files (package data)."""
    folder = resources.files("hdrd.io.web").joinpath("webpage")
    return {path: (folder.joinpath(name).read_bytes(), ct) for path, (name, ct) in ASSETS.items()}


def tcp_listener(listen: str) -> tuple[socket.socket, str, bool]:
    """A listening TCP socket on ``listen`` (:func:`hdrd.io.net.datagrams.bound_socket`), that
    address as shown to a user, and whether it is a loopback address.

    ValueError: malformed or not resolved. OSError: it cannot be bound."""
    sock, shown, sockaddr = bound_socket(listen, socket.SOCK_STREAM)
    try:
        sock.listen(64)
    except OSError:
        sock.close()
        raise
    return sock, shown, is_loopback(str(sockaddr[0]))


def fitted_max_clients(asked: int, nofile: int, in_use: int) -> int:
    """The most streams (at most ``asked``, at least 1) whose connections
    (:attr:`WebSettings.max_connections`) fit in ``nofile`` descriptors of which ``in_use``
    are taken, :data:`SPARE_DESCRIPTORS` kept aside. Pure."""
    room = nofile - in_use - SPARE_DESCRIPTORS - 2 * EXTRA_CONNECTIONS
    return max(1, min(asked, room))


def descriptors(asked: int) -> tuple[int, int, int]:
    """This process's descriptors for ``asked`` streams: (the soft RLIMIT_NOFILE, raised
    toward the hard one as far as they need, descriptors open now, :func:`fitted_max_clients`
    of that)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    try:  # those numbered below the limit (a new one takes the lowest free number)
        fds = [int(n) for n in os.listdir("/proc/self/fd")]
        in_use = sum(1 for fd in fds if soft == resource.RLIM_INFINITY or fd < soft) - 1
    except (OSError, ValueError):
        in_use = 16  # no /proc: a guess above what hdrd web holds at start
    need = asked + 2 * EXTRA_CONNECTIONS + SPARE_DESCRIPTORS + in_use
    if soft != resource.RLIM_INFINITY and soft < need:
        raised = need if hard == resource.RLIM_INFINITY else min(need, hard)
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (raised, hard))
            soft = raised
        except (ValueError, OSError):
            pass  # kept as it is: fewer clients
    nofile = need if soft == resource.RLIM_INFINITY else soft
    return nofile, in_use, fitted_max_clients(asked, nofile, in_use)


# -- the server ------------------------------------------------------------------------------


class WebServer:
    """Serves the page and the stream from the sockets given (see the module doc).

    :meth:`serve` runs until :meth:`stop` (thread-safe); counters: ``refused`` (streams over
    the limit), ``dropped`` (slow clients disconnected), ``closed_waiting`` (connections
    closed while waiting for a request, for a newer one).
    """

    def __init__(
        self,
        http_sock: socket.socket,
        udp_sock: socket.socket,
        local: bool,
        udp_shown: str = "",
        settings: WebSettings = WebSettings(),
        version: str = "",
    ) -> None:
        self.http_sock = http_sock
        self.udp_sock = udp_sock
        self.local = local
        self.settings = settings
        self.state = LiveState(udp_shown, version)
        self.assets = load_assets()
        self.clients: set[_Connection] = set()
        """The open streams."""
        self.open: set[_Connection] = set()
        """Every open connection (streams, page loads, requests still coming)."""
        self.waiting: dict[str, dict[_Connection, None]] = {}
        """Peer (:func:`peer_key`) -> its connections waiting for a request's head, oldest
        first."""
        self.n_waiting = 0
        self.refused = 0
        self.dropped = 0
        self.closed_waiting = 0
        self._throttles = {
            k: Throttle(LOG_INTERVAL_S)
            for k in ("ignored", "refused", "dropped", "waiting", "descriptors")
        }
        self._enforcing: asyncio.TimerHandle | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None

    async def serve(self) -> None:
        """Serve until :meth:`stop`; then every connection is closed."""
        loop = self._loop = asyncio.get_running_loop()
        loop.set_exception_handler(self._loop_error)
        self._stop = asyncio.Event()
        self.http_sock.setblocking(False)
        self.udp_sock.setblocking(False)
        server = await loop.create_server(lambda: _Connection(self), sock=self.http_sock)
        udp, _ = await loop.create_datagram_endpoint(lambda: _Datagrams(self), sock=self.udp_sock)
        keepalive = loop.call_later(self.settings.keepalive_s, self._keepalive)
        try:
            await self._stop.wait()
        finally:
            keepalive.cancel()
            server.close()
            udp.close()
            for c in list(self.open):
                c.transport.abort()
            await server.wait_closed()

    @property
    def connections(self) -> int:
        """Open connections."""
        return len(self.open)

    def stop(self) -> None:
        """End :meth:`serve` (from any thread)."""
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)

    def _loop_error(self, loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        """What asyncio could not hand to anyone: out of descriptors (or memory) to accept a
        connection is one rate-limited warning (asyncio pauses accepting for 1 s each time),
        not a traceback per retry; anything else as asyncio reports it."""
        exc = context.get("exception")
        if isinstance(exc, OSError) and exc.errno in _OUT_OF:
            if self._throttles["descriptors"].due(time.monotonic()):
                log.warning(
                    "web_descriptors_exhausted",
                    reason="no descriptor for a new connection: new ones wait, retried every "
                    "second (raise LimitNOFILE, or lower --max-clients)",
                    error=errno.errorcode.get(exc.errno or 0, str(exc.errno)),
                    open=len(self.open),
                )
            return
        loop.default_exception_handler(context)

    # -- connections waiting for a request --

    def admit(self, conn: _Connection) -> None:
        """A new connection, waiting for its request; when too many wait, some are closed,
        soon (:meth:`_enforce`)."""
        mine = self.waiting.setdefault(conn.key, {})
        mine[conn] = None
        self.n_waiting += 1
        over = len(mine) > PEER_PENDING or self.n_waiting > EXTRA_CONNECTIONS
        if over and self._enforcing is None and self._loop is not None:
            # A timer: it runs after the loop has read what the connections accepted with
            # this one already sent, so a request that came with a burst is answered first.
            self._enforcing = self._loop.call_later(0.0, self._enforce)

    def _enforce(self) -> None:
        """The bounds on connections waiting for a request: a peer's oldest beyond
        :data:`PEER_PENDING`, then the oldest of the peer with the most beyond
        :data:`EXTRA_CONNECTIONS` in all, closed."""
        self._enforcing = None
        for mine in list(self.waiting.values()):
            while len(mine) > PEER_PENDING:
                self._close_waiting(next(iter(mine)))
        while self.n_waiting > EXTRA_CONNECTIONS:
            busiest = max(self.waiting.values(), key=len)
            self._close_waiting(next(iter(busiest)))

    def _close_waiting(self, conn: _Connection) -> None:
        self.unwait(conn)
        conn.transport.abort()
        self.closed_waiting += 1
        if self._throttles["waiting"].due(time.monotonic()):
            log.warning(
                "web_connections_closed",
                reason="too many connections waiting for a request (idle or slow)",
                peer=conn.peer,
                closed=self.closed_waiting,
            )

    def unwait(self, conn: _Connection) -> None:
        """``conn`` no longer waits for a request (answered, closed); idempotent."""
        mine = self.waiting.get(conn.key)
        if mine is not None and conn in mine:
            del mine[conn]
            self.n_waiting -= 1
            if not mine:
                del self.waiting[conn.key]

    # -- streams --

    def open_stream(self, conn: _Connection) -> bool:
        """A new stream: sent the snapshot, or refused (False) when ``max_clients`` are in."""
        if len(self.clients) >= self.settings.max_clients:
            self.refused += 1
            if self._throttles["refused"].due(time.monotonic()):
                log.warning(
                    "web_client_refused",
                    reason="max_clients reached",
                    max_clients=self.settings.max_clients,
                    refused=self.refused,
                )
            return False
        self.clients.add(conn)
        conn.transport.write(STREAM_HEAD + self.state.snapshot(time.time()))
        return True

    def broadcast(self, event: bytes) -> None:
        """Queue ``event`` on every stream; a client with more than ``queue_bytes`` already
        queued is disconnected instead."""
        limit = self.settings.queue_bytes
        for c in list(self.clients):
            if c.transport.get_write_buffer_size() > limit:
                self.clients.discard(c)
                self.dropped += 1
                if self._throttles["dropped"].due(time.monotonic()):
                    log.warning(
                        "web_client_dropped",
                        reason="too slow: its queue is full",
                        peer=c.peer,
                        dropped=self.dropped,
                    )
                c.transport.abort()
            else:
                c.transport.write(event)

    def _keepalive(self) -> None:
        self.broadcast(b": keepalive\n\n")
        assert self._loop is not None
        self._loop.call_later(self.settings.keepalive_s, self._keepalive)

    def on_datagram(self, data: bytes, addr: Any) -> None:
        """A datagram: validated, kept, pushed (see :class:`hdrd.io.web.webstate.LiveState`)."""
        sender = f"{addr[0]}:{addr[1]}" if isinstance(addr, tuple) else str(addr)
        for event in self.state.take(data, sender, time.time()):
            self.broadcast(event)
        ignored = self.state.ignored
        new = self._throttles["ignored"].count(ignored, time.monotonic())
        if new:
            log.warning(
                "web_datagrams_ignored", total=ignored, new=new, last=self.state.last_reason
            )


_OUT_OF = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
"""What ``accept`` fails with when the process or the system runs out of resources."""


class _Datagrams(asyncio.DatagramProtocol):
    def __init__(self, server: WebServer) -> None:
        self.server = server

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.server.on_datagram(data, addr)

    def error_received(self, exc: Exception) -> None:
        pass  # an ICMP error from a sender that went away: nothing to do


class _Connection(asyncio.Protocol):
    """One HTTP connection: a request, then a page response or a stream."""

    def __init__(self, server: WebServer) -> None:
        self.server = server
        self.transport: Any = None
        self.peer = "?"
        self.key = "?"
        """The peer the per-peer bound counts it against (:func:`peer_key`)."""
        self.head = b""
        self.answered = False
        self.timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: Any) -> None:
        self.transport = transport
        s = self.server
        s.open.add(self)
        peer = transport.get_extra_info("peername")
        if isinstance(peer, tuple):
            self.peer, self.key = shown_address(str(peer[0]), int(peer[1])), peer_key(peer[0])
        if s.connections > s.settings.max_connections:
            transport.abort()
            return
        sock = transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, s.settings.send_buffer)
        self._arm(s.settings.head_timeout_s, self._too_slow)
        s.admit(self)

    def _arm(self, delay: float, what: Any) -> None:
        if self.timer is not None:
            self.timer.cancel()
        self.timer = asyncio.get_running_loop().call_later(delay, what)

    def _too_slow(self) -> None:
        self._answer(http_response(408, b"request too slow\n"))

    def data_received(self, data: bytes) -> None:
        if self.answered:
            return  # a stream's client has nothing more to say: ignored
        self.head += data
        end = self.head.find(b"\r\n\r\n")
        if end < 0:
            if len(self.head) > MAX_HEAD_BYTES:
                self._answer(http_response(431, b"request head too long\n"))
            return
        if end > MAX_HEAD_BYTES:
            self._answer(http_response(431, b"request head too long\n"))
            return
        self._route(parse_request(self.head[:end]))

    def _route(self, req: Request | None) -> None:
        s = self.server
        if req is None:
            self._answer(http_response(400, b"malformed request\n"))
        elif not host_allowed(req.host, s.local):
            self._answer(http_response(403, b"this server answers to localhost only\n"))
        elif req.method != "GET":
            self._answer(http_response(405, b"read only: GET\n", headers=("Allow: GET",)))
        elif req.path == STREAM_PATH:
            self._stream()
        elif req.path in s.assets:
            body, ct = s.assets[req.path]
            self._answer(http_response(200, body, ct))
        else:
            self._answer(http_response(404, b"not found\n"))

    def _stream(self) -> None:
        self.answered = True
        self.server.unwait(self)
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
        if not self.server.open_stream(self):
            self._answer(http_response(503, b"too many viewers\n", headers=("Retry-After: 10",)))

    def _answer(self, response: bytes) -> None:
        """Send a whole response and close; dropped if not taken within ``linger_s``."""
        self.answered = True
        self.server.unwait(self)
        self.transport.write(response)
        self.transport.close()
        self._arm(self.server.settings.linger_s, self.transport.abort)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.timer is not None:
            self.timer.cancel()
        self.server.unwait(self)
        self.server.clients.discard(self)
        self.server.open.discard(self)

    def eof_received(self) -> bool | None:
        return None  # the client closed its side: close the connection


def run_server(server: WebServer) -> None:
    """Serve until SIGTERM or SIGINT (then every connection is closed)."""
    import signal

    async def main() -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, server.stop)
        task = asyncio.create_task(server.serve())
        await task

    asyncio.run(main())
