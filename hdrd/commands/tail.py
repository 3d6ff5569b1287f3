"""``hdrd tail``: print what the daemon publishes (like gpsd's ``gpspipe -w``).

It binds a UDP socket, prints the table's header and says on stderr where it waits, then
prints a table row per HDR step, or the JSON lines and NMEA sentences as received
(``--raw``). The validation and formatting are :mod:`hdrd.io.net.datagrams`'s (pure,
:class:`~hdrd.io.net.datagrams.TailFormatter`: printable text only); this is the edge.
"""

from __future__ import annotations

import argparse
import errno
import os
import signal
import socket
import sys
import threading
from collections.abc import Sequence
from typing import TextIO

from hdrd.io.net.datagrams import DEFAULT_TAIL_LISTEN, TailFormatter, udp_listener
from hdrd.io.net.portowner import udp_port_holders

__all__ = ["main"]


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
        sock, shown = udp_listener(listen)
    except ValueError as e:
        print(f"hdrd tail: bad --listen {listen!r}: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        why = _in_use(listen) if e.errno == errno.EADDRINUSE else (e.strerror or str(e))
        print(f"hdrd tail: cannot listen on {listen}: {why}", file=sys.stderr)
        return 1
    formatter = TailFormatter(raw=bool(getattr(args, "raw", False)), display=_is_tty(sys.stdout))
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _raise_stop) if in_main else None
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


def _in_use(listen: str) -> str:
    """Why ``listen`` cannot be bound, when another socket holds it: which process, where
    this user can see it (:func:`hdrd.io.net.portowner.udp_port_holders`)."""
    try:
        holders = udp_port_holders(int(listen.rpartition(":")[2]))
    except (ValueError, OSError):
        holders = []
    held = "".join(f", held by pid {pid} ({cmd})" for pid, cmd in holders[:3])
    return (
        f"the address is in use{held}; stop that program, or listen on another address "
        "(--listen HOST:PORT, and send there: hdrd run --udp HOST:PORT)"
    )


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
