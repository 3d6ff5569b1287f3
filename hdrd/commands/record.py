"""``hdrd record``: the raw bytes of the gyro's port to a capture file, losing nothing.

Every byte read is written as read (no parsing, so a capture keeps garbage and bad frames
for replay and fault analysis); the file is flushed every second and fsynced at the end.
A pulled cable is survived: the port is reopened by :class:`hdrd.io.wire.serialport.SerialReader`
(the same reconnect loop as the daemon) and the loss noted on stderr. SIGINT/SIGTERM, or
``--seconds``, end the recording after draining what the port still holds; exit status 0.

Exit 1, with one line saying why, when the port cannot be opened at the start (missing, or
in use by another program: the capture file is then not created), when writing fails (a
full disk: what was written stays), or when not one byte came.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
from typing import Any

from hdrd.io.wire.record import record
from hdrd.io.wire.serialport import SerialReader

__all__ = ["main"]


def _note(msg: str) -> None:
    print(f"hdrd record: {msg}", file=sys.stderr, flush=True)


def _finish(out: Any) -> OSError | None:
    """Flush, fsync and close ``out``; the first error (each step is tried once)."""
    first: OSError | None = None
    for step in (out.flush, lambda: os.fsync(out.fileno())):
        try:
            step()
        except OSError as e:
            first = first or e
            break
    try:
        out.close()
    except OSError as e:  # the buffered bytes that could not be written: dropped
        first = first or e
    return first


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
    if not reader.is_open:  # missing, busy, refused: say so, create no file
        reader.close()
        _note(f"cannot open {args.port}: {reader.last_error}; nothing recorded")
        return 1
    try:
        out = open(args.out, "wb")  # noqa: SIM115 - closed in _finish, after fsync
    except OSError as e:
        reader.close()
        _note(f"cannot write {args.out}: {e.strerror or e}")
        return 1

    result, error, stopping = _record_until_stopped(reader, out, seconds)
    n = int(result.get("bytes", 0))
    if error is not None:
        _note(
            f"cannot write {args.out}: {error.strerror or error}; recording stopped, "
            f"{n} bytes read from {args.port}"
        )
        return 1
    _note(
        f"{n} bytes in {result.get('seconds', 0.0):.1f} s to {args.out}"
        + (f", {int(result['losses'])} device losses" if result.get("losses") else "")
    )
    if n == 0 and not stopping:
        _note(f"nothing came from {args.port}; is the gyro sending?")
        return 1
    return 0


def _record_until_stopped(
    reader: SerialReader, out: Any, seconds: float | None
) -> tuple[dict[str, Any], OSError | None, bool]:
    """:func:`record` until done or SIGINT / SIGTERM (their handlers restored after); the
    file and the reader closed. The result, the first write error, and whether a signal
    stopped it."""
    stopping = False

    def on_signal(signum: int, frame: object) -> None:
        nonlocal stopping
        stopping = True

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    result: dict[str, Any] = {}
    try:
        result = record(reader, out, seconds, stop=lambda: stopping, note=_note)
    finally:
        error = result.get("error") or _finish(out)
        if result.get("error"):
            _finish(out)  # close it; the write error is the one to report
        reader.close()
        for s, h in old.items():
            signal.signal(s, h)
    return result, error, stopping
