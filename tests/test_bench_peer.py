"""The Kalman peer of the outage benchmarks (bench/peer.py): the outages it is judged on, and
the filter on drives whose answer is known.

Rates in deg/s, + = CCW; headings compass deg; times s since the log's first sample.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import peer  # noqa: E402

from hdrd.analysis.outages import FROZEN, OutageSpec  # noqa: E402
from hdrd.analysis.prepare import DEFAULTS, prepare_drive  # noqa: E402
from hdrd.io.files.drivelog import DriveLog  # noqa: E402
from tests.test_outages import drive  # noqa: E402


def test_the_plan_runs_the_grid_at_four_phases_and_a_long_drive_every_five_minutes() -> None:
    ten, five = OutageSpec(120.0, 600.0), OutageSpec(120.0, 300.0)
    assert peer.outage_plan(12.0) == [(ten, 0.0), (ten, 150.0), (ten, 300.0), (ten, 450.0)]
    assert peer.outage_plan(30.0) == peer.outage_plan(12.0)
    assert peer.outage_plan(30.5) == [(five, 0.0), (five, 75.0), (five, 150.0), (five, 225.0)]


def test_the_peer_holds_a_known_bias_through_every_outage_of_the_plan() -> None:
    # The calibration measures the bias (0.3 deg/s), the gyro's noise is 0.02 deg/s: every
    # outage ends within a degree, as the frozen bias does; every run of the plan is there.
    log = drive(minutes=28.0)
    prep = prepare_drive(log)
    r = peer.plan_errors(prep, log, (FROZEN,), DEFAULTS)
    assert r.phases == [0.0, 0.0, 150.0, 150.0, 300.0, 300.0, 450.0, 450.0]
    assert r.windows[:3] == [(510.0, 630.0), (1110.0, 1230.0), (660.0, 780.0)]
    assert r.errors[FROZEN].shape == r.errors["kalman peer"].shape == (8,)
    assert np.all(np.isfinite(r.errors["kalman peer"]))
    assert np.max(np.abs(r.errors["kalman peer"])) < 1.0
    assert np.max(np.abs(r.errors[FROZEN])) < 1.0


def stop_and_go(lagging_speed: bool) -> DriveLog:
    """A 1 Hz point-sampled logger in a car that stops for 60 s every 5 minutes and leaves
    each stop with a 90 deg turn at 30 deg/s; ``lagging_speed``: the logged speed still reads
    0 through that turn (as a logger's speed does). Bias 0.05 deg/s, noise 0.1 deg/s, a course
    above 2 m/s."""
    rng = np.random.default_rng(3)
    t = np.arange(30.0 + 32 * 60.0)
    since = t - 30.0
    phase = since % 300.0
    stopped = (since < 0) | ((phase >= 200.0) & (phase < 260.0))
    turning = (since >= 0) & (phase >= 260.0) & (phase < 263.0)
    w_true = np.where(turning, 30.0, 0.0)
    heading = (40.0 - np.cumsum(w_true)) % 360.0
    speed = np.where(stopped, 0.0, 15.0)
    logged = np.where(turning, 0.0, speed) if lagging_speed else speed
    omega = w_true + 0.05 + rng.normal(0.0, 0.1, t.shape[0])
    course = np.where(speed > 2.0, heading, np.nan)
    return DriveLog(t=t, omega=omega, heading_truth=course, speed=logged, name="stop-and-go")


def test_a_logged_speed_of_zero_in_a_turn_is_no_stop() -> None:
    # A logger's speed lags the car: it read 0 m/s while the gyro turned at 24 deg/s, and a
    # zero-rate update on that speed alone had pulled the peer's bias to -5 deg/s. The
    # daemon's standstill test (the gyro must agree) keeps those steps out: the outages end
    # as they do with a speed that is right, within the gyro's noise (0.1 deg/s over 120 s).
    errs = {}
    for lagging in (False, True):
        log = stop_and_go(lagging)
        prep = prepare_drive(log)
        spec = OutageSpec(120.0, 600.0)
        errs[lagging] = np.concatenate(
            [peer.kalman_peer(prep, log, spec, phase_s=ph) for ph in (0.0, 150.0, 300.0)]
        )
    assert errs[True].shape == (7,) and np.all(np.isfinite(errs[True]))
    assert np.max(np.abs(errs[False])) < 3.0
    assert np.max(np.abs(errs[True] - errs[False])) < 0.1
