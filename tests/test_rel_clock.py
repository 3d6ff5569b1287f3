# ruff: noqa: F811 - the fixtures hdrd and receivers come from test_rel_daemon by import
"""`hdrd run` fed frames that keep coming but are stale: the last frame repeated, the sequence
advancing with a frozen clock, a device clock 100x slow or 100x fast, random frames that pass
the CRC, and a device clock that jumped before a reconnection.

A real daemon process reads a real pty written here at a fixed host rate, 10 frames a second,
whatever the frames' own clock says (a broken clock is the point); steps go to a real UDP
socket and sd_notify to a NOTIFY_SOCKET. What must hold (docs/protocol.md, "Sequence and
clock"; docs/operations.md, "Stale data"): no step is made of those frames, the daemon says
"stale" (its messages, systemd's STATUS) while they come, the watchdog keeps being fed by the
stale reports, the frames are counted by reason in the ``stop`` event, and steps resume, their
numbers moving on by the host's clock, when good frames come back.

The module-level tests: test_tracker.py (FrameTracker), test_clocks.py (WallClockCheck).
No timings are asserted: waits are upper bounds that only a hung daemon reaches.
"""

from __future__ import annotations

import os
import random
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from hdrd.io.wire.codec import Frame, encode_bin
from tests.test_rel_daemon import (  # noqa: F401 - hdrd and receivers are fixtures
    WAIT,
    Receiver,
    hdrd,
    receivers,
    run_args,
    wait_port_open,
)

HZ = 10
STEP_US = 100_000
ZERO = 32768  # counts at 0 deg/s


