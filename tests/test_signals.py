"""hdrd.daemon.signals: handlers that only set flags, SIGHUP held from the entry point until the
daemon's handlers take it over, and signals a parent left blocked. Real signals sent to this
thread (pthread_kill), each test restoring the handlers and the signal mask it found.

The same as processes (a SIGHUP during start-up, at the first import, blocked by the parent):
test_daemon_startup.py.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator

import pytest

from hdrd.daemon.signals import (
    Signals,
    command_of,
    hold_hangup,
    hold_hangup_for,
    take_held_hangup,
)

SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)


def send(sig: int) -> None:
    """``sig`` to this thread (the main thread, where Python runs handlers): a signal sent to
    the process while this thread blocks it could go to another thread of the test run that
    does not, and end the run. Its handler has run when this returns."""
    signal.pthread_kill(threading.get_ident(), sig)


@pytest.fixture(autouse=True)
def restore_signal_state() -> Iterator[None]:
    """The handlers and mask of SIGTERM, SIGINT and SIGHUP as they were, after each test."""
    handlers = {s: signal.getsignal(s) for s in SIGNALS}
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    take_held_hangup()
    yield
    signal.pthread_sigmask(signal.SIG_SETMASK, mask)
    for s, h in handlers.items():
        signal.signal(s, h)
    take_held_hangup()


def test_command_of_is_the_first_word_that_is_not_an_option() -> None:
    assert command_of(["run", "--config", "x.yaml"]) == "run"
    assert command_of(["-v", "calibrate"]) == "calibrate"
    assert command_of(["--help"]) is None
    assert command_of([]) is None


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_term_and_int_ask_to_stop(sig: int) -> None:
    s = Signals()
    s.install()
    assert not s.stop and not s.reload
    send(sig)
    assert s.stop and not s.reload


def test_hup_asks_to_reload_and_not_to_stop() -> None:
    s = Signals()
    s.install()
    send(signal.SIGHUP)
    assert s.reload and not s.stop


def test_restore_puts_back_the_handlers_it_found() -> None:
    before = {sig: signal.getsignal(sig) for sig in SIGNALS}
    s = Signals()
    s.install()
    assert all(signal.getsignal(sig) != before[sig] for sig in SIGNALS)
    s.restore()
    assert {sig: signal.getsignal(sig) for sig in SIGNALS} == before
    s.restore()  # twice: nothing more to do
    assert {sig: signal.getsignal(sig) for sig in SIGNALS} == before


def test_install_is_idempotent_and_keeps_the_first_saved_handlers() -> None:
    before = signal.getsignal(signal.SIGTERM)
    s = Signals()
    s.install()
    s.install()  # a second install must not save its own handler as "the old one"
    s.restore()
    assert signal.getsignal(signal.SIGTERM) == before


def test_a_hangup_while_held_does_not_end_the_process_and_becomes_a_reload() -> None:
    hold_hangup()
    send(signal.SIGHUP)  # default action: the end of the process
    s = Signals()
    s.install()
    assert s.reload and not s.stop


def test_take_held_hangup_forgets_it() -> None:
    hold_hangup()
    assert not take_held_hangup()
    send(signal.SIGHUP)
    send(signal.SIGHUP)
    assert take_held_hangup()
    assert not take_held_hangup()
    s = Signals()
    s.install()
    assert not s.reload  # taken already: not a second reload


def test_hold_hangup_for_holds_only_for_run() -> None:
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    hold_hangup_for(["calibrate", "--seconds", "5"])
    assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN
    hold_hangup_for(["run", "--config", "x.yaml"])
    send(signal.SIGHUP)
    assert take_held_hangup()


def test_a_hangup_the_parent_blocked_is_a_reload_once_installed() -> None:
    """A parent that starts the daemon with SIGHUP blocked (the mask survives exec): the
    signal waits, pending, and is delivered when install unblocks it."""
    signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    send(signal.SIGHUP)
    assert signal.SIGHUP in signal.sigpending()
    s = Signals()
    s.install()
    assert s.reload and not s.stop
    assert not (set(SIGNALS) & signal.pthread_sigmask(signal.SIG_BLOCK, []))


def test_a_term_the_parent_blocked_is_a_stop_once_installed() -> None:
    signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGTERM])
    send(signal.SIGTERM)
    s = Signals()
    s.install()
    assert s.stop and not s.reload


def test_hold_hangup_unblocks_and_holds_a_pending_one() -> None:
    signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGHUP])
    send(signal.SIGHUP)
    hold_hangup()
    assert signal.SIGHUP not in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    assert take_held_hangup()
