"""A fake gyro on a pty: the USB ADC without hardware, for tests and demos (``hdrd fakegyro``,
:mod:`hdrd.commands.fakegyro`, is its command line).

Like gpsd's ``gps/fake.py`` FakePTY: :class:`FakeGyro` opens a pty pair and writes the frames
of a drive profile to the master, so a reader opens the slave (:attr:`FakeGyro.path`, or the
stable symlink :attr:`FakeGyro.link`) exactly as it would open ``/dev/ttyUSB0``. Frames go out
at real time times ``speedup``, or as fast as the reader reads (``speedup`` 0). Either way
the drive starts when a reader first has the port open: a demo started a moment before its
reader sees the drive from its first frame (its standstill lead-in, to calibrate on).

Faults, drawn from a seeded generator so a run is reproducible:

- ``garbage``: probability of 1..32 random bytes before a frame (bytes that cannot start a
  sync pattern, so the parser's counts can be compared exactly);
- ``crc_errors``: probability that a frame goes out with one bit flipped (hdr-bin) or one digit
  changed (hdr-text), so its CRC/checksum fails;
- ``drop``: probability that a frame is not sent (a sequence gap);
- a "cable pull" (``pull_at`` device times, or :meth:`FakeGyro.pull`): the master is closed
  (the reader sees EOF/EIO) and the symlink removed; after ``pull_for`` seconds of wall time a
  NEW pty is opened and the symlink re-pointed to it. The device clock runs on meanwhile:
  the frames of the gap are never sent (``pull_for * speedup`` device seconds, or ``pull_for``
  when ``speedup`` is 0). A real-time reader that is slow to reopen loses the frames due
  meanwhile too, as it would a real device's: the device time it misses is the wall-clock
  time it was away times ``speedup``.

:attr:`FakeGyro.injected` counts what went out; :meth:`FakeGyro.sent_frames` lists the frames
delivered intact, in order. Once the drive has started, while no reader has the port open,
real-time frames are not written (a reader's open flushes them anyway; counted in
``unread_frames``); at ``speedup`` 0 the fake waits for a reader instead.
"""

from __future__ import annotations

import errno
import fcntl
import os
import select
import sys
import termios
import threading
import time
import tty
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hdrd.core.sensor import SensorModel
from hdrd.io.files.drivelog import DriveLog
from hdrd.io.wire.capture import encode_array
from hdrd.io.wire.clocks import device_seconds
from hdrd.io.wire.codec import FRAME_DTYPE, Frame, array_to_frames, encode_text
from hdrd.io.wire.protocol import PROTOCOLS, SYNC
from hdrd.sim.profiles import profile_frames

__all__ = ["FakeGyro", "Injected"]


@dataclass(slots=True)
class Injected:
    """What the fake gyro sent (only what reached an open port counts).

    frames: frames delivered intact. garbage_events / garbage_bytes: runs of garbage and
    their bytes. crc_errors: corrupted frames sent. extra_sync: sync patterns inside the
    corrupted hdr-bin frames (the parser counts each as one more bad frame). dropped: frames
    skipped on purpose. pulls: cable pulls. pulled_frames: frames not sent during pulls.
    unread_frames: frames not sent because no reader had the port open.
    """

    frames: int = 0
    garbage_events: int = 0
    garbage_bytes: int = 0
    crc_errors: int = 0
    extra_sync: int = 0
    dropped: int = 0
    pulls: int = 0
    pulled_frames: int = 0
    unread_frames: int = 0

    @property
    def expected_bad_frames(self) -> int:
        """The bad frames a parser reading everything must count."""
        return self.crc_errors + self.extra_sync

    @property
    def missing_frames(self) -> int:
        """Frames whose sequence numbers a reader never sees (dropped, pulled, unread, or
        sent corrupted)."""
        return self.dropped + self.pulled_frames + self.unread_frames + self.crc_errors


