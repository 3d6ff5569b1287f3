"""The raw bytes of the gyro's port copied to a capture file as read, losing nothing
(``hdrd record``, :mod:`hdrd.commands.record`, is its command line).

No parsing, so a capture keeps garbage and bad frames for replay and fault analysis; the
file is flushed every :data:`FLUSH_INTERVAL_S`. A pulled cable is survived: the port is
reopened by :class:`hdrd.io.wire.serialport.SerialReader` (the same reconnect loop as the daemon).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from hdrd.io.wire.serialport import DeviceBack, DeviceLost, SerialReader

__all__ = ["FLUSH_INTERVAL_S", "READ_TIMEOUT_S", "record"]

FLUSH_INTERVAL_S = 1.0
READ_TIMEOUT_S = 0.2
"""Longest a read waits, s: bounds how late a signal or --seconds is noticed."""


def record(
    reader: SerialReader,
    out: Any,
    seconds: float | None = None,
    stop: Any = None,
    note: Callable[[str], None] = lambda message: None,
) -> dict[str, Any]:
    """Copy bytes from ``reader`` to the binary file ``out`` until ``seconds`` have passed
    (None: forever) or ``stop()`` is true; returns counters (bytes, losses, seconds) and,
    if writing failed (the recording then stops), ``error``: the OSError. ``note(text)`` is
    told of a device lost and back."""
    clock = time.monotonic
    start = clock()
    last_flush = start
    total = 0
    losses = 0
    should_stop = stop or (lambda: False)
    try:
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
    except OSError as e:  # the capture file, not the port (the reader never raises)
        return {"bytes": total, "losses": losses, "seconds": clock() - start, "error": e}
    return {"bytes": total, "losses": losses, "seconds": clock() - start}
