"""The zero-rate update inside HDR+: standstill detected over step sequences and the bias refined
at stops (hdrd/core/standstill.py, hdrd/core/biasbank.py through hdrd/core/hdrplus.py). The
detector alone, step by step, and the calibration window's noise: test_standstill.py.

Rates in deg/s, + = CCW; speeds m/s; temperatures degC. Inputs are hand-made step sequences
(block mean u = raw mean - eps0, within-block spread), not simulator output, so each test
states exactly what the detector sees.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hdrd.core import biasbank as bb
from hdrd.core.hdrplus import INITIAL_PLUS_STATE, HdrPlusParams, run_batch, step
from hdrd.core.plusparams import one_model
from hdrd.core.standstill import StandstillParams, block_mean_variance
from hdrd.core.steps import StepInput
from tests.test_hdrplus import plus

NAN = math.nan
SS = StandstillParams()


# -- the detector over step sequences, inside HDR+ -------------------------------------------


def _run(
    u: list[float], spread: list[float], speed: list[float], params: HdrPlusParams
) -> np.ndarray:
    return run_batch(u, spread, speed, None, 1.0, params).standstill


def test_a_stationary_block_sequence_is_detected_with_speed() -> None:
    n, k = 20, SS.steps_speed
    still = _run([0.01] * n, [0.15] * n, [0.0] * n, HdrPlusParams())
    assert still.tolist() == [False] * (k - 1) + [True] * (n - k + 1)
    one = HdrPlusParams(standstill=StandstillParams(steps_speed=1))
    assert _run([0.01] * n, [0.15] * n, [0.0] * n, one).all()


def test_a_halt_shorter_than_steps_speed_is_not_used() -> None:
    # A rolling halt between two manoeuvres (one or two steps at zero speed, the car still
    # yawing as it brakes) must not be taken for a bias measurement.
    u = [2.0] * 5 + [-0.1, -0.1] + [-2.0] * 5
    speed = [1.0] * 5 + [0.0, 0.0] + [1.0] * 5
    tr = run_batch(u, [0.2] * 12, speed, None, 1.0, HdrPlusParams())
    assert not tr.standstill.any()
    assert np.all(np.abs(tr.bias_corr_dps) < 0.01)


def test_a_slow_straight_drive_is_not_detected() -> None:
    n = 30
    still = _run([0.01] * n, [0.15] * n, [2.0] * n, HdrPlusParams())
    assert not still.any()


def test_gyro_only_detection_requires_quiet_for_several_steps() -> None:
    p = HdrPlusParams(standstill=StandstillParams(gyro_only=True, steps_gyro=5))
    quiet = [0.02] * 12
    still = _run(quiet, [0.1] * 12, [NAN] * 12, p)
    assert still.tolist() == [False] * 4 + [True] * 8
    # A loud step (a bump) restarts the count; so does a rotating one.
    spread = [0.1] * 12
    spread[6] = 1.0
    still = _run(quiet, spread, [NAN] * 12, p)
    assert still.tolist() == [False] * 4 + [True] * 2 + [False] * 5 + [True]
    rot = list(quiet)
    rot[3] = 0.5
    assert _run(rot, [0.1] * 12, [NAN] * 12, p).tolist() == [False] * 8 + [True] * 4
    # Without the switch, an unknown speed never means standstill.
    assert not _run(quiet, [0.1] * 12, [NAN] * 12, HdrPlusParams()).any()


def test_yaw_does_not_move_at_standstill() -> None:
    # Driving with a residual bias makes yaw move; at standstill omega is 0 whatever u is.
    u = [0.2] * 75
    speed = [10.0] * 10 + [0.0] * 60 + [10.0] * 5
    tr = run_batch(u, [0.15] * 75, speed, None, 1.0, HdrPlusParams())
    yaw = tr.yaw - np.cumsum(tr.heading_fix_deg)  # without the heading fix
    a = 10 + SS.steps_speed - 1  # the first zero-rate update
    assert tr.standstill.tolist() == [False] * a + [True] * (70 - a) + [False] * 5
    assert np.all(tr.omega[a:70] == 0.0)
    assert np.allclose(yaw[a:70], yaw[a - 1], rtol=0.0, atol=1e-12)
    assert yaw[a - 1] > 1.0
    # ... and after the stop most of the bias it measured (0.2) is removed: the estimate
    # weighs the stop against its prior (the start-up eps0) and a bias that could not have
    # moved much in 10 s, so not all of it at once.
    assert abs(tr.omega[70]) < 0.3 * 0.2
    assert tr.bias_corr_dps[69] == pytest.approx(0.2, abs=0.06)
    # With the heading fix (the default), the yaw moves at a stop only by the correction of
    # what the bias error bent it while driving (the car did not turn: the truth is 0). A
    # bias 0.2 deg/s off after 10 s is evidence of a drifting gyro (weight 0.99 at the stop),
    # whose filter ties only part of the old heading error to today's bias: a third of it.
    fix = run_batch(u, [0.15] * 75, speed, None, 1.0, HdrPlusParams())
    assert np.all(fix.omega[a:70] == 0.0)
    moved = np.diff(fix.yaw[a - 1 : 70])
    assert np.allclose(moved, fix.heading_fix_deg[a:70], rtol=0.0, atol=1e-12)
    assert abs(fix.yaw[69]) < 0.7 * abs(fix.yaw[a - 1])


def test_zero_rate_update_through_step_publishes_standstill() -> None:
    # A start-up bias known to +-1 deg/s only; stops count from their first step.
    vague = plus(bias_p0=1.0, standstill=StandstillParams(steps_speed=1))
    s = INITIAL_PLUS_STATE
    s, o = step(s, StepInput(0.5, 0.1, 0.0, NAN, 1.0), vague)
    assert o.standstill and o.omega == 0.0 and o.yaw == 0.0 and o.W == 0
    assert o.bias_corr_dps == pytest.approx(0.5, rel=0.01)
    s, o = step(s, StepInput(0.5, 0.1, 5.0, NAN, 1.0), vague)
    assert not o.standstill and abs(o.omega) < 0.05


# -- bias refinement ----------------------------------------------------------------------------


def test_bias_converges_to_the_true_bias_on_a_noisy_stationary_segment() -> None:
    rng = np.random.default_rng(1)
    true_bias, sigma, n_samples, steps = 0.137, 0.16, 10, 120
    # Block means of n_samples white samples: the spread is sigma, the mean's noise sigma/sqrt(n).
    u = true_bias + sigma / math.sqrt(n_samples) * rng.standard_normal(steps)
    # A bias that does not wander (q = 0) and a vague start-up prior: the filter's answer
    # is then the mean of the block means, as good as the samples allow.
    p = plus(bias_p0=1.0, bank=one_model(0.0))
    tr = run_batch(u, np.full(steps, sigma), np.zeros(steps), None, 1.0, p)
    used = steps - (SS.steps_speed - 1)  # the first steps of a stop are not measurements
    expect_sd = math.sqrt(sigma**2 + SS.noise_floor_dps**2) / math.sqrt(n_samples * used)
    assert abs(tr.bias_corr_dps[-1] - true_bias) < 4 * expect_sd
    # The filter knows how well it knows: its standard deviation is about that of the mean.
    assert tr.bias_sd_dps[-1] == pytest.approx(expect_sd, rel=0.15)
    assert np.all(np.diff(tr.bias_sd_dps[SS.steps_speed - 1 :]) <= 0)


def test_a_wandering_bias_is_followed_from_stop_to_stop() -> None:
    # Without temperature, a bias random walk of 4e-5 (deg/s)^2/s (a CRS03-04 in a warming
    # cabin): a later stop that sees a different bias moves the estimate most of the way.
    # With the default, a slow random walk (a good gyro), it moves much less: the 40 s
    # between the stops could not have moved a good gyro's bias by 0.08 deg/s.
    n = 40
    u = [0.10] * n + [0.18] * n
    speed = [0.0] * (2 * n)
    fast = plus(bias_p0=1.0, stop_offset_var=0.0, bank=one_model(4e-5))
    tr = run_batch(u, [0.15] * (2 * n), speed, None, 1.0, fast)
    assert tr.bias_corr_dps[n - 1] == pytest.approx(0.10, abs=0.005)
    assert tr.bias_corr_dps[-1] == pytest.approx(0.18, abs=0.01)
    slow = run_batch(u, [0.15] * (2 * n), speed, None, 1.0, plus(bias_p0=1.0, bank=one_model(3e-7)))
    assert 0.10 < slow.bias_corr_dps[-1] < 0.16


def _weighted_mean(z: list[float], r: list[float]) -> float:
    w = [1 / v for v in r]
    return sum(wi * zi for wi, zi in zip(w, z, strict=True)) / sum(w)


def test_stops_weigh_by_duration_and_quietness() -> None:
    # With a vague prior and no random walk, the estimate is the inverse-variance weighted
    # mean of the stops' block means: a long stop outweighs a short one, a quiet one a loud one.
    ss = StandstillParams()
    stops = [(0.10, 0.1, 20), (0.20, 0.4, 20), (0.40, 0.1, 2)]  # (bias seen, spread, steps)
    f = bb.prior(1e6, 0.0, 0.0, 0.0)
    x, P = list(f.x), list(f.P)
    z: list[float] = []
    r: list[float] = []
    for bias, spread, steps in stops:
        for _ in range(steps):
            var = block_mean_variance(spread, ss)
            bb.update(x, P, 1.0, 0.0, 0.0, bias, var)
            z.append(bias)
            r.append(var)
    assert x[bb.B] == pytest.approx(_weighted_mean(z, r), abs=1e-6)
    # The quiet 20-step stop dominates: the estimate sits near 0.10, not at the plain mean.
    plain = float(np.mean([s[0] for s in stops]))
    assert abs(x[bb.B] - 0.10) < abs(x[bb.B] - plain) / 2


def test_temperature_coefficient_is_learned_from_stops_at_different_temperatures() -> None:
    b_true, k_true, t0 = 0.05, 0.009, 8.0
    p = plus(bias_p0=1.0)
    u, spread, speed, temp = [], [], [], []
    for t_c in (8.0, 12.0, 16.0, 20.0):
        for _ in range(15):
            u.append(b_true + k_true * (t_c - t0))
            spread.append(0.1)
            speed.append(0.0)
            temp.append(t_c)
    tr = run_batch(u, spread, speed, temp, 1.0, p)
    assert tr.temp_coeff_dps_per_c[-1] == pytest.approx(k_true, rel=0.05)
    assert tr.bias_corr_dps[-1] == pytest.approx(b_true + k_true * 12.0, abs=2e-3)


# -- limits and exact arithmetic (each assertion pins one comparison or formula) ----------------
