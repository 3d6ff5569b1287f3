#!/usr/bin/env python3
"""Record the golden capture, tests/data/golden/drive-faults.bin (docs/testing.md).

    PYTHONPATH=$PWD python tools/golden_capture.py [--out tests/data/golden/drive-faults.bin]

A real recording: ``hdrd record`` (a process) reads a fake gyro on a real pty, as it would
read /dev/ttyUSB0, and writes every byte it reads. What the capture holds, in order:

1. A simulated city drive (seed 7, 10 Hz): 30 s standing still, then 2 minutes of driving,
   with a supply monitor wired (ref counts at 5.1 V) and the cabin temperature; its device
   clock starts 60 s before the 32-bit microsecond wrap and its sequence 400 frames before
   the 16-bit wrap, so both wrap in the capture. Garbage before 2 % of the frames, 2 % with
   a CRC error, 1 % dropped, and the cable pulled at device time 100 s for 2 s (the board
   stays powered: its clock runs on, 20 frames are never sent).
2. The device unplugged and plugged in again, re-powered: a second board's stream whose
   clock and sequence start at 0 (a device reset), 5 s still then a 30 s left turn at
   8 deg/s (+ = CCW), again with garbage and CRC errors, no temperature sensor.

The script checks that the recording holds exactly the frames the fakes delivered. The
capture is committed and does not change; what is regenerated when the pipeline's output
changes on purpose is the expected output beside it (``pytest tests/test_golden.py
--regen-golden``).
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from hdrd.io.wire.capture import decode_capture
from hdrd.io.wire.codec import array_to_frames
from hdrd.io.wire.protocol import CLOCK_WRAP_US
from hdrd.sim import simulate_drive
from hdrd.sim.fakegyro import FakeGyro
from hdrd.sim.profiles import builtin_profile, profile_frames

OUT = Path(__file__).resolve().parents[1] / "tests" / "data" / "golden" / "drive-faults.bin"
WAIT_S = 120.0


def _record(out: Path, link: Path, a: FakeGyro, b: FakeGyro) -> tuple[int, str]:
    """``hdrd record`` on the fakes' ``link``: ``a`` to its end, its cable pulled, then ``b``,
    then SIGINT. Its exit status and stderr."""
    with a:
        rec = subprocess.Popen(
            [sys.executable, "-m", "hdrd", "record", "--port", str(link), "--out", str(out)],
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            a.start()
            if not a.wait(WAIT_S) or a.error is not None:
                raise SystemExit(f"the first fake gyro did not finish: {a.error}")
        except BaseException:
            rec.kill()
            raise
    # `a` closed: its pty and link are gone (the cable pulled); `b` is a new device there.
    with b:
        try:
            b.start()
            if not b.wait(WAIT_S) or b.error is not None:
                raise SystemExit(f"the second fake gyro did not finish: {b.error}")
        finally:
            rec.send_signal(signal.SIGINT)
            _, err = rec.communicate(timeout=WAIT_S)
    return rec.returncode, err


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)

    city = simulate_drive("city", 2.0, 7, hz=10.0, lead_in_s=30.0)
    first = profile_frames(city, supply_v=5.1, t0_us=CLOCK_WRAP_US - 60_000_000, seq0=65536 - 400)
    turn = builtin_profile(
        "constant", minutes=0.5, seed=8, rate_dps=8.0, bias_dps=-0.4, lead_in_s=5.0
    )
    second = profile_frames(turn)
    second["temp"] = -32768  # this board has no temperature sensor

    with tempfile.TemporaryDirectory() as tmp:
        link = Path(tmp) / "gyro"
        a = FakeGyro(
            first, speedup=0, link=link, garbage=0.02, crc_errors=0.02, drop=0.01,
            pull_at=[100.0], pull_for=2.0, seed=7,
        )  # fmt: skip
        b = FakeGyro(second, speedup=0, link=link, garbage=0.02, crc_errors=0.02, seed=8)
        rc, err = _record(args.out, link, a, b)
    if rc != 0:
        raise SystemExit(f"hdrd record failed ({rc}): {err}")
    arr, stats = decode_capture(args.out.read_bytes())
    if array_to_frames(arr) != a.sent_frames() + b.sent_frames():
        raise SystemExit("the recording is not exactly the frames the fakes delivered")
    print(err.strip(), file=sys.stderr)
    print(
        f"{args.out}: {args.out.stat().st_size} bytes, {arr.shape[0]} frames, "
        f"{stats.bad_frames} bad, {stats.garbage_bytes} bytes of garbage, "
        f"{stats.seq_gaps} sequence gaps, {stats.seq_resets} sequence resets",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
