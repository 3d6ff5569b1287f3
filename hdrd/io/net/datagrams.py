"""The daemon's datagrams as a reader receives them: what ``hdrd tail`` and ``hdrd web`` accept,
and ``hdrd tail``'s printing of them.

:func:`read_datagram` is the one validation of a received datagram (pure, never raises): its
lines that are UTF-8 and either an NMEA 0183 sentence with a good checksum
(:func:`hdrd.io.net.formats.parse_nmea`) or a JSON object; a note for each other line (not UTF-8,
malformed, a number of more than 4,300 digits, nesting too deep, a JSON value that is not an
object). :func:`implausible` says why an HDR message holds a value no hdrd can send (``hdrd
web`` refuses such a message). :func:`udp_listener` binds the UDP socket both read from.

:class:`TailFormatter` turns datagrams into ``hdrd tail``'s lines: the table's header, a row per
HDR step, or the JSON lines and NMEA sentences as received (``raw``). What it returns is
printable text only (:func:`printable`): no datagram can move the cursor, retitle the window or
ring the bell. Every number fits its column (a yaw of 1e300 is ``1e+300``, never 300 digits); on
a terminal JSON lines show their numbers rounded to what they mean
(:func:`hdrd.io.net.display.for_display`), into a pipe exactly as received.
"""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hdrd.io.net.display import fit, for_display
from hdrd.io.net.formats import heading_field, parse_nmea
from hdrd.io.net.publish import parse_hostport
from hdrd.io.wire.protocol import ADDED_KEYS, MESSAGE_CLASS, STEP_KEYS

__all__ = [
    "DEFAULT_TAIL_LISTEN",
    "MAX_MAGNITUDE",
    "Received",
    "TailFormatter",
    "bound_socket",
    "implausible",
    "printable",
    "read_datagram",
    "shown_address",
    "udp_listener",
]


DEFAULT_TAIL_LISTEN = "127.0.0.1:10110"
"""Where ``hdrd tail`` (and ``hdrd web``'s ``--udp``) listens by default (10110: the registered
NMEA-0183 port)."""


_COLUMNS: tuple[tuple[str, str, int, str], ...] = (
    # (title, key, width, format); a missing value prints as "-"
    ("time", "time", 8, "time"),
    ("step", "step", 6, "d"),
    ("status", "status", 11, "s"),
    ("heading", "heading", 7, ".2f"),
    ("yaw", "yaw", 9, ".2f"),
    ("omega", "omega", 8, ".3f"),
    ("I", "I", 8, ".4f"),
    ("W", "W", 1, "d"),
    ("r", "r", 4, "d"),
    ("bias", "bias", 8, ".4f"),
    ("samples", "samples", 7, "d"),
    ("bad", "bad_frames", 5, "d"),
    ("mode", "mode", 14, "s"),  # GPS aiding (hdrd run --gpsd): aided / dead-reckoning
)


# -- receiving ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Received:
    """One valid line of a datagram, as received (``text``, printable or not): a JSON object
    (``msg``) or an NMEA sentence (``nmea``: its talker and sentence, and its fields)."""

    text: str
    msg: dict[str, Any] | None = None
    nmea: tuple[str, list[str]] = ("", [])


def _read_line(raw_line: bytes, sender: str, who: str) -> Received | str:
    """One line of a datagram: what it holds, or the note saying why it is ignored."""
    shown = raw_line[:60].decode("utf-8", "replace")
    try:
        text = raw_line.decode("utf-8")
    except UnicodeDecodeError:
        return f"{who}: ignored non-UTF-8 data from {sender}: {shown!r}"
    if text.startswith(("$", "!")):
        try:
            return Received(text, nmea=parse_nmea(text))
        except ValueError as e:
            return f"{who}: ignored a bad NMEA sentence from {sender}: {e}: {shown!r}"
    try:
        msg = json.loads(text)
    except json.JSONDecodeError as e:
        return f"{who}: ignored malformed data from {sender}: {e.msg}: {shown!r}"
    except (ValueError, RecursionError) as e:  # a huge integer; nesting too deep
        why = "nested too deeply" if isinstance(e, RecursionError) else "a number too long"
        return f"{who}: ignored data from {sender}: {why}: {shown!r}"
    if not isinstance(msg, dict):
        return f"{who}: ignored a JSON value that is not an object from {sender}: {shown!r}"
    return Received(text, msg=msg)


