"""The serial link: raw bytes from a port that reopens itself (pyserial underneath).

:class:`SerialReader` is shared by :class:`hdrd.io.wire.sources.SerialSource` (frames for the daemon
and ``hdrd calibrate``) and ``hdrd record`` (raw bytes to a capture). It reports a lost
device once (:class:`DeviceLost`), reopens it with backoff inside its ``read`` calls, and
reports it back (:class:`DeviceBack`); nothing it does blocks longer than the timeout a
caller gives, ``socket://`` connections and the lookup of their host name included. The port is opened exclusively, so a
second hdrd on the same device gets a clear "in use" error instead of half the frames.
Time comes from a :class:`Clock` (real, or a test's :class:`ManualClock`).
"""

from __future__ import annotations

import errno
import os
import select
import socket
from dataclasses import dataclass
from typing import Any

import serial
from serial.urlhandler import protocol_socket

from hdrd.io.resolve import Resolver, default_resolver
from hdrd.io.wire.clocks import Clock, RealClock

__all__ = [
    "CONNECT_TIMEOUT_S",
    "DeviceBack",
    "DeviceLost",
    "LinkStats",
    "SerialReader",
]


# --------------------------------------------------------------------------- events


@dataclass(frozen=True, slots=True)
class DeviceLost:
    """The device went away (unplugged, EOF, I/O error); the source is reopening it."""

    reason: str


@dataclass(frozen=True, slots=True)
class DeviceBack:
    """The device is open again after a :class:`DeviceLost`."""


# --------------------------------------------------------------------------- serial


@dataclass(slots=True)
class LinkStats:
    """The serial link's counters: bytes read, losses, successful reopenings, failed opens."""

    bytes_read: int = 0
    lost: int = 0
    reconnects: int = 0
    open_failures: int = 0


def _reason(e: BaseException) -> str:
    text = str(e).strip()
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


_READ_MAX = 65536
"""Most bytes taken from the port per read: 4096 hdr-bin frames, 0.2 s of a 3 Mbaud link."""


CONNECT_TIMEOUT_S = 5.0
"""A ``socket://`` connection not made within this long is a failed open (pyserial's)."""
CONNECT_POLL_S = 0.05
"""While a ``socket://`` connection is being made, how often ``read`` looks at it, s."""
START_CONNECT_WAIT_S = 1.0
"""At construction, how long a ``socket://`` connection may take before the reader reports
the device lost and goes on connecting in the background (during ``read`` calls)."""


class _SocketPort(protocol_socket.Serial):
    """pyserial's ``socket://`` port on a socket that :class:`SerialReader` connected without
    blocking. Why: pyserial's own open blocks up to 5 s in ``create_connection`` (a listener
    with a full backlog never answers), and its close sleeps 0.3 s; both would stall the
    daemon's loop while it reconnects."""

    def adopt(self, sock: socket.socket) -> None:
        """Become open on ``sock`` (connected), as pyserial's ``open`` would leave it."""
        self.logger = None
        sock.setblocking(False)
        self._socket = sock
        self.is_open = True

    def close(self) -> None:
        if self.is_open and self._socket is not None:
            try:
                self._socket.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self._socket.close()
        self._socket = None  # type: ignore[assignment] # pyserial's own close does the same
        self.is_open = False


def _open_reason(e: BaseException, url: str) -> str:
    """Why ``url`` did not open, as the user wants to read it: a missing device or a denied
    one said plainly, else the exception's own text."""
    err = getattr(e, "errno", None)
    if err == errno.ENOENT:
        return f"{url} does not exist"
    if err in (errno.EACCES, errno.EPERM):
        return f"{url}: permission denied (is the user in the device's group, e.g. dialout?)"
    return _reason(e)


def _busy_reason(e: BaseException, url: str) -> str | None:
    """The user's message if ``e`` says another program holds the port (pyserial's
    ``exclusive=True`` lock, or a device that refuses a second opener), else None."""
    text = str(e)
    if "exclusively lock" in text or getattr(e, "errno", None) == errno.EBUSY:
        return f"{url} is in use by another program (another hdrd run, calibrate or record?)"
    return None


