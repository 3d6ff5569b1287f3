"""hdrd.daemon.sdnotify: sd_notify(3) over a real AF_UNIX datagram socket where systemd would
listen (a path, or an @abstract name), silent outside systemd; and the rule that decides when
the run loop feeds the watchdog (pure, the time passed in).

The daemon's notifications as a process (READY=1, STATUS=, WATCHDOG=1, STOPPING=1 from
``hdrd run``) are in test_daemon.py and test_run_stress.py.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from hdrd.daemon.sdnotify import SdNotifier, WatchdogGate


@pytest.fixture
def listener(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A datagram socket bound where systemd's NOTIFY_SOCKET would be, and its path."""
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(5.0)
    yield sock, path
    sock.close()


def test_notifications_arrive_as_sent(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    n = SdNotifier({"NOTIFY_SOCKET": path})
    try:
        assert n.enabled and n.watchdog_s is None
        for text in ("READY=1", "STATUS=heading 12.5 deg, 3 steps", "WATCHDOG=1", "STOPPING=1"):
            n.notify(text)
            assert sock.recv(4096).decode() == text
        assert n.sent == 4
    finally:
        n.close()


def test_an_abstract_socket_name_is_reached(tmp_path: Path) -> None:
    """``@name`` is Linux's abstract namespace: a leading NUL byte instead of the ``@``."""
    name = f"hdrd-test-{os.getpid()}-{tmp_path.name}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind("\0" + name)
        sock.settimeout(5.0)
        n = SdNotifier({"NOTIFY_SOCKET": "@" + name})
        try:
            n.notify("READY=1")
            assert sock.recv(64) == b"READY=1"
        finally:
            n.close()


def test_outside_systemd_everything_is_a_silent_no_op() -> None:
    n = SdNotifier({})
    assert not n.enabled and n.watchdog_s is None
    n.notify("READY=1")
    assert n.sent == 0
    n.close()
    n.close()


def test_a_socket_that_is_gone_is_no_reason_to_stop(tmp_path: Path) -> None:
    n = SdNotifier({"NOTIFY_SOCKET": str(tmp_path / "nobody-listens.sock")})
    try:
        assert n.enabled
        n.notify("WATCHDOG=1")  # ENOENT / ECONNREFUSED: dropped
        assert n.sent == 0
    finally:
        n.close()
    n.notify("WATCHDOG=1")  # closed: a no-op
    assert n.sent == 0


def test_a_full_socket_drops_notifications_without_blocking(
    listener: tuple[socket.socket, str],
) -> None:
    """systemd that reads nothing: the sender never blocks; the ones that could not go are
    not counted, and the first that went is intact."""
    sock, path = listener
    n = SdNotifier({"NOTIFY_SOCKET": path})
    try:
        tries = 20_000  # far more datagrams than a receive queue holds
        for i in range(tries):
            n.notify(f"STATUS={i}")
        assert 0 < n.sent < tries
        assert sock.recv(64) == b"STATUS=0"
    finally:
        n.close()


@pytest.mark.parametrize(
    ("env", "expected_s"),
    [
        ({"WATCHDOG_USEC": "4000000"}, 2.0),  # ping at half of WatchdogSec
        ({"WATCHDOG_USEC": "400000", "WATCHDOG_PID": str(os.getpid())}, 0.2),
        ({"WATCHDOG_USEC": "4000000", "WATCHDOG_PID": "1"}, None),  # meant for another process
        ({"WATCHDOG_USEC": "0"}, None),
        ({"WATCHDOG_USEC": "-5"}, None),
        ({"WATCHDOG_USEC": "soon"}, None),
        ({}, None),
    ],
)
def test_the_watchdog_interval_is_half_of_watchdog_usec(
    env: dict[str, str], expected_s: float | None
) -> None:
    n = SdNotifier(env)
    assert n.watchdog_s == (None if expected_s is None else pytest.approx(expected_s))
    n.close()


# -- the watchdog rule ---------------------------------------------------------------------


def test_watchdog_gate_pings_only_after_progress() -> None:
    gate = WatchdogGate(5.0)
    assert not gate.due(0.0)  # no progress yet
    gate.progress()
    assert gate.due(0.1)
    gate.progress()
    assert not gate.due(1.0)  # at most every interval
    assert gate.due(5.1)
    # a loop that turns without publishing or idling: no ping, however long
    assert not any(gate.due(t) for t in (10.0, 20.0, 100.0))
    gate.progress()  # ... until it catches up: at once
    assert gate.due(100.5)


def test_watchdog_gate_off_outside_systemd() -> None:
    gate = WatchdogGate(None)
    gate.progress()
    assert not gate.due(1e9)


def test_a_starved_loop_stops_feeding_the_watchdog() -> None:
    """The run loop's rule over a scripted run: steps every second, then a loop starved for
    30 s (no step, never idle), then the device gone (idle turns, stale reports)."""
    gate = WatchdogGate(2.5)  # WatchdogSec=5
    pings: list[float] = []
    t = 0.0
    while t < 90.0:
        healthy = t < 20.0 or t >= 50.0
        if healthy and abs(t - round(t)) < 1e-9:
            gate.progress()  # a step (or, after 50 s, a stale report / an idle recv)
        if gate.due(t):
            pings.append(t)
        t = round(t + 0.1, 1)
    gaps = [b - a for a, b in zip(pings, pings[1:])]
    assert max(g for a, g in zip(pings, gaps) if a < 17.0) <= 3.0  # fed while stepping
    assert not [p for p in pings if 22.6 <= p < 50.0]  # starved: none after the last step
    assert pings[-1] > 85.0  # fed again once it catches up
