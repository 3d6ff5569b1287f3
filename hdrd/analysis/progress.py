"""Progress of a long analysis on stderr (``hdrd tune``, and ``hdrd evaluate`` / ``hdrd gap`` on
a fleet): fed by the work as it finishes, in this process or on a cluster."""

from __future__ import annotations

import sys
import time
from typing import Any

__all__ = ["ProgressBar"]


class ProgressBar:
    """Progress on stderr: on a terminal a one-line bar redrawn in place (``\\r``) at most
    every 0.1 s; anywhere else (a log file, journald, a pipe) one plain line per tenth of
    the work, since a carriage return there only piles up as one endless line."""

    def __init__(self, label: str, stream: Any = None, width: int = 30) -> None:
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.width = width
        self.t0 = time.monotonic()
        self._last = 0.0
        self._drawn = False
        isatty = getattr(self.stream, "isatty", None)
        self.tty = bool(isatty is not None and isatty())
        self._tenths = -1  # off a terminal: the last tenth of the work reported

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        frac = done / total if total else 1.0
        elapsed = now - self.t0
        eta = elapsed / frac - elapsed if frac > 0 else 0.0
        if not self.tty:
            tenths = int(frac * 10 + 1e-9)
            if tenths <= self._tenths:
                return
            self._tenths = tenths
            self.stream.write(
                f"{self.label}: {frac * 100:5.1f}%  {elapsed:5.1f} s, ~{eta:.0f} s left\n"
            )
            self.stream.flush()
            return
        if done < total and now - self._last < 0.1:
            return
        self._last = now
        fill = round(frac * self.width)
        self.stream.write(
            f"\r{self.label} [{'#' * fill}{'.' * (self.width - fill)}] "
            f"{frac * 100:5.1f}%  {elapsed:5.1f} s, ~{eta:4.0f} s left "
        )
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        if self._drawn:
            self.stream.write("\n")
            self.stream.flush()