MAX_MAGNITUDE = 1e15
"""No number hdrd publishes comes near this (in a count, a time in UNIX s, an angle in deg, a
rate in deg/s); below 2**53, so an integer up to it is exact in a browser too."""
_COMPASS_KEYS = ("heading", "gps_course")
"""Compass headings, deg clockwise from north: in [0, 360] (360 once rounded)."""
_KNOWN_KEYS = STEP_KEYS + ADDED_KEYS


def _shown_number(v: float | int) -> str:
    if isinstance(v, int) and abs(v) >= 10**16:
        return f"(an integer of {len(str(abs(v)))} digits)"
    return f"{v:.6g}"


def implausible(msg: Mapping[str, Any]) -> str | None:
    """Why an HDR message holds a value no hdrd can send, or None: a number under a key
    docs/protocol.md defines that is not finite, or beyond :data:`MAX_MAGNITUDE`, or a compass
    heading (``heading``, ``gps_course``) outside [0, 360]. Other types, and keys this version
    does not know, are not judged (readers ignore what they do not understand). Pure."""
    for key in _KNOWN_KEYS:
        v = msg.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        if not abs(v) <= MAX_MAGNITUDE:  # NaN too; exact for an integer of any length
            return f"{key} {_shown_number(v)} is beyond any value hdrd sends"
        if key in _COMPASS_KEYS and not 0.0 <= v <= 360.0:
            return f"{key} {_shown_number(v)} is not a compass heading (0 to 360 deg)"
    return None


def read_datagram(
    data: bytes, sender: str = "?", who: str = "hdrd tail"
) -> tuple[list[Received], list[str]]:
    """A received datagram's valid lines, and a note (``who: ignored ...``, not yet made
    printable) for each line that is not valid (see the module doc). Blank lines are skipped;
    a line may end in CR LF. Pure; never raises."""
    items: list[Received] = []
    notes: list[str] = []
    for raw_line in data.split(b"\n"):
        raw_line = raw_line.rstrip(b"\r")
        if not raw_line.strip():
            continue
        got = _read_line(raw_line, sender, who)
        if isinstance(got, str):
            notes.append(got)
        else:
            items.append(got)
    return items, notes


def shown_address(host: str, port: int) -> str:
    """HOST:PORT as a user writes it (an IPv6 address in brackets)."""
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def bound_socket(listen: str, kind: int) -> tuple[socket.socket, str, Any]:
    """A socket of ``kind`` (``SOCK_DGRAM``, ``SOCK_STREAM``: with ``SO_REUSEADDR``) bound to
    ``listen`` (HOST:PORT, :func:`hdrd.io.net.publish.parse_hostport`; the first address the
    host resolves to), that address as shown to a user, and the socket address bound.

    ValueError: the address is malformed or does not resolve. OSError: it cannot be bound
    (in use, not this host's)."""
    try:
        host, port = parse_hostport(listen)
        infos = socket.getaddrinfo(host, port, type=kind, flags=socket.AI_PASSIVE)
    except (ValueError, OSError, UnicodeError) as e:
        raise ValueError(str(e)) from None
    family, _, _, _, sockaddr = infos[0]
    sock = socket.socket(family, kind)
    try:
        if kind == socket.SOCK_STREAM:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(sockaddr)
    except OSError:
        sock.close()
        raise
    return sock, shown_address(host, port), sockaddr


def udp_listener(listen: str) -> tuple[socket.socket, str]:
    """A UDP socket bound to ``listen`` and that address as shown to a user
    (:func:`bound_socket`)."""
    sock, shown, _ = bound_socket(listen, socket.SOCK_DGRAM)
    return sock, shown


# -- printing (hdrd tail) ----------------------------------------------------------------------


def _escape(c: str) -> str:
    """*c* as a JSON-style escape: ``\\u001b``; beyond the BMP, a surrogate pair."""
    o = ord(c)
    if o < 0x10000:
        return f"\\u{o:04x}"
    o -= 0x10000
    return f"\\u{0xD800 + (o >> 10):04x}\\u{0xDC00 + (o & 0x3FF):04x}"


