"""``hdrd record``: the raw bytes of the gyro's port to a capture file, losing nothing.

Every byte read is written as read (no parsing, so a capture keeps garbage and bad frames
for replay and fault analysis); the file is flushed every second and fsynced at the end.
A pulled cable is survived: the port is reopened by :class:`hdrd.source.SerialReader` (the
same reconnect loop as the daemon) and the loss noted on stderr. SIGINT/SIGTERM, or
``--seconds``, end the recording after draining what the port still holds; exit status 0.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import time
from typing import Any

from hdrd.source import DeviceBack, DeviceLost, SerialReader

__all__ = ["main", "record"]

FLUSH_INTERVAL_S = 1.0
READ_TIMEOUT_S = 0.2
"""Longest a read waits, s: bounds how late a signal or --seconds is noticed."""


def _note(msg: str) -> None:
    print(f"hdrd record: {msg}", file=sys.stderr, flush=True)


def record(
    reader: SerialReader,
    out: Any,
    seconds: float | None = None,
    stop: Any = None,
    note: Any = _note,
) -> dict[str, float]:
    """Copy bytes from ``reader`` to the binary file ``out`` until ``seconds`` have passed
    (None: forever) or ``stop()`` is true; returns counters (bytes, losses, seconds)."""
    clock = time.monotonic
    start = clock()
    last_flush = start
    total = 0
    losses = 0
    should_stop = stop or (lambda: False)
    while not should_stop():
        now = clock()
        timeout = READ_TIMEOUT_S
        if seconds is not None:
            left = start + seconds - now
            if left <= 0:
                break
            timeout = min(timeout, left)
        item = reader.read(timeout)
        if isinstance(item, bytes):
            out.write(item)
            total += len(item)
        elif isinstance(item, DeviceLost):
            losses += 1
            note(f"device lost ({item.reason}); reconnecting to {reader.url}")
        elif isinstance(item, DeviceBack):
            note(f"device back: {reader.url}")
        if clock() - last_flush >= FLUSH_INTERVAL_S:
            out.flush()
            last_flush = clock()
    # Take what the port still holds: it was sent before we stopped.
    while reader.is_open:
        item = reader.read(0)
        if not isinstance(item, bytes):
            break
        out.write(item)
        total += len(item)
    return {"bytes": total, "losses": losses, "seconds": clock() - start}


def main(args: argparse.Namespace) -> int:
    """``hdrd record --port URL --out FILE [--seconds S]``."""
    seconds = args.seconds
    if seconds is not None and not (seconds > 0 and math.isfinite(seconds)):
        _note(f"--seconds must be a number > 0, got {seconds}")
        return 2
    try:
        reader = SerialReader(args.port, baud=args.baud)
    except ValueError as e:
        _note(str(e))
        return 2
    try:
        out = open(args.out, "wb")  # noqa: SIM115 - closed in finally, after fsync
    except OSError as e:
        reader.close()
        _note(f"cannot write {args.out}: {e.strerror or e}")
        return 1

    stopping = False

    def on_signal(signum: int, frame: object) -> None:
        nonlocal stopping
        stopping = True

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    result: dict[str, float] = {}
    try:
        result = record(reader, out, seconds, stop=lambda: stopping)
    finally:
        try:
            out.flush()
            os.fsync(out.fileno())
        finally:
            out.close()
            reader.close()
            for s, h in old.items():
                signal.signal(s, h)
    _note(
        f"{int(result.get('bytes', 0))} bytes in {result.get('seconds', 0.0):.1f} s to {args.out}"
        + (f", {int(result['losses'])} device losses" if result.get("losses") else "")
    )
    return 0
