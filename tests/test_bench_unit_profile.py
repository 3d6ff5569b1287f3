"""The cut of a real drive into an earlier and a later part (bench/unit_profile.py): the later
part starts at the stop it was cut at, and that stop is its start-up standstill.

Rates in deg/s, + = CCW; times s since the log's first sample; speeds m/s.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import unit_profile  # noqa: E402

from hdrd.analysis.prepare import prepare_drive  # noqa: E402
from hdrd.io.files.drivelog import DriveLog  # noqa: E402


def _drive() -> DriveLog:
    """15 min at 1 Hz: a 60 s lead-in, driving (a gentle weave), a 20 s stop at 500 s."""
    t = np.arange(900.0)
    moving = (t >= 60.0) & ~((t >= 500.0) & (t < 520.0))
    speed = np.where(moving, 12.0, 0.0)
    rng = np.random.default_rng(4)
    weave = np.where(moving, 3.0 * np.sin(2 * np.pi * t / 37.0), 0.0)
    omega = 0.5 + weave + rng.normal(0.0, 0.02, t.shape[0])
    truth = np.mod(90.0 - np.cumsum(weave), 360.0)
    return DriveLog(t=t, omega=omega, heading_truth=truth, speed=speed, name="d",
                    meta={"lead_in_s": "60"})  # fmt: skip


def test_the_later_part_calibrates_on_the_stop_it_starts_at() -> None:
    parts = unit_profile.cut_at_stop(_drive())
    assert parts is not None
    first, later = parts
    assert (first.name, later.name) == ("d-first", "d-later")
    assert first.meta["lead_in_s"] == "60"  # the drive's own lead-in
    assert later.t[0] == 500.0 and float(later.meta["lead_in_s"]) == 19.0
    prep = prepare_drive(later)
    assert prep.bias_source == "lead-in 19 s" and abs(prep.steps.bias_dps - 0.5) < 0.02
