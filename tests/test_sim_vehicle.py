"""The simulated drive: heading conventions, truth at GPS epochs, smooth motion, determinism,
the character of each road type, cabin temperature and GPS noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hdrd.core.angles import wrap180
from hdrd.io.files.drivelog import DriveLog
from hdrd.sim import (
    DRIVE_TYPES,
    CabinTemperature,
    GpsModel,
    GyroModel,
    MotionOffset,
    StaticBias,
    count_turns,
    gps_course,
    heading_from_rate,
    simulate_drive,
)

_cache: dict[tuple[str, float, int], DriveLog] = {}


def drive(kind: str, minutes: float = 8.0, seed: int = 1) -> DriveLog:
    key = (kind, minutes, seed)
    if key not in _cache:
        _cache[key] = simulate_drive(kind, minutes, seed)
    return _cache[key]


def stops(log: DriveLog) -> int:
    """Standstill episodes after the start of the drive."""
    assert log.speed is not None
    s = (log.speed < 0.1) & (log.t > float(log.meta["lead_in_s"]) + 5.0)
    return int(np.sum(np.diff(s.astype(np.int8)) == 1))


def curving_fraction(log: DriveLog) -> float:
    """Share of the moving time spent turning faster than 1 deg/s."""
    assert log.speed is not None and log.omega_truth is not None
    moving = log.speed > 1.0
    return float(np.mean(np.abs(log.omega_truth[moving]) > 1.0))


@pytest.mark.parametrize("kind", ["city", "suburbs", "mixed"])
def test_heading_truth_is_minus_the_integral_of_the_yaw_rate(kind: str) -> None:
    log = drive(kind)
    assert log.heading_truth is not None and log.omega_truth is not None and log.speed is not None
    h0 = float(log.meta["heading0_deg"])
    # Independent integration (rectangles on a 10x finer interpolated grid): compass heading
    # is clockwise, yaw counter-clockwise, so heading = heading0 - integral(omega).
    fine_t = np.linspace(log.t[0], log.t[-1], 10 * (len(log) - 1) + 1)
    fine_w = np.interp(fine_t, log.t, log.omega_truth)
    yaw = np.concatenate(([0.0], np.cumsum(fine_w[1:]) * (fine_t[1] - fine_t[0])))[::10]
    ok = np.isfinite(log.heading_truth)
    err = wrap180(log.heading_truth[ok] - (h0 - yaw[ok]))
    # GPS course noise: ~atan(0.08 / v) rad, at most ~2.3 deg at the 2 m/s threshold.
    assert np.max(np.abs(err)) < 12.0
    assert np.mean(np.abs(err)) < 0.8
    assert np.all((log.heading_truth[ok] >= 0) & (log.heading_truth[ok] < 360))


def test_a_left_turn_lowers_the_compass_heading() -> None:
    t = np.arange(0, 20, 0.1)
    omega = np.where((t > 5) & (t < 14), 10.0, 0.0)  # 90 deg counter-clockwise (left)
    h = heading_from_rate(t, omega, 10.0)
    assert h[0] == 10.0
    assert h[-1] == pytest.approx(280.0, abs=1.0)  # from 10 deg (NNE) left to 280 deg (W)


def test_heading_truth_only_at_one_hertz_epochs_and_above_the_speed_threshold() -> None:
    log = drive("city")
    assert log.heading_truth is not None and log.speed is not None
    ok = np.isfinite(log.heading_truth)
    assert ok.sum() > 100
    np.testing.assert_allclose(log.t[ok], np.round(log.t[ok]), atol=1e-9)
    assert np.all(log.speed[ok] >= 2.0)
    epochs = np.isclose(log.t, np.round(log.t), atol=1e-9)
    fast = log.speed >= 2.0
    assert np.array_equal(ok, epochs & fast)  # no outages by default


def test_lead_in_is_standstill_with_the_raw_bias() -> None:
    log = simulate_drive("highway", 2.0, 5, model=GyroModel((StaticBias(0.75),)), lead_in_s=20.0)
    assert log.speed is not None and log.omega_truth is not None
    lead = log.t < 20.0
    assert lead.sum() == 200
    assert np.all(log.speed[lead] == 0) and np.all(log.omega_truth[lead] == 0)
    np.testing.assert_allclose(log.omega, log.omega_truth + 0.75, atol=1e-12)
    assert log.duration_s == pytest.approx(20.0 + 120.0 - 0.1)
    assert log.speed[~lead].max() > 20.0


def test_the_gyro_reads_a_motion_offset_while_the_car_moves() -> None:
    """A motion-dependent bias in the model: the gyro reads it while the car moves and not at
    its stops (the lead-in and the traffic lights), the truth unchanged."""
    model = GyroModel((StaticBias(0.5), MotionOffset(offset_dps=0.09)))
    log = simulate_drive("city", 4.0, 3, model=model, lead_in_s=20.0)
    plain = simulate_drive("city", 4.0, 3, model=GyroModel((StaticBias(0.5),)), lead_in_s=20.0)
    assert log.speed is not None and log.omega_truth is not None
    np.testing.assert_array_equal(log.omega_truth, plain.omega_truth)
    moving = log.speed > 0.5
    assert (~moving[log.t > 60.0]).sum() > 100  # a stop after the lead-in
    np.testing.assert_allclose(log.omega - plain.omega, np.where(moving, 0.09, 0.0), atol=1e-12)


@pytest.mark.parametrize("kind", ["city", "suburbs", "rural", "highway", "mixed"])
def test_motion_is_physically_smooth(kind: str) -> None:
    log = drive(kind)
    assert log.omega_truth is not None and log.speed is not None
    yaw_acc = np.diff(log.omega_truth) * 10.0
    assert np.max(np.abs(yaw_acc)) < 80.0  # deg/s^2: continuous rate, finite acceleration
    assert np.max(np.abs(np.diff(yaw_acc))) * 10.0 < 400.0  # deg/s^3: no kinks worth the name
    assert np.max(np.abs(np.diff(log.speed))) * 10.0 < 2.5  # m/s^2
    assert np.min(log.speed) >= 0.0
    assert np.max(np.abs(log.omega_truth)) < 60.0


def test_deterministic_by_seed_and_model_independent_truth() -> None:
    a = simulate_drive("mixed", 3.0, 11)
    b = simulate_drive("mixed", 3.0, 11)
    c = simulate_drive("mixed", 3.0, 12)
    for col in ("omega", "omega_truth", "heading_truth", "speed", "temp_c"):
        np.testing.assert_array_equal(getattr(a, col), getattr(b, col))
    assert a.omega_truth is not None and c.omega_truth is not None
    assert not np.allclose(a.omega_truth, c.omega_truth)
    d = simulate_drive("mixed", 3.0, 11, model=GyroModel((StaticBias(0.1),)))
    np.testing.assert_array_equal(a.heading_truth, d.heading_truth)
    np.testing.assert_array_equal(a.omega_truth, d.omega_truth)
    assert not np.array_equal(a.omega, d.omega)


def test_city_has_corners_and_stops() -> None:
    log = drive("city", 10.0, 2)
    assert log.omega_truth is not None
    assert count_turns(log.t, log.omega_truth) >= 3
    assert stops(log) >= 2


def test_suburbs_are_mostly_curving() -> None:
    sub = curving_fraction(drive("suburbs", 10.0, 2))
    assert sub > 0.35
    for other in ("city", "rural", "highway"):
        assert sub > 3 * curving_fraction(drive(other, 10.0, 2))


def test_highway_is_fast_and_gentle() -> None:
    log = drive("highway", 10.0, 2)
    assert log.omega_truth is not None and log.speed is not None
    assert log.speed[log.t > 60].mean() > 25.0
    assert stops(log) == 0
    assert np.max(np.abs(log.omega_truth)) < 5.0
    assert count_turns(log.t, log.omega_truth) == 0


def test_rural_is_mostly_straight_at_country_speed() -> None:
    log = drive("rural", 10.0, 2)
    assert log.speed is not None
    assert 16.0 < log.speed[log.t > 60].mean() < 25.0
    assert curving_fraction(log) < 0.2


def test_mixed_has_rural_highway_and_city_parts() -> None:
    log = drive("mixed", 15.0, 2)
    assert log.speed is not None
    n = len(log)
    first, middle, last = (
        log.speed[: n // 3],
        log.speed[n // 3 : 2 * n // 3],
        log.speed[2 * n // 3 :],
    )
    assert middle.mean() > 25.0  # highway
    assert 15.0 < first[first > 1].mean() < 25.0  # rural
    assert last.mean() < 14.0  # city


def test_standstill_drive() -> None:
    log = drive("standstill", 2.0)
    assert log.speed is not None and log.omega_truth is not None and log.heading_truth is not None
    assert np.all(log.speed == 0) and np.all(log.omega_truth == 0)
    assert np.all(np.isnan(log.heading_truth))
    assert abs(np.mean(log.omega) - 1.0) < 0.3  # the default static bias, plus temperature effects


def test_cabin_temperature_warms_up() -> None:
    log = simulate_drive(
        "city", 20.0, 3, temperature=CabinTemperature(5.0, 21.0, 300.0, noise_c=0.0)
    )
    assert log.temp_c is not None
    np.testing.assert_allclose(log.temp_c[0], 5.0)
    assert np.all(np.diff(log.temp_c) >= 0)
    end = log.t[-1]
    cabin = 5.0 + 16.0 * (1 - math.exp(-(end - 30.0) / 300.0))
    board = 1.0 * (1 - math.exp(-end / 300.0))
    assert log.temp_c[-1] == pytest.approx(cabin + board, abs=1e-9)
    # During the lead-in only the board warms (the heater comes on when the drive starts).
    assert log.temp_c[299] - log.temp_c[0] < 0.15
    profile = CabinTemperature(10.0, 20.0, 100.0, on_s=50.0, self_heat_c=0.0, noise_c=0.0)
    t = np.array([0.0, 50.0, 150.0])
    np.testing.assert_allclose(
        profile.profile(t, 0.0, np.random.default_rng(0)),
        [10.0, 10.0, 10.0 + 10 * (1 - math.exp(-1))],
    )


def test_count_turns_on_a_hand_made_trace() -> None:
    t = np.arange(0, 100, 0.1)
    w = np.zeros_like(t)
    w[(t >= 10) & (t < 19)] = 10.0  # left 90
    w[(t >= 30) & (t < 36)] = -15.0  # right 90
    w[(t >= 50) & (t < 59)] = 5.0  # 45 deg curve
    w[(t >= 70) & (t < 80)] = 18.0  # 180 deg U-turn
    w += 0.2 * np.sin(t * 3)  # swaying
    assert count_turns(t, w) == 2


def test_other_sample_rates() -> None:
    log = simulate_drive("city", 1.0, 4, hz=50.0)
    assert log.rate_hz == pytest.approx(50.0)
    assert len(log) == 50 * 90
    ok = np.isfinite(log.heading_truth)  # type: ignore[arg-type]
    np.testing.assert_allclose(log.t[ok], np.round(log.t[ok]), atol=1e-9)


def test_unknown_drive_type() -> None:
    with pytest.raises(ValueError, match="unknown drive type 'moon'.*city"):
        simulate_drive("moon", 1.0, 1)
    assert set(DRIVE_TYPES) == {"city", "suburbs", "rural", "highway", "mixed", "standstill"}


def test_gps_noise_grows_at_low_speed_and_outages_blank_epochs() -> None:
    n = 36_000
    t = np.arange(n) / 10.0
    heading = np.full(n, 359.9)
    rng = np.random.default_rng(0)
    slow = gps_course(t, heading, np.full(n, 3.0), rng)
    fast = gps_course(t, heading, np.full(n, 30.0), rng)
    e_slow = wrap180(slow[np.isfinite(slow)] - 359.9)
    e_fast = wrap180(fast[np.isfinite(fast)] - 359.9)
    assert np.std(e_slow) == pytest.approx(math.degrees(math.atan(0.08 / 3.0)), rel=0.15)
    assert np.std(e_slow) > 5 * np.std(e_fast)
    assert np.isfinite(fast).sum() == 3600
    parked = gps_course(t, heading, np.full(n, 1.9), rng)
    assert np.all(np.isnan(parked))
    gappy = gps_course(
        t, heading, np.full(n, 30.0), rng, GpsModel(outages_per_hour=20.0, outage_s=(30.0, 30.0))
    )
    missing = 3600 - int(np.isfinite(gappy).sum())
    assert 60 <= missing <= 20 * 2 * 30
