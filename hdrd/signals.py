"""Signals of the long-running commands: handlers only set flags, the loops act on them.

SIGTERM and SIGINT ask to stop; SIGHUP asks ``hdrd run`` to reload its configuration. SIGHUP's
default action would end the process, so it is held from argument parsing on
(:func:`hold_hangup`) until the daemon installs its handlers (:meth:`Signals.install`), which
take a held one as a reload request. Light: the command line imports it.
"""

from __future__ import annotations

import signal
from types import FrameType
from typing import Any

__all__ = ["Signals", "hold_hangup", "take_held_hangup"]


_held_hangups: list[int] = []


def _hold_hangup(signum: int, frame: FrameType | None) -> None:
    _held_hangups.append(signum)


def hold_hangup() -> None:
    """Hold SIGHUP from now on (remember it instead of ending the process) until
    :meth:`Signals.install` takes it over. ``hdrd run`` calls it first thing, before the slow
    imports and the configuration."""
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, _hold_hangup)


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
        """Take over SIGTERM, SIGINT and SIGHUP (idempotent). A SIGHUP that came while it was
        held (:func:`hold_hangup`, from argument parsing until now) is a reload to do."""
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

    def restore(self) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()

    def _on_stop(self, signum: int, frame: FrameType | None) -> None:
        self.stop = True

    def _on_hup(self, signum: int, frame: FrameType | None) -> None:
        self.reload = True