def _fd_poll(port: Any) -> tuple[int, select.poll] | None:
    """(descriptor, poller) for the direct read path of a plain local port (``serial.Serial``
    on POSIX: a device path or a pty), None for URL handlers (``loop://``, ``socket://``,
    ``spy://``...), which keep pyserial's own read."""
    if type(port) is not serial.Serial or not isinstance(getattr(port, "fd", None), int):
        return None
    poller = select.poll()
    poller.register(port.fd, select.POLLIN | select.POLLERR | select.POLLHUP | select.POLLNVAL)
    return port.fd, poller


class SerialReader:
    """Raw bytes from a serial port that reopens itself (shared by SerialSource and record).

    ``url`` is anything ``serial.serial_for_url`` opens: a device path, a
    ``/dev/serial/by-id/...`` link, ``loop://``, ``socket://host:port``, ``spy://...``.
    ``read(timeout)`` returns the bytes available (waiting up to ``timeout`` s for the first
    one), ``None`` when nothing came, :class:`DeviceLost` once when the port fails (any
    OSError / SerialException, or EOF on a pty whose other side closed), and
    :class:`DeviceBack` once it has reopened the same URL. While lost it retries with
    exponential backoff from ``reconnect_min_s`` to ``reconnect_max_s``, inside ``read``
    calls, never waiting longer than the timeout given. It never raises on I/O trouble; an
    unusable URL (unknown scheme) raises ValueError at construction.
    """

    def __init__(
        self,
        url: str,
        baud: int = 115200,
        reconnect_min_s: float = 0.5,
        reconnect_max_s: float = 10.0,
        clock: Clock | None = None,
        resolver: Resolver | None = None,
    ) -> None:
        if not reconnect_min_s > 0 or not reconnect_max_s >= reconnect_min_s:
            raise ValueError(
                f"need 0 < reconnect_min_s <= reconnect_max_s, got {reconnect_min_s}, {reconnect_max_s}"
            )
        self.url = url
        self.baud = baud
        self.reconnect_min_s = reconnect_min_s
        self.reconnect_max_s = reconnect_max_s
        self.clock: Clock = clock or RealClock()
        self.resolver = resolver or default_resolver()
        """Looks up a ``socket://`` host off the caller's thread (:mod:`hdrd.io.resolve`)."""
        self.stats = LinkStats()
        self.port: Any = None
        self._timeout: object = object()  # the timeout the open port is set to (unset)
        self._backoff = reconnect_min_s
        self._next_try = 0.0
        self._closed = False
        self._report: DeviceLost | None = None
        self._fd_poll: tuple[int, select.poll] | None = None
        self._connecting: tuple[socket.socket, float] | None = None  # socket://, in progress
        self._looking_up = False  # socket://: its host's address is being looked up
        self.last_error: str | None = None
        self.busy = False
        """The last open failed because another program holds the port (its lock)."""
        self.opened_once = False
        """The port has been open at least once (False: still waiting for it to appear)."""
        try:
            # Validates the URL (unknown schemes raise here), without touching the device.
            serial.serial_for_url(url, baudrate=baud, do_not_open=True)
        except ValueError as e:
            raise ValueError(f"unusable serial port URL {url!r}: {e}") from None
        except (OSError, serial.SerialException):
            pass  # e.g. a socket:// host that does not resolve yet: treated as a lost device
        if not self._first_open():
            self._report = DeviceLost(self.last_error or "cannot open")
            self.stats.lost += 1

    def _first_open(self) -> bool:
        """Open at construction; a ``socket://`` lookup or connection under way gets
        START_CONNECT_WAIT_S before the device is called lost."""
        opened = self._open()
        deadline = self.clock.monotonic() + START_CONNECT_WAIT_S
        while not opened and (self._connecting is not None or self._looking_up):
            left = deadline - self.clock.monotonic()
            if left <= 0:
                break
            if self._connecting is not None:
                self._wait_connect(min(left, CONNECT_POLL_S))
            else:
                self.clock.sleep(min(left, CONNECT_POLL_S / 5))
            opened = self._open()
        return opened

    @property
    def is_open(self) -> bool:
        return self.port is not None

    def _open(self) -> bool:
        """One attempt to open the port: True if open (for ``socket://``, False while the
        connection is still being made, with the next look due in CONNECT_POLL_S)."""
        if self.url.startswith("socket://"):
            return self._open_socket()
        try:
            # exclusive: a second hdrd (calibrate on the daemon's port) gets a clear error
            # instead of stealing frames; pyserial locks the device with flock(2).
            port = serial.serial_for_url(
                self.url, baudrate=self.baud, timeout=0, exclusive=True, do_not_open=True
            )
            port.open()
        except Exception as e:  # noqa: BLE001 - any failure to open is "still lost"
            self._open_failed(e)
            return False
        self._adopt(port)
        return True

    def _open_failed(self, e: BaseException | str) -> None:
        if isinstance(e, str):
            self.busy, self.last_error = False, e
        else:
            busy = _busy_reason(e, self.url)
            self.busy, self.last_error = busy is not None, busy or _open_reason(e, self.url)
        self.stats.open_failures += 1
        now = self.clock.monotonic()
        self._next_try = now + self._backoff
        self._backoff = min(self._backoff * 2, self.reconnect_max_s)

    def _adopt(self, port: Any) -> None:
        self.port = port
        self.opened_once = True
        self.busy = False
        self._timeout = 0
        self._fd_poll = _fd_poll(port)
        self._backoff = self.reconnect_min_s

    def _open_socket(self) -> bool:
        """``socket://host:port`` connected without blocking: start the connection, then on
        later calls see whether it is made, failed, or has taken CONNECT_TIMEOUT_S."""
        now = self.clock.monotonic()
        if self._connecting is None:
            addr = self._socket_address(now)
            if addr is None:
                return False
            family, kind, proto, _, sockaddr = addr
            try:
                sock = socket.socket(family, kind, proto)
            except OSError as e:
                self._open_failed(e)
                return False
            sock.setblocking(False)
            code = sock.connect_ex(sockaddr)
            if code not in (0, errno.EINPROGRESS, errno.EALREADY, errno.EWOULDBLOCK):
                sock.close()
                self._open_failed(f"could not connect to {self.url}: {os.strerror(code)}")
                return False
            self._connecting = (sock, now + CONNECT_TIMEOUT_S)
        sock, deadline = self._connecting
        try:
            ready = select.select([], [sock], [], 0)[1]
        except (OSError, ValueError) as e:
            self._connecting = None
            sock.close()
            self._open_failed(e)
            return False
        if not ready:
            if now < deadline:
                self.last_error = f"connecting to {self.url}: no answer yet"
                self._next_try = now + CONNECT_POLL_S
                return False
            self._connecting = None
            sock.close()
            self._open_failed(
                f"could not connect to {self.url}: no answer in {CONNECT_TIMEOUT_S:g} s"
            )
            return False
        self._connecting = None
        code = sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
        if code:
            sock.close()
            self._open_failed(f"could not connect to {self.url}: {os.strerror(code)}")
            return False
        port = _SocketPort(None)
        port._port = self.url  # what pyserial's port.port shows
        port.adopt(sock)
        self._adopt(port)
        return True

    def _socket_address(self, now: float) -> Any:
        """The ``socket://`` host's address as the resolver knows it now (never waits); None,
        with the next try due, while it is looked up or when it failed."""
        try:
            host, tcp_port = _SocketPort(None).from_url(self.url)
        except Exception as e:  # noqa: BLE001 - a bad URL: still lost
            self._open_failed(e)
            return None
        found = self.resolver.lookup(host, tcp_port, socket.SOCK_STREAM, refresh=True)
        self._looking_up = not found.infos and found.pending and found.error is None
        if found.infos:
            return found.infos[0]
        if self._looking_up:  # being looked up: look again soon
            self.last_error = f"connecting to {self.url}: looking up {host}"
            self._next_try = now + CONNECT_POLL_S
        else:
            self._open_failed(found.error or f"cannot resolve {host}")
        return None

    def _wait_connect(self, timeout: float) -> None:
        """Wait up to ``timeout`` s for the connection under way to be made or fail."""
        if self._connecting is not None:
            try:
                select.select([], [self._connecting[0]], [], max(timeout, 0.0))
            except (OSError, ValueError):
                pass

    def _lose(self, e: BaseException) -> DeviceLost:
        self.last_error = _reason(e)
        self._drop_port()
        self.stats.lost += 1
        self._backoff = self.reconnect_min_s
        self._next_try = self.clock.monotonic() + self._backoff
        return DeviceLost(self.last_error)

    def _drop_port(self) -> None:
        port, self.port = self.port, None
        self._fd_poll = None
        if self._connecting is not None:
            self._connecting[0].close()
            self._connecting = None
        if port is not None:
            try:
                port.close()
            except Exception:  # noqa: BLE001, S110 - closing a dead port may fail; it is gone anyway
                pass

    def read(self, timeout: float | None = None) -> bytes | DeviceLost | DeviceBack | None:
        """Bytes, None (nothing within timeout s), or a link event. See the class doc."""
        if self._closed:
            return None
        if self._report is not None:
            ev, self._report = self._report, None
            return ev
        if self.port is not None:
            return self._read_open(timeout)
        deadline = None if timeout is None else self.clock.monotonic() + timeout
        while True:
            now = self.clock.monotonic()
            if now >= self._next_try:
                if self._open():
                    self.stats.reconnects += 1
                    return DeviceBack()
                now = self.clock.monotonic()
            wait = self._next_try - now
            if deadline is not None:
                left = deadline - now
                if left <= 0:
                    return None
                wait = min(wait, left)
            self.clock.sleep(max(wait, 0.0))
            if self._closed:
                return None

    def _read_open(self, timeout: float | None) -> bytes | DeviceLost | None:
        if self._fd_poll is not None:
            return self._read_fd(*self._fd_poll, timeout)
        port = self.port
        try:
            if timeout != self._timeout:
                port.timeout = timeout
                self._timeout = timeout
            waiting = port.in_waiting
            data = port.read(waiting or 1)
            if data and not waiting:
                more = port.in_waiting  # the first byte woke us: take the rest that is there
                if more:
                    data += port.read(more)
        except Exception as e:  # noqa: BLE001 - any I/O trouble means the device is lost
            return self._lose(e)
        if not data:
            return None
        self.stats.bytes_read += len(data)
        return data

    def _read_fd(
        self, fd: int, poller: select.poll, timeout: float | None
    ) -> bytes | DeviceLost | None:
        """:meth:`_read_open` for a local serial device: one poll, one read of all there is.

        Why not ``port.read``: pyserial re-applies the termios settings whenever its timeout
        changes (every call here, as ``recv``'s deadline shrinks), and makes two select calls
        and two reads per wake-up (one byte, then ``in_waiting`` more); at 1 kHz that was most
        of the daemon's CPU. The descriptor is non-blocking (pyserial opens it O_NONBLOCK), so
        a read takes what the driver holds. Losses are what pyserial reports: an error from
        poll or read (EIO once a pty's other side has closed), or a readable descriptor that
        gives no bytes (an unplugged USB adapter). tests/test_serialport.py (ptys, sockets).
        """
        try:
            if not poller.poll(None if timeout is None else timeout * 1000.0):
                return None
            data = os.read(fd, _READ_MAX)
        except (BlockingIOError, InterruptedError):
            return None  # woken for nothing (another reader took the bytes, or a signal)
        except Exception as e:  # noqa: BLE001 - any I/O trouble means the device is lost
            return self._lose(e)
        if not data:
            return self._lose(
                serial.SerialException("device reports readiness to read but returned no data")
            )
        self.stats.bytes_read += len(data)
        return data

    def close(self) -> None:
        """Close the port (idempotent)."""
        self._closed = True
        self._drop_port()

    def __enter__(self) -> SerialReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