class _Tally:
    __slots__ = (
        "crc_errors",
        "dropped",
        "extra_sync",
        "frames",
        "garbage_bytes",
        "garbage_events",
        "idx",
    )

    def __init__(self) -> None:
        self.frames = self.garbage_events = self.garbage_bytes = 0
        self.crc_errors = self.extra_sync = self.dropped = 0
        self.idx: list[int] = []


class FakeGyro:
    """A fake ADC on a pty, writing the frames of ``profile`` (see the module doc).

    profile: a drive (:class:`hdrd.io.files.drivelog.DriveLog`, its raw ``omega`` turned into counts
    by ``sensor``) or frames (:data:`hdrd.io.wire.codec.FRAME_DTYPE` array). Pacing follows the
    frames' device clock. Use as a context manager (``open``/``close``); ``start()`` begins
    writing; ``wait(timeout)`` until all is written; ``stop()`` ends early.
    """

    def __init__(
        self,
        profile: DriveLog | npt.NDArray[np.void],
        *,
        protocol: str = "hdr-bin",
        speedup: float = 1.0,
        link: str | os.PathLike[str] | None = None,
        garbage: float = 0.0,
        crc_errors: float = 0.0,
        drop: float = 0.0,
        pull_at: tuple[float, ...] | list[float] = (),
        pull_for: float = 5.0,
        seed: int = 0,
        sensor: SensorModel | None = None,
        settle_s: float = 0.2,
    ) -> None:
        if protocol not in PROTOCOLS:
            raise ValueError(
                f"unknown protocol {protocol!r} (expected one of {', '.join(PROTOCOLS)})"
            )
        for name, p in (("garbage", garbage), ("crc_errors", crc_errors), ("drop", drop)):
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"{name} is a probability in [0, 1], got {p!r}")
        if not (speedup >= 0 and np.isfinite(speedup)):
            raise ValueError(
                f"speedup must be a finite number >= 0 (0 = as fast as possible), got {speedup!r}"
            )
        if not pull_for > 0:
            raise ValueError(f"pull_for must be > 0 s, got {pull_for!r}")
        if isinstance(profile, DriveLog):
            self.frames = profile_frames(profile, sensor)
        else:
            self.frames = np.ascontiguousarray(profile, dtype=FRAME_DTYPE)
        self.profile = profile if isinstance(profile, DriveLog) else None
        self.protocol = protocol
        self.speedup = float(speedup)
        self.link = None if link is None else str(link)
        self.garbage = garbage
        self.crc_errors = crc_errors
        self.drop = drop
        self.pull_at = sorted(float(t) for t in pull_at)
        self.pull_for = float(pull_for)
        self.seed = seed
        self.settle_s = settle_s
        self.injected = Injected()
        self.delivered = np.zeros(self.frames.shape[0], bool)
        """delivered[k]: frame k reached an open port intact."""
        self.path: str | None = None
        """The pty slave of the current connection (changes at every cable pull)."""
        self._link_target: str | None = None  # what our symlink points at, once made
        self.t_s = device_seconds(self.frames["t_us"])
        self._wire = self._encode_all()
        self._rng = np.random.default_rng(seed)
        self._master: int | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._done = threading.Event()
        self._pull_request: float | None = None
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None

    # -- the pty ---------------------------------------------------------------------------

    def open(self) -> FakeGyro:
        """Open the pty (and the symlink); nothing is written before :meth:`start`."""
        if self._master is None:
            self._open_pty()
        return self

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        try:
            tty.setraw(slave)  # binary-clean, no echo, for readers that do not set it themselves
            self.path = os.ttyname(slave)
        finally:
            # Not keeping the slave open lets poll() on the master say (POLLHUP) whether a reader has it.
            os.close(slave)
        fl = fcntl.fcntl(master, fcntl.F_GETFL)
        fcntl.fcntl(master, fcntl.F_SETFL, fl | os.O_NONBLOCK)
        self._master = master
        if self.link is not None:
            try:
                self._point_link()
            except OSError:
                self._master = None
                os.close(master)
                raise

    def _point_link(self) -> None:
        """Make (or re-point) the symlink at the current pty, atomically. Only a symlink is
        ever replaced: a regular file, a directory or a device at that path is refused
        (FileExistsError), never deleted."""
        assert self.link is not None and self.path is not None
        if os.path.lexists(self.link) and not os.path.islink(self.link):
            raise FileExistsError(
                errno.EEXIST, "exists and is not a symlink; refusing to replace it", self.link
            )
        tmp = f"{self.link}.tmp{os.getpid()}"
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        os.symlink(self.path, tmp)
        os.replace(tmp, self.link)  # atomic: the link is never half-made
        self._link_target = self.path

    def _close_pty(self) -> None:
        if self.link is not None and self._link_target is not None:
            try:  # remove the link only if it is still ours (pointing at our pty)
                if os.readlink(self.link) == self._link_target:
                    os.unlink(self.link)
            except OSError:
                pass
        master, self._master = self._master, None
        if master is not None:
            os.close(master)

    def _reader_present(self) -> bool:
        if self._master is None:
            return False
        p = select.poll()
        p.register(self._master, select.POLLHUP)
        return not any(ev & select.POLLHUP for _, ev in p.poll(0))

    def _drain(self, timeout_s: float = 2.0, quiet_s: float = 0.05) -> None:
        """Wait (bounded) until the reader has read what was written, so a pull falls
        between frames rather than on bytes still queued in the pty. The kernel moves
        written bytes to the reader's queue asynchronously, so the queue must stay empty for
        ``quiet_s`` before we believe it."""
        if self.path is None or not self._reader_present():
            return
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:
            return
        try:
            end = time.monotonic() + timeout_s
            empty_since: float | None = None
            buf = bytearray(4)
            while not self._stop.is_set():
                now = time.monotonic()
                if now >= end:
                    break
                fcntl.ioctl(fd, termios.FIONREAD, buf)
                if int.from_bytes(buf, sys.byteorder):
                    empty_since = None
                elif empty_since is None:
                    empty_since = now
                elif now - empty_since >= quiet_s:
                    break
                time.sleep(0.005)
        except OSError:
            pass
        finally:
            os.close(fd)

    def _write(self, data: bytes) -> bool:
        """Write all of ``data``; False if it could not reach a reader (or we are stopping)."""
        view = memoryview(data)
        waited = False
        while view:
            if self._stop.is_set() or self._master is None:
                return False
            if not self._reader_present():
                if self.speedup > 0:
                    return False  # a real device's bytes go nowhere; the reader's open flushes them
                waited = True
                self._stop.wait(0.02)
                continue
            if waited:
                # A reader just opened: let its open-time flush (pyserial) pass first.
                waited = False
                if self._stop.wait(self.settle_s):
                    return False
                continue
            p = select.poll()
            p.register(self._master, select.POLLOUT)
            if not p.poll(50):
                continue
            try:
                n = os.write(self._master, view)
            except BlockingIOError:
                continue
            except OSError as e:
                if e.errno == errno.EIO:  # the reader closed in between
                    continue
                raise
            view = view[n:]
        return True

    # -- frames and faults -----------------------------------------------------------------

    def _encode_all(self) -> list[bytes] | bytes:
        if self.protocol == "hdr-bin":
            return encode_array(self.frames, "hdr-bin")
        return [encode_text(f) for f in array_to_frames(self.frames)]

    def _frame_wire(self, k: int) -> bytes:
        if isinstance(self._wire, bytes):
            return self._wire[16 * k : 16 * k + 16]
        return self._wire[k]

    def _garbage_bytes(self) -> bytes:
        n = int(self._rng.integers(1, 33))
        b = self._rng.integers(0, 256, n, dtype=np.uint8)
        if self.protocol == "hdr-bin":
            b[(b == 0xA5) | (b == 0x5A)] = 0x00
        else:
            b[b == ord("$")] = ord("#")
        return b.tobytes()

    def _corrupt(self, wire: bytes) -> tuple[bytes, int]:
        b = bytearray(wire)
        if self.protocol == "hdr-bin":
            b[int(self._rng.integers(2, 16))] ^= 1 << int(self._rng.integers(0, 8))
            extra = sum(1 for i in range(1, 15) if b[i : i + 2] == SYNC)
            return bytes(b), extra
        star = b.rindex(b"*")
        digits = [i for i in range(6, star) if 0x30 <= b[i] <= 0x39]
        i = digits[int(self._rng.integers(0, len(digits)))]
        b[i] = 0x30 + (b[i] - 0x30 + int(self._rng.integers(1, 10))) % 10
        return bytes(b), 0

    def _emit(self, k: int, out: bytearray, tally: _Tally) -> None:
        """Frame k with its faults appended to ``out``; what went in is noted in ``tally``."""
        u = self._rng.random(3)
        if u[0] < self.drop:
            tally.dropped += 1
            return
        if u[1] < self.garbage:
            g = self._garbage_bytes()
            out += g
            tally.garbage_events += 1
            tally.garbage_bytes += len(g)
        wire = self._frame_wire(k)
        if u[2] < self.crc_errors:
            bad, extra = self._corrupt(wire)
            out += bad
            tally.crc_errors += 1
            tally.extra_sync += extra
            return
        out += wire
        tally.frames += 1
        tally.idx.append(k)

    def _commit(self, tally: _Tally, written: bool) -> None:
        with self._lock:
            inj = self.injected
            if written:
                inj.frames += tally.frames
                inj.garbage_events += tally.garbage_events
                inj.garbage_bytes += tally.garbage_bytes
                inj.crc_errors += tally.crc_errors
                inj.extra_sync += tally.extra_sync
                inj.dropped += tally.dropped
                self.delivered[tally.idx] = True
            else:
                inj.unread_frames += tally.frames + tally.crc_errors
                inj.dropped += tally.dropped

    def sent_frames(self) -> list[Frame]:
        """The frames delivered intact so far, in order."""
        return array_to_frames(self.frames[self.delivered])

    # -- running ---------------------------------------------------------------------------

    def start(self) -> FakeGyro:
        """Start writing in a background thread (opens the pty first if needed)."""
        self.open()
        if self._thread is None:
            self._thread = threading.Thread(target=self._run_guarded, name="fakegyro", daemon=True)
            self._thread.start()
        return self

    def pull(self, seconds: float | None = None) -> None:
        """Pull the cable before the next frame, for ``seconds`` (default ``pull_for``)."""
        self._pull_request = self.pull_for if seconds is None else float(seconds)

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until every frame is written and the reader has read them (bounded wait), or
        until :meth:`stop`; True if finished."""
        return self._done.wait(timeout)

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def stop(self) -> None:
        """Stop writing (the pty stays open until :meth:`close`)."""
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout=10)

    def close(self) -> None:
        """Stop, close the pty and remove the symlink (idempotent)."""
        self.stop()
        self._close_pty()

    def __enter__(self) -> FakeGyro:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _run_guarded(self) -> None:
        try:
            self._run()
        except BaseException as e:  # noqa: BLE001 - kept for the test/CLI to report
            self.error = e
        finally:
            self._done.set()

    def _do_pull(self, seconds: float) -> None:
        self._drain()
        with self._lock:
            self.injected.pulls += 1
        self._close_pty()
        if self._stop.wait(seconds):
            return
        self._open_pty()
        self.on_pull_end()

    def on_pull_end(self) -> None:
        """Hook called after a pull, when the new pty is up (the CLI reports it)."""

    def _await_reader(self) -> bool:
        """Until a reader has the port open, and its open-time flush (pyserial) has passed:
        a real-time drive starts then, not before (its first frames, a standstill to
        calibrate on, would go to nobody). False if stopped meanwhile."""
        while not self._reader_present():
            if self._stop.wait(0.02):
                return False
        return not self._stop.wait(self.settle_s)

    def _run(self) -> None:
        n = self.frames.shape[0]
        t = self.t_s
        pulls = list(self.pull_at)
        k = 0
        if self.speedup > 0 and not self._await_reader():
            return
        wall0 = time.monotonic()  # the device clock starts with the reader
        batch_max = 256 if self.speedup == 0 else 4096
        while k < n and not self._stop.is_set():
            req, self._pull_request = self._pull_request, None
            if req is None and pulls and t[k] >= pulls[0]:
                req = self.pull_for
            if req is not None:
                k = self._pull_at(k, req, pulls)
                continue
            j = self._batch_end(k, wall0, batch_max, pulls)
            if j is None:
                continue
            out = bytearray()
            tally = _Tally()
            for i in range(k, j):
                self._emit(i, out, tally)
            written = self._write(bytes(out)) if out else True
            self._commit(tally, written)
            k = j
        self._drain()  # "done" means the reader has had everything

    def _pull_at(self, k: int, seconds: float, pulls: list[float]) -> int:
        """Pull the cable at frame k for ``seconds`` (scaled by the speed-up), dropping the
        scheduled pulls that are due; the frame to resume at."""
        t = self.t_s
        while pulls and t[k] >= pulls[0]:
            pulls.pop(0)
        t_pull = t[k]
        self._do_pull(seconds)
        resume = t_pull + seconds * (self.speedup if self.speedup > 0 else 1.0)
        k_next = int(np.searchsorted(t, resume, side="left"))
        with self._lock:
            self.injected.pulled_frames += k_next - k
        return k_next

    def _batch_end(self, k: int, wall0: float, batch_max: int, pulls: list[float]) -> int | None:
        """The end of the next write from frame k: every frame already due (paced), at most
        ``batch_max``, none past the next pull; None after waiting for frame k to be due."""
        n = self.frames.shape[0]
        t = self.t_s
        if self.speedup > 0:
            wait = wall0 + t[k] / self.speedup - time.monotonic()
            if wait > 0:
                self._stop.wait(min(wait, 0.5))
                return None
            # Every frame already due goes in one write.
            due_t = (time.monotonic() - wall0) * self.speedup
            j = int(np.searchsorted(t, due_t, side="right"))
        else:
            j = n
        j = min(max(j, k + 1), k + batch_max, n)
        if pulls:
            j = min(j, max(k + 1, int(np.searchsorted(t, pulls[0], side="left"))))
        return j

    # -- a capture file instead of a pty ---------------------------------------------------

    def write_capture(self, path: str | os.PathLike[str]) -> None:
        """Write the whole stream, with its faults, to a capture file (no pacing; a pull
        leaves its frames out)."""
        n = self.frames.shape[0]
        t = self.t_s
        pulls = list(self.pull_at)
        with open(path, "wb") as f:
            k = 0
            while k < n:
                if pulls and t[k] >= pulls[0]:
                    while pulls and t[k] >= pulls[0]:
                        pulls.pop(0)
                    k_next = int(np.searchsorted(t, t[k] + self.pull_for, side="left"))
                    self.injected.pulls += 1
                    self.injected.pulled_frames += k_next - k
                    k = k_next
                    continue
                j = min(n, k + 4096)
                if pulls:
                    j = min(j, max(k + 1, int(np.searchsorted(t, pulls[0], side="left"))))
                out = bytearray()
                tally = _Tally()
                for i in range(k, j):
                    self._emit(i, out, tally)
                f.write(out)
                self._commit(tally, True)
                k = j
            f.flush()
            os.fsync(f.fileno())
