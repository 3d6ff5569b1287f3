"""systemd notification (sd_notify(3) over ``$NOTIFY_SOCKET``) and when the run loop may feed
the watchdog. Outside systemd, silent no-ops.

:class:`SdNotifier` sends READY=1, STATUS=..., WATCHDOG=1 and STOPPING=1 without ever blocking
(a notification that cannot go at once is dropped); :class:`WatchdogGate` decides, from the
loop's progress and the time passed in, when a WATCHDOG=1 is due (docs/operations.md).
"""

from __future__ import annotations

import math
import os
import socket

__all__ = ["SdNotifier", "WatchdogGate"]


class SdNotifier:
    """sd_notify(3) over $NOTIFY_SOCKET (path or @abstract); silent no-op outside systemd."""

    def __init__(self, env: dict[str, str] | None = None) -> None:
        env = dict(os.environ) if env is None else env
        self._addr: str | bytes | None = None
        self._sock: socket.socket | None = None
        addr = env.get("NOTIFY_SOCKET", "")
        if addr:
            self._addr = "\0" + addr[1:] if addr.startswith("@") else addr
            try:
                # Non-blocking: a notification that cannot go at once is dropped (and the
                # next one tried), never a reason to hold up the loop.
                self._sock = socket.socket(
                    socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC | socket.SOCK_NONBLOCK
                )
            except OSError:
                self._sock = None
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        self.watchdog_s: float | None = None
        if usec.isdigit() and int(usec) > 0 and (not pid or pid == str(os.getpid())):
            self.watchdog_s = int(usec) / 1e6 / 2  # ping at half of WatchdogSec
        self.sent: int = 0

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, text: str) -> None:
        if self._sock is None or self._addr is None:
            return
        try:
            self._sock.sendto(text.encode("utf-8", "replace"), self._addr)
            self.sent += 1
        except OSError:
            pass  # systemd gone or socket full: never a reason to stop publishing

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


class WatchdogGate:
    """When the run loop may tell systemd ``WATCHDOG=1``. Pure: the caller passes the time.

    A ping says "the loop is doing its job", so it is sent (at most every *interval_s*, half
    of WatchdogSec) only if, since the previous ping, the loop has made **progress**
    (:meth:`progress`): it published a message (a step, or a stale report on time while no
    usable data comes: the device silent, or its frames dropped as not new or with a clock that
    disagrees), or it found the source with nothing to hand out (everything that arrived is
    handled: the state while the device is unplugged, before it first appears, or when it
    sends only garbage or frames that are dropped). A loop that turns without either (a flood of other work keeps it
    from the frames that are waiting, so steps come late or never) stops pinging, and
    systemd restarts the daemon after WatchdogSec. Steps come every T, so WatchdogSec must
    be longer than T; at least 2 T leaves room (docs/operations.md).
    """

    __slots__ = ("_next", "_progress", "interval_s")

    def __init__(self, interval_s: float | None) -> None:
        self.interval_s = interval_s
        self._next = -math.inf
        self._progress = False

    def progress(self) -> None:
        """A message was published, or the source was idle."""
        self._progress = True

    def due(self, now: float) -> bool:
        """True when a ping should go now (and then it counts as sent)."""
        if self.interval_s is None or now < self._next or not self._progress:
            return False
        self._progress = False
        self._next = now + self.interval_s
        return True
