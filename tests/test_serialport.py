"""hdrd.io.wire.serialport: the raw serial link that reopens itself, on real ptys (a link in a
temporary folder standing for /dev/serial/by-id/...), real TCP sockets on 127.0.0.1
(``socket://``) and pyserial's ``loop://``; backoff on a manual clock.

Frames on top of it (parsing, a held frame at an unplug, the fake gyro's cable pulls):
test_sources.py; ``hdrd record`` on it: test_record.py; the daemon on a ``socket://`` port
whose listener never answers: test_daemon_startup.py.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hdrd.io.wire.clocks import ManualClock
from hdrd.io.wire.serialport import DeviceBack, DeviceLost, SerialReader
from hdrd.sim.profiles import builtin_profile

WAIT_S = 20.0  # upper bound for anything that should happen "soon" (never a timing assertion)


class Pty:
    """A real pty whose slave side is reached through a symlink ``path``, as a USB adapter
    is through /dev/serial/by-id; ``unplug`` removes the link and closes the master."""

    def __init__(self, path: Path) -> None:
        self.master, slave = os.openpty()
        self.path = path
        path.symlink_to(os.ttyname(slave))
        os.close(slave)

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    def unplug(self) -> None:
        if self.master >= 0:
            self.path.unlink()
            os.close(self.master)
            self.master = -1


@pytest.fixture
def pty(tmp_path: Path) -> Iterator[Pty]:
    p = Pty(tmp_path / "gyro")
    yield p
    p.unplug()


def read_until(
    reader: SerialReader, want: int, timeout_s: float = WAIT_S
) -> tuple[bytes, list[object]]:
    """Read until ``want`` bytes came (or the bound passes); bytes and the events seen."""
    data = b""
    events: list[object] = []
    end = time.monotonic() + timeout_s
    while len(data) < want and time.monotonic() < end:
        item = reader.read(0.1)
        if isinstance(item, bytes):
            data += item
        elif item is not None:
            events.append(item)
    return data, events


def next_event(reader: SerialReader) -> object:
    """The first thing other than None that ``read`` gives (bounded)."""
    end = time.monotonic() + WAIT_S
    while time.monotonic() < end:
        item = reader.read(0.05)
        if item is not None:
            return item
    raise AssertionError("nothing came")


# -- a pty ---------------------------------------------------------------------------------


def test_bytes_come_as_written_and_silence_is_none(pty: Pty) -> None:
    payload = bytes(range(256)) * 40  # any byte value, more than one read's worth of a tty
    with SerialReader(str(pty.path)) as r:
        assert r.is_open and r.opened_once and r.read(0) is None
        pty.write(payload)
        got, events = read_until(r, len(payload))
        assert got == payload and events == []
        assert r.stats.bytes_read == len(payload)
        assert r.read(0.05) is None  # a silent device is not a lost one
        assert r.stats.lost == 0


def test_an_unplug_is_lost_once_then_quiet_and_a_replug_is_back(pty: Pty) -> None:
    with SerialReader(str(pty.path), reconnect_min_s=0.02, reconnect_max_s=0.05) as r:
        pty.write(b"abc")
        assert read_until(r, 3)[0] == b"abc"
        pty.unplug()
        lost = next_event(r)
        assert isinstance(lost, DeviceLost) and lost.reason
        assert not r.is_open and r.stats.lost == 1
        for _ in range(5):  # gone for good: it keeps trying, never raises, reports nothing new
            assert r.read(0.02) is None
        assert r.stats.open_failures >= 1 and r.last_error == f"{pty.path} does not exist"
        again = Pty(pty.path)  # plugged in again (another pty behind the same link)
        try:
            assert isinstance(next_event(r), DeviceBack)
            assert r.stats.reconnects == 1 and r.is_open
            again.write(b"xyz")
            assert read_until(r, 3) == (b"xyz", [])
        finally:
            again.unplug()


def test_a_device_missing_at_start_is_said_plainly_then_found(tmp_path: Path) -> None:
    link = tmp_path / "gyro"
    with SerialReader(str(link), reconnect_min_s=0.02, reconnect_max_s=0.05) as r:
        assert not r.is_open and not r.opened_once and not r.busy
        lost = r.read(0)
        assert isinstance(lost, DeviceLost) and lost.reason == f"{link} does not exist"
        assert r.read(0.05) is None
        p = Pty(link)
        try:
            assert isinstance(next_event(r), DeviceBack) and r.opened_once
        finally:
            p.unplug()


def test_a_local_port_takes_the_direct_read_path_and_url_handlers_do_not(pty: Pty) -> None:
    with SerialReader(str(pty.path)) as r:
        assert r._fd_poll is not None  # one poll and one os.read per wake-up
    with SerialReader("loop://") as r:
        assert r._fd_poll is None  # pyserial's own read (loop://, socket://, spy://)


def test_the_port_is_opened_exclusively(fake_gyro) -> None:
    # A second opener of the same device (hdrd calibrate on the running daemon's port) gets
    # a clear "in use" instead of half the frames; once the first closes, the port is free.
    g = fake_gyro(builtin_profile("standstill", minutes=1), speedup=0)
    first = SerialReader(g.path)
    assert first.is_open and not first.busy
    second = SerialReader(g.path, reconnect_min_s=0.01, reconnect_max_s=0.02)
    assert not second.is_open and second.busy
    assert second.last_error == (
        f"{g.path} is in use by another program (another hdrd run, calibrate or record?)"
    )
    lost = second.read(0)
    assert isinstance(lost, DeviceLost) and "in use by another program" in lost.reason
    first.close()
    deadline = time.monotonic() + 10
    while not isinstance(second.read(0.05), DeviceBack):
        assert time.monotonic() < deadline
    assert second.is_open and not second.busy
    second.close()


# -- loop:// and the reader itself ---------------------------------------------------------


def test_loop_url_gives_back_what_is_written() -> None:
    with SerialReader("loop://") as r:
        r.port.write(b"\xa5\x5a hello")
        assert read_until(r, 8) == (b"\xa5\x5a hello", [])
        assert r.read(0.01) is None


def test_closed_reader_reads_nothing_and_closes_once_more() -> None:
    r = SerialReader("loop://")
    r.port.write(b"left over")
    r.close()
    assert r.read(0) is None and not r.is_open
    r.close()


@pytest.mark.parametrize(("lo", "hi"), [(0.0, 1.0), (-1.0, 1.0), (2.0, 1.0)])
def test_backoff_limits_are_checked(lo: float, hi: float) -> None:
    with pytest.raises(ValueError, match="reconnect_min_s"):
        SerialReader("loop://", reconnect_min_s=lo, reconnect_max_s=hi)


def test_an_unknown_scheme_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="unusable serial port URL 'nosuchscheme://x'"):
        SerialReader("nosuchscheme://x")


def test_retries_back_off_exponentially_within_read_timeouts(tmp_path: Path) -> None:
    """On a manual clock: attempts at 0, 1, 3, 7, 11, 15 s (the wait doubling from 1 s up to
    4 s), each read waiting no longer than it is asked to."""
    clock = ManualClock()
    r = SerialReader(str(tmp_path / "none"), reconnect_min_s=1.0, reconnect_max_s=4.0, clock=clock)
    assert isinstance(r.read(0), DeviceLost) and r.stats.open_failures == 1
    failed_at = {1: 0.0}  # open failures so far -> when the last one was
    while clock.now < 16.0:
        before = clock.now
        assert r.read(0.25) is None
        assert clock.now - before <= 0.25 + 1e-9
        failed_at.setdefault(r.stats.open_failures, clock.now)  # (tried as a read ends)
    assert failed_at == {1: 0.0, 2: 1.0, 3: 3.0, 4: 7.0, 5: 11.0, 6: 15.0}
    assert max(clock.slept) <= 0.25
    r.close()


# -- socket:// -------------------------------------------------------------------------------


@pytest.fixture
def listener() -> Iterator[socket.socket]:
    srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    srv.settimeout(WAIT_S)
    yield srv
    srv.close()


def test_a_socket_port_reads_what_the_peer_sends_and_loses_it_when_it_hangs_up(
    listener: socket.socket,
) -> None:
    port = listener.getsockname()[1]
    with SerialReader(f"socket://127.0.0.1:{port}", reconnect_min_s=0.02) as r:
        assert r.is_open  # a listener on this host answers within the first second
        assert r.port.port == f"socket://127.0.0.1:{port}"
        peer, _ = listener.accept()
        with peer:
            peer.sendall(b"$HDRG,1,2,3*00\r\n")
            got, _ = read_until(r, 16)
            assert got == b"$HDRG,1,2,3*00\r\n"
        lost = next_event(r)  # the peer closed
        assert isinstance(lost, DeviceLost)
        assert not r.is_open


def test_a_refused_socket_port_is_a_lost_device_with_the_reason(
    listener: socket.socket,
) -> None:
    port = listener.getsockname()[1]
    listener.close()  # nothing listens there now: the connection is refused
    with SerialReader(f"socket://127.0.0.1:{port}", reconnect_min_s=0.02) as r:
        lost = r.read(0)
        assert isinstance(lost, DeviceLost) and not r.is_open
        assert lost.reason == f"could not connect to socket://127.0.0.1:{port}: Connection refused"
        assert r.stats.open_failures >= 1
