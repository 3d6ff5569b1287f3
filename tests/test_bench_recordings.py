"""bench/recordings.py, the recording profile bench/gap_real.py measures, and the simulator's
effects it rests on: a GPS course that lags, a log that keeps point samples of a faster gyro
(docs/gyro-model.md, docs/model-gap.md)."""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hdrd.analysis.gap import run_gap, summary
from hdrd.core.angles import wrap180
from hdrd.core.grades import Grade
from hdrd.sim import simulate_drive
from hdrd.sim.effects import RateRandomWalk, TimeOffset, WhiteNoise
from hdrd.sim.gps import GpsModel, gps_course, heading_from_rate
from hdrd.sim.grades import grade_model
from hdrd.sim.gyrolimits import limit_problem

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from recordings import (  # noqa: E402
    RECORDINGS,
    Recording,
    log_rate_model,
    point_sampled_sd,
    recording_gps,
    recording_model,
    simulate_recording,
)


def test_course_latency_reports_the_heading_of_that_long_before() -> None:
    t = np.arange(0.0, 120.0, 0.1)
    omega = 10.0 * np.sin(2.0 * np.pi * t / 40.0)  # deg/s, turning both ways
    heading = heading_from_rate(t, omega, 30.0)
    speed = np.full(t.shape, 10.0)
    exact = GpsModel(vel_noise_mps=0.0, floor_deg=0.0)
    now = gps_course(t, heading, speed, np.random.default_rng(1), exact)
    late = gps_course(t, heading, speed, np.random.default_rng(1), replace(exact, latency_s=1.2))
    fix = np.flatnonzero(np.isfinite(late))
    assert np.array_equal(fix, np.flatnonzero(np.isfinite(now)))
    unwrapped = np.degrees(np.unwrap(np.radians(heading)))
    want = np.mod(np.interp(t[fix] - 1.2, t, unwrapped), 360.0)
    np.testing.assert_allclose(late[fix], want, atol=1e-9)
    assert np.max(np.abs(wrap180(late[fix] - now[fix]))) > 5.0


def test_no_latency_leaves_the_course_as_it_was() -> None:
    """latency_s = 0 (the default) draws and returns exactly what the course did before."""
    log = simulate_drive("city", 3.0, 4, hz=5.0)
    again = simulate_drive("city", 3.0, 4, hz=5.0, gps=GpsModel(latency_s=0.0))
    np.testing.assert_array_equal(log.heading_truth, again.heading_truth)
    with pytest.raises(ValueError, match="latency_s"):
        GpsModel(latency_s=-1.0)


def test_point_samples_carry_the_sensor_noise_of_its_whole_bandwidth() -> None:
    """A 1 Hz log of a 100 Hz phone gyro: the same rows and times as a 1 Hz simulation, and at
    the stops each sample carries the noise of the sensor's 32 Hz bandwidth, not a second's
    average of it."""
    model = grade_model("phone", 3).without("quantization")
    avg = simulate_drive("city", 30.0, 3, hz=1.0, model=model)
    point = simulate_drive("city", 30.0, 3, hz=1.0, model=model, sensor_hz=100.0)
    assert point.meta["sensor_hz"] == "100"
    np.testing.assert_array_equal(point.t, avg.t)
    g = Grade.from_table("phone")

    def stop_sd(log: object) -> float:
        st = log.speed == 0.0  # type: ignore[attr-defined]
        d = np.diff(log.omega)[st[1:] & st[:-1]]  # type: ignore[attr-defined]
        return float(np.std(d) / math.sqrt(2.0))

    want = point_sampled_sd(g.white_dps_per_rthz, g.bandwidth_hz, 100.0)
    assert stop_sd(point) == pytest.approx(want, rel=0.15)
    assert stop_sd(avg) == pytest.approx(g.white_dps_per_rthz, rel=0.15)
    with pytest.raises(ValueError, match="whole multiple"):
        simulate_drive("city", 1.0, 2, hz=1.0, sensor_hz=2.5)


def test_the_profile_is_the_grade_with_what_the_tuning_drives_measured() -> None:
    assert "driveplotr" in RECORDINGS
    r = Recording.from_table("driveplotr")
    assert set(r.sources) and all(r.sources.values())
    m = recording_model("driveplotr", 5)
    white = m.get("white_noise")
    assert isinstance(white, WhiteNoise) and white.density_dps_per_rthz == r.white_dps_per_rthz
    assert recording_gps("driveplotr").latency_s == r.gps_latency_s
    seen = log_rate_model("driveplotr", 5)
    lag = seen.get("time_offset")
    assert isinstance(lag, TimeOffset) and lag.delay_s == -r.gps_latency_s
    assert "bandwidth" not in seen and "temperature_bias" not in seen
    g = Grade.from_table(r.grade)
    per_sample = point_sampled_sd(r.white_dps_per_rthz, g.bandwidth_hz, r.sensor_hz)
    white = seen.get("white_noise")
    assert isinstance(white, WhiteNoise)
    assert white.density_dps_per_rthz == pytest.approx(per_sample / math.sqrt(r.log_hz))
    with pytest.raises(ValueError, match="unknown recording"):
        Recording.from_table("nope")


def test_every_profiles_models_are_within_the_gyro_limits() -> None:
    for r in RECORDINGS:
        for m in (recording_model(r, 0), log_rate_model(r, 0)):
            for e in m.to_dict()["effects"]:
                for k, v in e.items():
                    if k != "name":
                        assert limit_problem(e["name"], k, v) is None, (r, e, k)


@pytest.mark.slow  # a whole model-gap search
def test_hdrd_gap_reads_the_profile_back_from_a_simulated_drive() -> None:
    """A city drive logged as DrivePlotR logs it, with its GPS course as the only truth:
    ``hdrd gap`` names the course's latency as a time offset of about -latency, the 1/16 deg/s
    step, and a white noise of the point-sampled sensor's sd (and, the stops pinning the bias,
    the profile's random walk); from the profile's own model it names nothing."""
    r = Recording.from_table("driveplotr")
    log = replace(simulate_recording("driveplotr", "city", 15.0, 3), omega_truth=None, temp_c=None)
    res = run_gap(log)
    names = [s.effect for s in res.steps]
    assert {"time_offset", "quantization"} <= set(names), summary(res)
    assert set(names) <= {"time_offset", "quantization", "rate_random_walk"}, summary(res)
    rw = res.final_model.get("rate_random_walk")
    if isinstance(rw, RateRandomWalk):
        assert rw.k_dps_per_sqrt_s == pytest.approx(r.rrw_dps_per_sqrt_s, rel=0.5), summary(res)
    lag = res.final_model.get("time_offset")
    assert isinstance(lag, TimeOffset) and lag.delay_s == pytest.approx(-r.gps_latency_s, abs=0.25)
    white = res.final_model.get("white_noise")
    g = Grade.from_table(r.grade)
    per_sample = point_sampled_sd(r.white_dps_per_rthz, g.bandwidth_hz, r.sensor_hz)
    assert isinstance(white, WhiteNoise)
    assert white.density_dps_per_rthz == pytest.approx(per_sample, rel=0.2)
    again = run_gap(log, log_rate_model("driveplotr", 3))
    assert again.steps == (), summary(again)