def printable(text: str) -> str:
    """*text* with every character a terminal could act on escaped (``\\u001b`` for ESC):
    C0 and C1 controls (ESC, BEL, CR, CSI U+009B ...), DEL, format characters such as
    bidirectional overrides, separators other than the space, surrogates and unassigned
    code points; i.e. all that ``str.isprintable`` refuses. What ``hdrd tail`` prints goes
    through it, so no datagram can move the cursor, retitle the window or ring the bell."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else _escape(c) for c in text)


def _printable_json(text: str) -> str:
    """A valid JSON line made printable with the same meaning: raw TAB and CR can only be
    whitespace between tokens (JSON strings cannot hold them unescaped), so they become
    spaces; any other non-printable character is inside a string, where ``\\uXXXX`` is the
    same character."""
    if text.isprintable():
        return text
    return printable(text.replace("\t", " ").replace("\r", " "))


class TailFormatter:
    """Turns received datagrams into printable lines for ``hdrd tail`` (pure, no I/O).

    :meth:`lines` returns (stdout lines, stderr notes, messages counted). In table mode the
    header comes first (:meth:`start`, or before the first HDR message); NMEA sentences are
    printed as received with their decoded meaning; other JSON objects as received. With
    *raw*, everything valid is printed exactly as received (like ``gpspipe -w``). With
    *display* (stdout is a terminal), JSON lines are printed with their numbers rounded to
    what they mean (:func:`hdrd.io.net.display.for_display`).
    """

    def __init__(self, raw: bool = False, display: bool = False) -> None:
        self.raw = raw
        self.display = display
        self._header_done = False

    def start(self) -> list[str]:
        """What to print before any data: the header in table mode (once), else nothing."""
        if self.raw or self._header_done:
            return []
        self._header_done = True
        return [self.header()]

    @staticmethod
    def header() -> str:
        return " ".join(
            f"{t:<{w}}" if f in ("s", "time") else f"{t:>{w}}" for t, _, w, f in _COLUMNS
        ).rstrip()

    @staticmethod
    def row(msg: Mapping[str, Any]) -> str:
        cells = []
        for _, key, w, f in _COLUMNS:
            v = msg.get(key)
            try:
                if v is None:
                    cell = "-"
                elif f == "time":
                    cell = time.strftime("%H:%M:%S", time.localtime(float(v)))
                elif f == "d":
                    cell = fit(int(v), "d", w)
                elif f == "s":
                    cell = printable(str(v))
                elif key == "heading":
                    cell = heading_field(float(v))
                else:
                    cell = fit(float(v), f, w)
            except (TypeError, ValueError, OverflowError, OSError, RecursionError):
                cell = "?"
            cells.append(f"{cell:<{w}}" if f in ("s", "time") else f"{cell:>{w}}")
        return " ".join(cells).rstrip()

    @staticmethod
    def describe_nmea(kind: str, fields_: list[str]) -> str:
        sentence = kind[-3:]
        if sentence == "HDT" and fields_:
            return f"heading {fields_[0]} deg true"
        if sentence == "ROT" and len(fields_) >= 2:
            if not fields_[0]:
                return "rate of turn unknown"
            valid = "valid" if fields_[1] == "A" else "invalid"
            return f"rate of turn {fields_[0]} deg/min ({valid}; - = to port)"
        if sentence == "THS" and len(fields_) >= 2:
            mode = {"E": "estimated", "V": "invalid", "A": "autonomous"}.get(fields_[1], fields_[1])
            return f"heading {fields_[0]} deg true ({mode})"
        return ""

    def lines(self, data: bytes, sender: str = "?") -> tuple[list[str], list[str], int]:
        """Never raises; every line returned is printable (:func:`printable`)."""
        out, notes, count = self._lines(data, sender)
        return [printable(x) for x in out], [printable(x) for x in notes], count

    def _lines(self, data: bytes, sender: str) -> tuple[list[str], list[str], int]:
        out: list[str] = []
        items, notes = read_datagram(data, sender, "hdrd tail")
        for item in items:
            if item.msg is None:  # an NMEA sentence
                what = "" if self.raw else self.describe_nmea(*item.nmea)
                out.append(f"{item.text}    # {what}" if what else item.text)
            elif self.raw or item.msg.get("class") != MESSAGE_CLASS:
                out.append(_printable_json(self._shown_json(item.text, item.msg)))
            else:
                if not self._header_done:
                    out.append(self.header())
                    self._header_done = True
                out.append(self.row(item.msg))
        return out, notes, len(items)

    def _shown_json(self, text: str, msg: dict[str, Any]) -> str:
        """The JSON line as received, or (``display``) with its numbers rounded."""
        if not self.display:
            return text
        try:
            return json.dumps(for_display(msg), separators=(",", ":"), ensure_ascii=False)
        except (ValueError, TypeError, RecursionError):
            return text
