# ruff: noqa: F811 - the fixtures hdrd and receivers come from test_rel_daemon by import
"""The sped-up fake-gyro demo of docs/commands.md, as a user runs it: ``hdrd fakegyro --speedup
60 --pull-at ... --link L &`` in one terminal, ``hdrd run --port L --clock-rate 60`` in the
next a moment later.

It used to start about 60 s of drive late (the fake's clock ran from its own start, and the
frames nobody read were gone), miss the drive's 30 s standstill and calibrate while moving
(``calibration_rejected``, a bias of 0.919 where the drive's is 0.706); and after the cable
pull its steps resumed 6 steps on with 360 s of device time gone (the gap measured by the
wall clock, not by the device clock 60 times faster).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.test_rel_daemon import (  # noqa: F401 - hdrd and receivers are fixtures
    WAIT,
    hdrd,
    receivers,
    run_args,
)

DRIVE = ("--drive", "city", "--minutes", "5")  # + the 30 s standstill: 330 s of drive
DRIVE_S = 330.0


def replayed(tmp_path: Path) -> list[dict[str, object]]:
    """What ``hdrd replay`` makes of the same drive's every frame."""
    cap = tmp_path / "drive.cap"
    subprocess.run(
        [sys.executable, "-m", "hdrd", "fakegyro", *DRIVE, "--out", str(cap)],
        check=True,
        capture_output=True,
        timeout=WAIT,
    )
    out = subprocess.run(
        [sys.executable, "-m", "hdrd", "replay", str(cap)],
        check=True,
        capture_output=True,
        timeout=WAIT,
    ).stdout
    return [json.loads(line) for line in out.splitlines()]


@pytest.mark.slow
def test_the_sped_up_demo_sees_the_standstill_and_keeps_device_time(hdrd, receivers, tmp_path):
    link = tmp_path / "hdrd-gyro"
    fake = hdrd(
        "fakegyro", *DRIVE, "--speedup", "60", "--pull-at", "120", "--pull-for", "1",
        "--link", str(link),
    )  # fmt: skip
    deadline = time.monotonic() + WAIT
    while not link.exists():
        assert fake.alive and time.monotonic() < deadline, fake.other
        time.sleep(0.02)
    time.sleep(1.5)  # the user types the next command: a minute and a half of drive at 60x
    rx = receivers()
    d = hdrd(*run_args("--port", str(link), "--clock-rate", "60", "--udp", rx.addr))
    deadline = time.monotonic() + 3 * WAIT
    while fake.alive and time.monotonic() < deadline:
        time.sleep(0.1)
    assert fake.stop() == 0 and any(x.startswith("hdrd fakegyro: done") for x in fake.other), (
        fake.other
    )
    assert d.stop() == 0 and not d.traceback
    msgs = rx.snapshot()
    # The drive from its first frame: the standstill calibrates, as replay calibrates it.
    assert d.count("calibration_rejected") == 0
    (cal,) = d.named("calibrated")
    want = next(m["bias"] for m in replayed(tmp_path) if "bias" in m)
    assert cal["bias_dps"] == want
    assert msgs[0]["step"] == 0 and msgs[0]["t"] == 1.0
    # Across the pull the steps move on by the device time missed (the device ran on at 60x
    # while the daemon reconnected): the last step ends where the drive ends.
    back = next(m for m in msgs if "gap_s" in m)
    assert back["gap_s"] >= 60.0 - 1.0  # the pull alone: 1 s of wall clock at 60x
    steps = [m for m in msgs if m["status"] != "stale"]
    assert abs(steps[-1]["t"] - DRIVE_S) <= 30.0, (steps[-1]["t"], back)
