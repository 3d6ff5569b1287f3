"""``hdrd fakegyro``: a fake gyro on a pty, or its stream written to a capture file (the fake
itself is :class:`hdrd.sim.fakegyro.FakeGyro`)."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from dataclasses import asdict

from hdrd.sim.fakegyro import FakeGyro
from hdrd.sim.profiles import ProfileError, load_profile

__all__ = ["main"]


def _err(msg: str) -> None:
    print(f"hdrd fakegyro: {msg}", file=sys.stderr, flush=True)


def _summary(g: FakeGyro) -> str:
    d = asdict(g.injected)
    return ", ".join(f"{k} {v}" for k, v in d.items() if v or k == "frames")


def main(args: argparse.Namespace) -> int:
    """``hdrd fakegyro``: print the pty path (and --link) on stdout, then write the drive."""
    try:
        profile = load_profile(args.drive, args.minutes, args.seed, args.hz, args.rate_dps)
        gyro = FakeGyro(
            profile,
            protocol=args.protocol,
            speedup=args.speedup,
            link=args.link,
            garbage=args.garbage,
            crc_errors=args.crc_errors,
            drop=args.drop,
            pull_at=tuple(args.pull_at or ()),
            pull_for=args.pull_for,
            seed=args.seed,
        )
    except (ProfileError, ValueError) as e:
        _err(str(e))
        return 2
    if args.out:
        try:
            gyro.write_capture(args.out)
        except OSError as e:
            _err(f"cannot write {args.out}: {e.strerror or e}")
            return 1
        _err(f"wrote {args.out}: {_summary(gyro)}")
        return 0
    return _serve(gyro, args.speedup)


def _serve(gyro: FakeGyro, speedup: float) -> int:
    """Serve the drive on the pty until it ends or SIGINT / SIGTERM (their handlers restored
    after); the exit status."""
    stop = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}

    def pull_end() -> None:
        _err(f"cable back: {gyro.path}" + (f" (link {gyro.link})" if gyro.link else ""))

    gyro.on_pull_end = pull_end  # type: ignore[method-assign]
    try:
        try:
            gyro.open()
        except OSError as e:
            where = f" {e.filename}" if e.filename else ""
            _err(f"cannot open a pty or the link{where}: {e.strerror or e}")
            return 1
        try:
            print(gyro.path, flush=True)
            if gyro.link:
                print(gyro.link, flush=True)
        except BrokenPipeError:
            pass
        pace = "as fast as it reads" if speedup == 0 else f"at {speedup:g}x real time"
        _err(f"waiting for a reader to open the port: the drive starts then, {pace}")
        gyro.start()
        while not stop.is_set() and not gyro.wait(0.2):
            pass
        if gyro.error is not None:
            _err(f"stopped: {gyro.error!r}")
            return 1
        _err(("interrupted: " if stop.is_set() else "done: ") + _summary(gyro))
        return 0
    finally:
        gyro.close()
        for s, h in old.items():
            signal.signal(s, h)
