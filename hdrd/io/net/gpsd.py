"""gpsd's JSON protocol: a pure line parser and a non-blocking client.

gpsd (https://gpsd.io, ``gpsd_json(5)``) speaks newline-delimited JSON objects tagged with
``"class"``. A client sends ``?WATCH={"enable":true,"json":true}`` and then receives, per
GPS cycle, a ``TPV`` report (time, position, velocity: ``mode`` 0/1 = no fix, 2 = 2D,
3 = 3D; ``track`` = course over ground, compass degrees clockwise from true north;
``speed`` = ground speed, m/s; ``epd``/``eps`` their 95 % error estimates), now and then
``SKY`` and ``ATT`` (which hdrd does not use: read as unknown classes) and the session
reports ``VERSION``, ``DEVICES``, ``DEVICE``, ``WATCH`` and ``ERROR``. An
attribute whose value is unknown is left out, never sent as null: so are ours.

Pure core: :func:`parse_line` turns one line into a small frozen dataclass (or ``None`` for
a class we do not use) and raises :class:`GpsdProtocolError` for a line that is not a
gpsd JSON object. The edge, :class:`GpsdClient`, owns a TCP socket that never blocks and
never raises on I/O trouble: it connects, reconnects with backoff, buffers partial lines,
counts and skips bad ones; :meth:`GpsdClient.poll` returns the fixes that arrived.
:class:`hdrd.daemon.gpslink.GpsdLink` wires the client and :class:`hdrd.daemon.aiding.GpsAiding` to the
daemon's pipeline.
"""

from __future__ import annotations

import calendar
import errno
import json
import math
import re
import select
import socket
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hdrd.errors import HdrdError, clipped
from hdrd.io.logs import log
from hdrd.io.resolve import Resolver, default_resolver

if TYPE_CHECKING:
    from typing_extensions import Self  # typing.Self from Python 3.11

__all__ = [
    "DEFAULT_HOST",
    "DEFAULT_PORT",
    "WATCH_COMMAND",
    "Device",
    "Devices",
    "Fix",
    "GpsdClient",
    "GpsdError",
    "GpsdProtocolError",
    "Report",
    "Version",
    "Watch",
    "parse_address",
    "parse_line",
    "parse_time",
]

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 2947
WATCH_COMMAND = b'?WATCH={"enable":true,"json":true}\n'
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


class GpsdProtocolError(HdrdError, ValueError):
    """A line that is not a gpsd JSON report; ``str()`` says why."""


# -- reports ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Version:
    """``VERSION``: the first line gpsd sends on connect."""

    release: str
    rev: str | None = None
    proto_major: int | None = None
    proto_minor: int | None = None


@dataclass(frozen=True, slots=True)
class Device:
    """``DEVICE``: one device gpsd reads (alone, or inside ``DEVICES``)."""

    path: str | None = None
    driver: str | None = None
    activated: str | None = None
    """When gpsd opened it (ISO 8601); None once closed (gpsd then sends 0)."""
    bps: int | None = None


@dataclass(frozen=True, slots=True)
class Devices:
    """``DEVICES``: the devices gpsd knows about."""

    devices: tuple[Device, ...] = ()


@dataclass(frozen=True, slots=True)
class Watch:
    """``WATCH``: gpsd's answer to our ``?WATCH``."""

    enable: bool | None = None
    json: bool | None = None


@dataclass(frozen=True, slots=True)
class Fix:
    """``TPV``: a time-position-velocity report.

    mode: 0 unknown, 1 no fix, 2 2D fix, 3 3D fix. time: UNIX s (GPS time), None if not
    sent. track_deg: course over ground, compass deg clockwise from true north [0, 360).
    speed_mps: ground speed, m/s. epd: course error estimate, deg; eps: speed error
    estimate, m/s (95 %). lat/lon: deg; alt_m: altitude (MSL when given), m.
    """

    mode: int
    time: float | None = None
    track_deg: float | None = None
    speed_mps: float | None = None
    epd: float | None = None
    eps: float | None = None
    lat: float | None = None
    lon: float | None = None
    alt_m: float | None = None
    climb_mps: float | None = None
    device: str | None = None
    status: int | None = None

    @property
    def has_fix(self) -> bool:
        """A 2D or 3D fix."""
        return self.mode >= 2


@dataclass(frozen=True, slots=True)
class GpsdError:
    """``ERROR``: gpsd did not like a request."""

    message: str


Report = Version | Devices | Device | Watch | Fix | GpsdError

_TIME_RE = re.compile(r"(\d{4})-(\d\d)-(\d\d)T(\d\d):(\d\d):(\d\d)(\.\d+)?Z?\Z")


def _finite(v: int | float) -> float | None:
    """*v* as a finite float; None for NaN, +-inf and integers beyond float range (JSON
    integers have no size limit: ``1`` followed by 400 zeros is valid JSON)."""
    try:
        f = float(v)
    except OverflowError:
        return None
    return f if math.isfinite(f) else None


