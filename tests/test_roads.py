"""hdrd.sim.roads: simulated gyros on a route (a real drive's true rate, speed and heading)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hdrd.analysis.prepare import prepare_drive
from hdrd.core.angles import wrap180
from hdrd.io.files.drivelog import DriveLog, read_drive, write_drive
from hdrd.sim.effects import MotionOffset, StaticBias, WhiteNoise
from hdrd.sim.gps import GpsModel, heading_from_rate
from hdrd.sim.grades import grade_model
from hdrd.sim.gyro import GyroModel
from hdrd.sim.roads import RouteError, grade_on_road, road_drive, route_stops, route_truth
from hdrd.sim.vehicle import CabinTemperature


def a_route(seconds: float = 300.0, first_heading_row: int = 0) -> DriveLog:
    """A route at ~9.6 Hz (uneven steps): 5 s standing, then 2 m/s^2 up to 12 m/s, a stop at
    150-170 s; a rate of slow left and right curves; the compass heading it makes, from 200
    deg, unknown before ``first_heading_row``."""
    rng = np.random.default_rng(5)
    dt = 0.1037 + 0.0005 * rng.standard_normal(int(seconds / 0.1037))
    t = np.concatenate(([0.0], np.cumsum(dt)))
    speed = np.clip(2.0 * (t - 5.0), 0.0, 12.0)
    speed = np.where((t > 150.0) & (t < 170.0), 0.0, speed)
    rate = np.where(speed > 0.0, 8.0 * np.sin(2 * math.pi * t / 40.0), 0.0)
    heading = heading_from_rate(t, rate, 200.0)
    heading[:first_heading_row] = np.nan
    meta = {"source": "test route", "route": "true rate"}
    return DriveLog(t, np.array(rate), None, heading, rate, speed, name="r", meta=meta)


def test_route_truth_backs_the_first_heading_out_of_the_rate() -> None:
    route = a_route(first_heading_row=900)  # ~93 s in, after curves
    t, rate, speed, heading0 = route_truth(route)
    assert t[0] == 0.0 and heading0 == pytest.approx(200.0, abs=1e-9)
    np.testing.assert_array_equal(rate, route.omega_truth)
    assert speed.max() == 12.0


def test_route_truth_refuses_what_is_no_route() -> None:
    route = a_route()
    with pytest.raises(RouteError, match="needs omega_truth"):
        route_truth(DriveLog(route.t, route.omega, name="x"))
    no_truth = DriveLog(route.t, route.omega, None, route.heading_truth, None, route.speed)
    with pytest.raises(RouteError, match="needs omega_truth"):
        route_truth(no_truth)  # without route metadata, omega is a gyro, not a truth
    assert route_truth(replace(no_truth, meta={"route": "yes"}))[3] == 200.0
    assert route.speed is not None
    gap = route.speed.copy()
    gap[10] = np.nan
    with pytest.raises(RouteError, match="known at every row"):
        route_truth(DriveLog(route.t, route.omega, None, route.heading_truth, route.omega, gap))
    blind = np.full(len(route), np.nan)
    with pytest.raises(RouteError, match="no heading_truth"):
        route_truth(DriveLog(route.t, route.omega, None, blind, route.omega, route.speed))
    with pytest.raises(ValueError, match="hz must be > 0"):
        road_drive(route, GyroModel(()), 1, hz=0.0)


def test_road_drive_columns_lead_in_and_exact_heading() -> None:
    route = a_route()
    log = road_drive(route, grade_model("crs03"), seed=3, hz=10.0, lead_in_s=30.0)
    assert log.columns() == [
        "t", "omega", "temp_c", "heading_truth", "omega_truth", "speed", "gps_course", "gps_speed",
    ]  # fmt: skip
    assert log.rate_hz == pytest.approx(10.0) and log.t[0] == 0.0
    assert log.duration_s == pytest.approx(30.0 + route.duration_s, abs=0.1)
    assert log.meta["lead_in_s"] == "30" and log.meta["route"] == "r"
    assert log.omega_truth is not None and log.speed is not None and log.heading_truth is not None
    assert route.omega_truth is not None
    lead = log.t < 30.0
    assert np.all(log.omega_truth[lead] == 0.0) and np.all(log.speed[lead] == 0.0)
    # The route, shifted by the lead-in and resampled.
    later = ~lead
    expect = np.interp(log.t[later] - 30.0, route.t - route.t[0], route.omega_truth)
    np.testing.assert_allclose(log.omega_truth[later], expect)
    # The heading: exact with omega_truth at every row, starting at the route's.
    np.testing.assert_allclose(log.heading_truth, heading_from_rate(log.t, log.omega_truth, 200.0))
    assert np.isfinite(log.heading_truth).all()
    # Resampling keeps the route's heading within a small fraction of a degree.
    assert route.heading_truth is not None and route.omega_truth is not None
    back = np.interp(route.t + 30.0, log.t, np.unwrap(log.heading_truth, period=360.0))
    err = wrap180(back - route.heading_truth)
    assert np.max(np.abs(err[route.t < route.t[-1] - 0.2])) < 0.2


def test_gps_course_is_a_noisy_one_hertz_course_above_its_speed() -> None:
    log = road_drive(a_route(), GyroModel(()), seed=4, gps=GpsModel(floor_deg=1.0))
    assert log.gps_course is not None and log.gps_speed is not None and log.speed is not None
    assert log.heading_truth is not None
    fixes = np.flatnonzero(np.isfinite(log.gps_course))
    assert np.all(np.diff(log.t[fixes]) >= 0.99)  # at most one per second
    assert np.all(log.speed[fixes] >= 2.0) and fixes.shape[0] > 250
    np.testing.assert_array_equal(np.isfinite(log.gps_speed), np.isfinite(log.gps_course))
    np.testing.assert_array_equal(log.gps_speed[fixes], log.speed[fixes])
    err = wrap180(log.gps_course[fixes] - log.heading_truth[fixes])
    assert 0.7 < float(np.std(err)) < 1.5 and abs(float(np.mean(err))) < 0.2


def test_deterministic_per_seed_and_the_gyro_changes_only_omega() -> None:
    route = a_route()
    a = road_drive(route, grade_model("phone", 8), seed=8)
    b = road_drive(route, grade_model("phone", 8), seed=8)
    for c in a.columns():
        np.testing.assert_array_equal(getattr(a, c), getattr(b, c))
    other = road_drive(route, grade_model("tactical", 8), seed=8)
    for c in ("temp_c", "heading_truth", "gps_course", "speed"):
        np.testing.assert_array_equal(getattr(a, c), getattr(other, c))
    assert not np.array_equal(a.omega, other.omega)
    again = road_drive(route, grade_model("phone", 8), seed=9)
    assert a.temp_c is not None and again.temp_c is not None
    assert not np.array_equal(a.temp_c, again.temp_c)


def test_the_motion_offset_reads_only_while_moving_and_the_cabin_warms() -> None:
    route = a_route()
    model = GyroModel((StaticBias(bias_dps=0.5), MotionOffset(offset_dps=0.02)))
    cabin = CabinTemperature(start_c=5.0, end_c=21.0, tau_s=100.0)
    log = road_drive(route, model, seed=1, temperature=cabin)
    assert log.omega_truth is not None and log.speed is not None and log.temp_c is not None
    err = log.omega - log.omega_truth
    moving = log.speed > 0.5
    np.testing.assert_allclose(err[moving], 0.52)
    np.testing.assert_allclose(err[~moving], 0.5)
    assert log.temp_c[:10].mean() == pytest.approx(5.0, abs=0.2)
    assert log.temp_c[-10:].mean() > 18.0


def test_grade_on_road_takes_the_grade_its_rate_and_the_offset(tmp_path: Path) -> None:
    route = a_route()
    log = grade_on_road(route, "automotive", 2, motion_offset_dps=-0.01)
    assert log.rate_hz == pytest.approx(80.0) and log.name == "r-automotive-mo-2"
    assert '"motion_offset"' in log.meta["gyro_model"] and log.meta["grade"] == "automotive"
    plain = grade_on_road(route, "automotive", 2, hz=10.0)
    assert plain.name == "r-automotive-2" and '"motion_offset"' not in plain.meta["gyro_model"]
    assert plain.rate_hz == pytest.approx(10.0)
    # A drive log hdrd evaluate reads and calibrates over the lead-in.
    write_drive(tmp_path / "d.csv", plain)
    back = read_drive(tmp_path / "d.csv")
    assert back.meta["lead_in_s"] == "30" and back.columns() == plain.columns()
    prep = prepare_drive(back)
    assert prep.bias_source == "lead-in 30 s" and prep.k == 0 and prep.align_n == 1
    bias = grade_model("automotive", 2).get("static_bias")
    assert isinstance(bias, StaticBias)
    assert prep.steps.bias_dps == pytest.approx(bias.bias_dps, abs=0.15)  # plus its temperature


def test_white_noise_is_the_grade_rate_s() -> None:
    # The gyro runs on the resampled grid: its white noise is that of its own rate.
    route = a_route(600.0)
    log = road_drive(route, GyroModel((WhiteNoise(density_dps_per_rthz=0.05),)), 1, hz=100.0)
    assert log.omega_truth is not None
    assert float(np.std(log.omega - log.omega_truth)) == pytest.approx(0.5, rel=0.05)


def test_route_stops_and_a_drive_from_one() -> None:
    route = a_route()
    stops = route_stops(route)
    assert len(stops) == 2 and stops[0][0] == 0.0 and stops[0][1] == pytest.approx(5.0, abs=0.11)
    assert stops[1][0] == pytest.approx(150.0, abs=0.11) and stops[1][1] == pytest.approx(
        170.0, abs=0.11
    )
    start = stops[1][0] + 1.0
    log = grade_on_road(route, "crs03", 5, start_s=start, lead_in_s=20.0)
    assert log.name == f"r-crs03-5-at{start:g}" and log.meta["route_start_s"] == f"{start:g}"
    assert log.duration_s == pytest.approx(20.0 + route.duration_s - start, abs=0.1)
    assert log.speed is not None and log.heading_truth is not None and log.omega_truth is not None
    assert np.all(log.speed[log.t < 20.0 + 15.0] == 0.0)  # the lead-in, then the rest of the stop
    # The heading where the route stood at start_s, and the route's rate from there on.
    assert route.heading_truth is not None and route.omega_truth is not None
    at = np.interp(start, route.t, np.unwrap(route.heading_truth, period=360.0)) % 360.0
    assert log.heading_truth[0] == pytest.approx(at, abs=0.05)
    later = log.t >= 20.0
    expect = np.interp(log.t[later] - 20.0 + start, route.t, route.omega_truth)
    np.testing.assert_allclose(log.omega_truth[later], expect)
    with pytest.raises(ValueError, match="start_s must be in"):
        road_drive(route, GyroModel(()), 1, start_s=route.duration_s + 1.0)
