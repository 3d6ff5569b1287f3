"""``hdrd tail``: print what the daemon publishes (like gpsd's ``gpspipe -w``).

It binds a UDP socket, prints the table's header and says on stderr where it waits, then
prints a table row per HDR step, or the JSON lines and NMEA sentences as received
(``--raw``). What it prints is printable text only (:func:`printable`): no datagram can move
the cursor, retitle the window or ring the bell. Every number fits its column (a yaw of
1e300 is ``1e+300``, never 300 digits); on a terminal JSON lines show their numbers rounded
to what they mean (:func:`hdrd.io.display.for_display`), into a pipe exactly as received. The
formatting is pure (:class:`TailFormatter`); :func:`main` is the edge.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any, TextIO

from hdrd.io.display import fit, for_display
from hdrd.io.protocol import MESSAGE_CLASS
from hdrd.io.publish import heading_field, parse_hostport, parse_nmea

__all__ = ["DEFAULT_TAIL_LISTEN", "TailFormatter", "main", "printable"]


DEFAULT_TAIL_LISTEN = "127.0.0.1:10110"
"""Where ``hdrd tail`` listens by default (10110: the registered NMEA-0183 port)."""


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
    what they mean (:func:`hdrd.io.display.for_display`).
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
        notes: list[str] = []
        count = 0
        for raw_line in data.split(b"\n"):
            raw_line = raw_line.rstrip(b"\r")
            if not raw_line.strip():
                continue
            shown = raw_line[:60].decode("utf-8", "replace")
            try:
                text = raw_line.decode("utf-8")
            except UnicodeDecodeError:
                notes.append(f"hdrd tail: ignored non-UTF-8 data from {sender}: {shown!r}")
                continue
            if text.startswith(("$", "!")):
                try:
                    kind, fields_ = parse_nmea(text)
                except ValueError as e:
                    notes.append(
                        f"hdrd tail: ignored a bad NMEA sentence from {sender}: {e}: {shown!r}"
                    )
                    continue
                count += 1
                what = "" if self.raw else self.describe_nmea(kind, fields_)
                out.append(f"{text}    # {what}" if what else text)
                continue
            try:
                msg = json.loads(text)
            except json.JSONDecodeError as e:
                notes.append(f"hdrd tail: ignored malformed data from {sender}: {e.msg}: {shown!r}")
                continue
            except (ValueError, RecursionError) as e:  # a huge integer; nesting too deep
                why = "nested too deeply" if isinstance(e, RecursionError) else "a number too long"
                notes.append(f"hdrd tail: ignored data from {sender}: {why}: {shown!r}")
                continue
            if not isinstance(msg, dict):
                notes.append(
                    f"hdrd tail: ignored a JSON value that is not an object from {sender}: {shown!r}"
                )
                continue
            count += 1
            if self.raw or msg.get("class") != MESSAGE_CLASS:
                out.append(_printable_json(self._shown_json(text, msg)))
                continue
            if not self._header_done:
                out.append(self.header())
                self._header_done = True
            out.append(self.row(msg))
        return out, notes, count

    def _shown_json(self, text: str, msg: dict[str, Any]) -> str:
        """The JSON line as received, or (``display``) with its numbers rounded."""
        if not self.display:
            return text
        try:
            return json.dumps(for_display(msg), separators=(",", ":"), ensure_ascii=False)
        except (ValueError, TypeError, RecursionError):
            return text


def _raise_stop(signum: int, frame: object) -> None:
    raise KeyboardInterrupt  # SIGTERM ends ``hdrd tail`` as Ctrl-C does: status 0


def _write(stream: TextIO, lines: Sequence[str]) -> None:
    if lines:
        stream.write("".join(f"{line}\n" for line in lines))
        stream.flush()


def main(args: argparse.Namespace) -> int:
    """``hdrd tail [--listen HOST:PORT] [--raw] [--count N]``: print what the daemon sends.

    Binds a UDP socket (default 127.0.0.1:10110), prints the table's header at once and
    says on stderr that it waits on that address, then prints a table row per HDR step, or
    the JSON lines / NMEA sentences as received with ``--raw``. Malformed data gets a note on
    stderr and is skipped. SIGINT, SIGTERM, ``--count`` reached, or the reader of stdout
    going away (``| head``) end it with status 0.
    """
    listen = getattr(args, "listen", None) or DEFAULT_TAIL_LISTEN
    count_max: int | None = getattr(args, "count", None)
    if count_max is not None and count_max < 1:
        print("hdrd tail: --count must be at least 1", file=sys.stderr)
        return 2
    try:
        host, port = parse_hostport(listen)
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM, flags=socket.AI_PASSIVE)
    except (ValueError, OSError, UnicodeError) as e:
        print(f"hdrd tail: bad --listen {listen!r}: {e}", file=sys.stderr)
        return 2
    family, _, _, _, sockaddr = infos[0]
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        sock.bind(sockaddr)
    except OSError as e:
        sock.close()
        print(f"hdrd tail: cannot listen on {listen}: {e.strerror or e}", file=sys.stderr)
        return 1
    formatter = TailFormatter(raw=bool(getattr(args, "raw", False)), display=_is_tty(sys.stdout))
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _raise_stop) if in_main else None
    shown = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    try:
        _write(sys.stdout, formatter.start())
        _write(
            sys.stderr,
            [f"hdrd tail: waiting on {shown} (hdrd run --udp {shown} sends there)"],
        )
        _print_messages(sock, formatter, count_max)
        return 0
    except KeyboardInterrupt:
        return 0
    except BrokenPipeError:
        _silence(sys.stdout)
        return 0
    finally:
        if in_main:
            signal.signal(signal.SIGTERM, previous)
        sock.close()


def _print_messages(sock: socket.socket, formatter: TailFormatter, count_max: int | None) -> None:
    """Print what comes (notes on stderr) until ``count_max`` messages (None: until
    stopped)."""
    seen = 0
    while count_max is None or seen < count_max:
        data, addr = sock.recvfrom(65535)
        out, notes, n = formatter.lines(data, sender=f"{addr[0]}:{addr[1]}")
        if count_max is not None and seen + n > count_max:
            out = out[: len(out) - (seen + n - count_max)]
        _write(sys.stderr, notes)
        _write(sys.stdout, out)
        seen += n


def _is_tty(stream: TextIO | None) -> bool:
    try:
        return stream is not None and stream.isatty()
    except (ValueError, OSError):
        return False


def _silence(stream: TextIO) -> None:
    """Point *stream*'s descriptor at /dev/null so the exit-time flush cannot fail."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, stream.fileno())
        finally:
            os.close(devnull)
    except (OSError, ValueError):
        pass