def parse_time(value: Any) -> float | None:
    """gpsd's time, ISO 8601 UTC (``2005-06-08T10:34:48.283Z``) or, in old gpsd, UNIX s,
    -> UNIX s. None for anything else (a bad time is not a reason to drop a fix)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return _finite(value)
    if not isinstance(value, str):
        return None
    m = _TIME_RE.match(value)
    if not m:
        return None
    y, mo, d, h, mi, s = (int(x) for x in m.groups()[:6])
    if not (1 <= y and 1 <= mo <= 12 and 1 <= d <= 31 and h < 24 and mi < 60 and s <= 60):
        return None  # year 0000 has no calendar date (datetime starts at year 1)
    frac = float(m.group(7)) if m.group(7) else 0.0
    return calendar.timegm((y, mo, d, h, mi, s, 0, 0, 0)) + frac


def _num(obj: Mapping[str, Any], key: str) -> float | None:
    """A finite number, None when absent or not finite (NaN, +-inf, an integer beyond float
    range); GpsdProtocolError when of the wrong type."""
    v = obj.get(key)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise GpsdProtocolError(f"{key!r} is not a number: {_shown(v)}")
    return _finite(v)


def _nonneg(obj: Mapping[str, Any], key: str) -> float | None:
    """:func:`_num` for a magnitude (a speed, an error estimate): a negative value is not one
    gpsd sends, so it is treated as unknown (None) rather than trusted."""
    v = _num(obj, key)
    return None if v is None or v < 0.0 else v


def _shown(v: Any) -> str:
    """A short, printable rendering of a bad value for an error message."""
    try:
        text = repr(v)
    except (ValueError, RecursionError):  # an int beyond the str-conversion limit, deep nesting
        text = f"<{type(v).__name__}>"
    return clipped(text, 40)


def _int(obj: Mapping[str, Any], key: str) -> int | None:
    v = _num(obj, key)
    return None if v is None else int(v)


def _str(obj: Mapping[str, Any], key: str) -> str | None:
    v = obj.get(key)
    if v is None:
        return None
    if not isinstance(v, str):
        raise GpsdProtocolError(f"{key!r} is not a string: {_shown(v)}")
    return v


def _bool(obj: Mapping[str, Any], key: str) -> bool | None:
    v = obj.get(key)
    if v is None:
        return None
    if not isinstance(v, bool):
        raise GpsdProtocolError(f"{key!r} is not true/false: {_shown(v)}")
    return v


def _device(obj: Mapping[str, Any]) -> Device:
    act = obj.get("activated")
    return Device(
        path=_str(obj, "path"),
        driver=_str(obj, "driver"),
        # ISO time when opened; gpsd sends the number 0 when it closes the device
        activated=act if isinstance(act, str) else None,
        bps=_int(obj, "bps"),
    )


def _fix(obj: Mapping[str, Any]) -> Fix:
    mode = _int(obj, "mode")
    track = _num(obj, "track")
    alt = _num(obj, "altMSL")
    return Fix(
        mode=0 if mode is None else mode,
        time=parse_time(obj.get("time")),
        track_deg=None if track is None else track % 360.0,
        speed_mps=_nonneg(obj, "speed"),
        epd=_nonneg(obj, "epd"),
        eps=_nonneg(obj, "eps"),
        lat=_num(obj, "lat"),
        lon=_num(obj, "lon"),
        alt_m=_num(obj, "alt") if alt is None else alt,
        climb_mps=_num(obj, "climb"),
        device=_str(obj, "device"),
        status=_int(obj, "status"),
    )


def parse_line(line: bytes | str) -> Report | None:
    """One line of gpsd output -> a report; None for a class hdrd does not use.

    Raises GpsdProtocolError (with the reason) for a line that is not a JSON object with a
    string ``class``, or whose known attributes have the wrong type; never anything else,
    whatever the line (numbers of any length, nesting of any depth, any bytes).
    A number that is not finite or beyond float range reads as absent (None); so does a
    negative speed or error estimate (``speed``, ``epd``, ``eps``: magnitudes).
    """
    if isinstance(line, bytes):
        try:
            line = line.decode("utf-8")
        except UnicodeDecodeError as e:
            raise GpsdProtocolError(f"not UTF-8: {e.reason}") from None
    line = line.strip()
    if not line:
        raise GpsdProtocolError("empty line")
    try:
        obj = json.loads(line)
    except json.JSONDecodeError as e:
        raise GpsdProtocolError(f"not JSON: {e.msg}") from None
    except ValueError:  # an integer of more than sys.get_int_max_str_digits() digits
        raise GpsdProtocolError("not JSON hdrd reads: a number with too many digits") from None
    except RecursionError:
        raise GpsdProtocolError("not JSON hdrd reads: nested too deeply") from None
    if not isinstance(obj, dict):
        raise GpsdProtocolError("not a JSON object")
    cls = obj.get("class")
    if not isinstance(cls, str):
        raise GpsdProtocolError("no 'class'")
    try:
        return _report(cls, obj)
    except GpsdProtocolError:
        raise
    except (ValueError, OverflowError, TypeError, RecursionError) as e:
        # A guard: every value is type-checked above, so this is a case we did not foresee;
        # the line is reported bad (counted, skipped) rather than stopping the caller.
        raise GpsdProtocolError(f"unusable {cls[:20]!r} report: {type(e).__name__}") from None


def _report(cls: str, obj: Mapping[str, Any]) -> Report | None:
    if cls == "TPV":
        return _fix(obj)
    if cls == "VERSION":
        return _version(obj)
    if cls == "DEVICES":
        return _devices(obj)
    if cls == "DEVICE":
        return _device(obj)
    if cls == "WATCH":
        return Watch(enable=_bool(obj, "enable"), json=_bool(obj, "json"))
    if cls == "ERROR":
        return GpsdError(_str(obj, "message") or "")
    return None


def _version(obj: Mapping[str, Any]) -> Version:
    return Version(
        release=_str(obj, "release") or _str(obj, "version") or "",
        rev=_str(obj, "rev"),
        proto_major=_int(obj, "proto_major"),
        proto_minor=_int(obj, "proto_minor"),
    )


def _devices(obj: Mapping[str, Any]) -> Devices:
    devs = obj.get("devices", [])
    if not isinstance(devs, list) or not all(isinstance(d, dict) for d in devs):
        raise GpsdProtocolError("'devices' is not a list of objects")
    return Devices(tuple(_device(d) for d in devs))


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
