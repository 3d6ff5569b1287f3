"""Signals of the long-running commands: handlers only set flags, the loops act on them.

SIGTERM and SIGINT ask to stop; SIGHUP asks ``hdrd run`` to reload its configuration. SIGHUP's
default action would end the process, so ``hdrd run`` holds it from its first statement on
(:func:`hold_hangup_for`, called by ``hdrd``'s entry point before anything is imported)
until the daemon installs its handlers (:meth:`Signals.install`), which take a held one as a
reload request. Before that first statement, while the Python interpreter itself starts, no
handler can exist: a sender that must not kill a starting daemon starts it with SIGHUP
blocked (the mask passes through ``exec``), and hdrd unblocks SIGHUP, SIGTERM and SIGINT once
its handlers are in place, taking the one that waited as a reload. ``systemctl reload`` waits
for READY=1 anyway. Light: the entry point imports it first.
"""

from __future__ import annotations

import signal
from types import FrameType
from typing import Any

__all__ = ["Signals", "command_of", "hold_hangup", "hold_hangup_for", "take_held_hangup"]


_held_hangups: list[int] = []


def _hold_hangup(signum: int, frame: FrameType | None) -> None:
    _held_hangups.append(signum)


def _unblock(*sigs: int) -> None:
    """Unblock ``sigs`` (a parent may have started us with them blocked); one that came
    while blocked is delivered now, to the handler in place."""
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, set(sigs))


def hold_hangup() -> None:
    """Hold SIGHUP from now on (remember it instead of ending the process) until
    :meth:`Signals.install` takes it over; a SIGHUP the parent left blocked and pending is
    held too."""
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, _hold_hangup)
        _unblock(signal.SIGHUP)


def command_of(argv: list[str]) -> str | None:
    """The subcommand of an ``hdrd`` command line (its first word that is not an option),
    read without the argument parser."""
    return next((a for a in argv if not a.startswith("-")), None)


def hold_hangup_for(argv: list[str]) -> None:
    """:func:`hold_hangup` if ``argv`` (without the program name) is an ``hdrd run``.
    The entry point's first statement."""
    if command_of(argv) == "run":
        hold_hangup()


def take_held_hangup() -> bool:
    """True if a SIGHUP came while held (:func:`hold_hangup`); forgets it."""
    held = bool(_held_hangups)
    _held_hangups.clear()
    return held


class Signals:
    """Signal handlers only set flags; the loop acts on them."""

    def __init__(self) -> None:
        self.stop = False
        self.reload = False
        self._old: dict[int, Any] = {}

    def install(self) -> None:
        """Take over SIGTERM, SIGINT and SIGHUP (idempotent) and unblock them. A SIGHUP that
        came while it was held (:func:`hold_hangup`, from the entry point until now) or
        blocked (by the parent, through ``exec``) is a reload to do."""
        if self._old:
            return
        for sig, handler in (
            (signal.SIGTERM, self._on_stop),
            (signal.SIGINT, self._on_stop),
            (signal.SIGHUP, self._on_hup),
        ):
            self._old[sig] = signal.signal(sig, handler)
        if take_held_hangup():
            self.reload = True
        _unblock(signal.SIGTERM, signal.SIGINT, signal.SIGHUP)  # one that waited: now

    def restore(self) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()

    def _on_stop(self, signum: int, frame: FrameType | None) -> None:
        self.stop = True

    def _on_hup(self, signum: int, frame: FrameType | None) -> None:
        self.reload = True