class PacedPty:
    """A device on a pty, reached through a symlink, that writes frames at ``HZ`` frames a
    second of host time. :meth:`pull` closes it (the reader sees EIO) and removes the link;
    :meth:`plug` opens a new pty behind the link."""

    def __init__(self, link: Path) -> None:
        self.link = link
        self.master = self.slave = -1
        self.plug()

    def plug(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        tmp = self.link.with_suffix(".new")
        tmp.symlink_to(os.ttyname(self.slave))
        tmp.replace(self.link)

    def send(self, frames: list[Frame] | list[bytes]) -> None:
        for f in frames:
            os.write(self.master, f if isinstance(f, bytes) else encode_bin(f))
            time.sleep(1.0 / HZ)

    def pull(self) -> None:
        self.link.unlink()
        os.close(self.master)
        os.close(self.slave)
        self.master = self.slave = -1

    def close(self) -> None:
        if self.master >= 0:
            self.pull()


@pytest.fixture
def device(tmp_path: Path) -> Iterator[PacedPty]:
    d = PacedPty(tmp_path / "gyro")
    yield d
    d.close()


class Stream:
    """A healthy 10 Hz device at 0 deg/s: its sequence number and clock, and what it sends."""

    def __init__(self, seq: int = 1000, t_us: int = 5_000_000) -> None:
        self.seq, self.t = seq, t_us

    def healthy(self, n: int) -> list[Frame]:
        out = []
        for _ in range(n):
            self.seq, self.t = (self.seq + 1) & 0xFFFF, (self.t + STEP_US) % 2**32
            out.append(Frame(self.seq, self.t, ZERO, 0, 2500))
        return out

    def skip(self, n: int) -> None:
        """``n`` frames' time passes on the device without them (its clock runs on)."""
        self.seq, self.t = (self.seq + n) & 0xFFFF, (self.t + n * STEP_US) % 2**32


def start(
    make_proc: Callable[..., Any],
    make_rx: Callable[..., Any],
    tmp_path: Path,
    device: PacedPty,
) -> tuple[Any, Any, Any]:
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text(
        "device:\n  stale_after_s: 0.5\n  reconnect_min_s: 0.1\n  reconnect_max_s: 0.2\n"
    )
    notify = make_rx(tmp_path / "notify.sock")
    rx = make_rx()
    d = make_proc(
        *run_args(
            "--config", str(cfg), "--port", str(device.link), "--bias", "0", "--udp", rx.addr
        ),
        env={"NOTIFY_SOCKET": str(tmp_path / "notify.sock"), "WATCHDOG_USEC": "1000000"},
    )
    wait_port_open(d, device.link)
    return d, rx, notify


def steps(ms: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [m for m in ms if m["status"] != "stale"]


def bad_phase(stream: Stream, kind: str, n: int) -> list[Frame] | list[bytes]:
    """``n`` frames (10 a second of host time) of one way of being stale."""
    if kind == "repeat":  # the last frame again and again
        return [Frame(stream.seq, stream.t, ZERO, 0, 2500)] * n
    if kind == "frozen":  # the sequence advances, the clock does not
        out = []
        for _ in range(n):
            stream.seq = (stream.seq + 1) & 0xFFFF
            out.append(Frame(stream.seq, stream.t, ZERO + 3000, 0, 2500))  # turning, if taken
        return out
    factor = {"slow": 0.01, "fast": 100.0}[kind]
    out = []
    for _ in range(n):
        stream.seq = (stream.seq + 1) & 0xFFFF
        stream.t = (stream.t + int(STEP_US * factor)) % 2**32
        out.append(Frame(stream.seq, stream.t, ZERO + 3000, 0, 2500))
    return out


def check_stale_then_resumed(
    d: Any, rx: Receiver, notify: Receiver, device: PacedPty, kind: str, counter: str
) -> None:
    """Good frames, 3 s of bad ones (the daemon reports stale meanwhile), good frames again."""
    stream = Stream()
    device.send(stream.healthy(35))  # 3.5 s: steps
    n_before = len(rx.wait(lambda ms: len(steps(ms)) >= 2, what="steps from good frames"))
    seq, t = stream.seq, stream.t
    bad = bad_phase(stream, kind, 30)
    device.send(bad)
    during = rx.wait(
        lambda ms: sum(m["status"] == "stale" for m in ms[n_before:]) >= 2,
        what="stale reports while the bad frames come",
    )[n_before:]
    assert all(m["status"] == "stale" for m in during[1:]), during  # no step of them
    seen = notify.wait(
        lambda xs: any(x.startswith("STATUS=stale") and "frames dropped" in x for x in xs),
        what="STATUS says stale, frames dropped",
    )
    status = [x for x in seen if x.startswith("STATUS=stale") and "frames dropped" in x]
    assert counter in status[-1], status[-1]
    # the watchdog is fed by the stale reports, on time: the loop does its job
    notify.wait(lambda xs: "WATCHDOG=1" in xs[xs.index(status[0]) :], what="WATCHDOG=1")
    stream.seq, stream.t = seq, t
    stream.skip(len(bad))  # the device's own clock ran on meanwhile
    device.send(stream.healthy(35))
    after = rx.wait(lambda ms: len(steps(ms[n_before + len(during) :])) >= 2, what="steps again")
    all_steps = steps(after)
    nums = [m["step"] for m in all_steps]
    assert nums == sorted(set(nums))  # forward only
    for m in all_steps:  # no step was made of the bad frames (0 deg/s was all it was sent)
        assert abs(m["omega"]) < 0.5 and m["status"] in ("ok", "turning", "standstill"), m
    assert max(m.get("gap_s", 0.0) for m in all_steps) < 10.0  # the phase lasted 3 s
    assert d.stop() == 0 and not d.traceback
    (stop,) = d.named("stop")
    assert stop["frames_dropped"][counter] > 0, stop


@pytest.mark.slow
@pytest.mark.parametrize(
    "kind, counter",
    [
        ("repeat", "seq_repeats"),
        ("frozen", "seq_clock_mismatch"),
        ("slow", "seq_clock_mismatch"),
        ("fast", "seq_clock_mismatch"),
    ],
)
def test_frames_that_keep_coming_but_are_not_new_are_stale(
    hdrd, receivers, tmp_path, device, kind, counter
):
    d, rx, notify = start(hdrd, receivers, tmp_path, device)
    check_stale_then_resumed(d, rx, notify, device, kind, counter)


@pytest.mark.slow
def test_a_device_clock_100x_fast_from_the_start_is_never_integrated(
    hdrd, receivers, tmp_path, device
):
    """Consistent with its own sequence numbers, so only the host's clock can tell: after the
    check's tolerance every frame is dropped (wall_clock_mismatch) and the daemon is stale,
    never a step every 0.1 s with gap_s 9."""
    d, rx, notify = start(hdrd, receivers, tmp_path, device)
    fast = [Frame((k + 1) & 0xFFFF, (k * STEP_US * 100) % 2**32, ZERO, 0, 2500) for k in range(120)]
    device.send(fast)
    ms = rx.wait(lambda ms: sum(m["status"] == "stale" for m in ms) >= 3, what="stale reports")
    for m in steps(ms):
        assert m.get("gap_s", 0.0) < 10.0
    # far fewer steps than the 1,200 s of device time sent: the first few seconds at most
    assert len(steps(ms)) < 120
    assert d.stop() == 0 and not d.traceback
    (stop,) = d.named("stop")
    assert stop["frames_dropped"]["wall_clock_mismatch"] > 0
    assert any("--clock-rate" in e.get("hint", "") for e in d.named("frames_dropped"))


def random_valid_frame(rng: random.Random) -> bytes:
    """A frame whose every field is random but whose CRC is right (what random bytes give,
    now and then)."""
    return encode_bin(
        Frame(rng.getrandbits(16), rng.getrandbits(32), rng.choice((0, 65535)), 0, None)
    )


@pytest.mark.slow
def test_random_frames_that_pass_the_crc_make_no_turn_and_no_step_jump_after_a_reconnection(
    hdrd, receivers, tmp_path, device
):
    """Random frames with a valid CRC among good ones used to reset the stale timer, make a
    bogus turn (omega -24.5 deg/s) and, after a reconnection, a step number jump 18 -> 387
    with gap_s 368 where the real gap was seconds."""
    d, rx, notify = start(hdrd, receivers, tmp_path, device)
    rng = random.Random(5)
    stream = Stream()
    device.send(stream.healthy(30))
    mixed: list[bytes] = []
    for _ in range(40):
        mixed.append(encode_bin(stream.healthy(1)[0]))
        mixed.append(random_valid_frame(rng))
    # and one that jumps the device clock 368 s on, sequence following
    mixed.append(
        encode_bin(Frame((stream.seq + 1) & 0xFFFF, (stream.t + 368_000_000) % 2**32, 0, 0, None))
    )
    device.send(mixed)
    before = rx.snapshot()
    last = steps(before)[-1]
    device.pull()
    d.wait_event("device_lost")
    device.plug()
    d.wait_event("device_back")
    stream.skip(20)  # a couple of seconds out
    device.send(stream.healthy(30))
    ms = rx.wait(lambda ms: len(steps(ms[len(before) :])) >= 3, what="steps after the reconnection")
    all_steps = steps(ms)
    for m in all_steps:
        assert abs(m["omega"]) < 0.5, m  # no turn from the random frames
    nums = [m["step"] for m in all_steps]
    assert nums == sorted(set(nums))
    (back,) = d.named("device_back")
    # Across the reconnection the steps move on by the host's clock (the gap, and the 3 s of
    # frames sent since), not by a device clock that jumped 368 s.
    for m in steps(ms[len(before) :]):
        assert m["step"] - last["step"] <= back["gap_s"] + 3 + 3, (last, m)
        assert m.get("gap_s", 0.0) <= back["gap_s"] + 1, m
    assert d.stop() == 0 and not d.traceback
    (stop,) = d.named("stop")
    assert stop["frames_dropped"]["seq_clock_mismatch"] > 0
