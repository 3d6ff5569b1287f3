"""One rate limit for every event said at most so often (a log warning, a stale report).

A fault that lasts (a divider open, a flood of bad lines, a stalled reader) happens on every
sample, fix or turn of the loop; its log line must not. Pure: the caller passes the time, on
whatever monotonic clock it keeps (s).
"""

from __future__ import annotations

import math

__all__ = ["Throttle"]


class Throttle:
    """Says yes at most once per ``interval_s`` (s), and counts what a growing counter added
    since it last said yes."""

    def __init__(self, interval_s: float, last: float = -math.inf) -> None:
        self.interval_s = interval_s
        self.last = last
        """When it last said yes (s; -inf: never)."""
        self.said = 0
        """The counter's total when :meth:`count` last said yes."""

    def due(self, now: float) -> bool:
        """True (and ``now`` remembered) when ``interval_s`` has passed since the last yes."""
        if now - self.last < self.interval_s:
            return False
        self.last = now
        return True

    def count(self, total: int, now: float) -> int:
        """How much a counter at ``total`` grew since it was last said, when that is more than
        nothing and the interval has passed (then remembered as said); 0 otherwise."""
        if total <= self.said or not self.due(now):
            return 0
        new, self.said = total - self.said, total
        return new

    def restart(self) -> None:
        """The counter started again from zero (its owner was rebuilt)."""
        self.said = 0
