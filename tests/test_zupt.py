"""Standstill detection (hdrd/core/standstill.py) and the bias refinement at stops, alone and inside HDR+.

Rates in deg/s, + = CCW; speeds m/s; temperatures degC. Inputs are hand-made step sequences
(block mean u = raw mean - eps0, within-block spread), not simulator output, so each test
states exactly what the detector sees.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hdrd.core import biasbank as bb
from hdrd.core import standstill as zupt
from hdrd.core.hdrplus import INITIAL_PLUS_STATE, HdrPlusParams, run_batch, step
from hdrd.core.standstill import StandstillParams, block_mean_variance, standstill_candidate
from hdrd.core.steps import StepInput

NAN = math.nan
SS = StandstillParams()


# -- the detector on single steps ----------------------------------------------------------


def test_stopped_and_quiet_with_speed_is_a_candidate() -> None:
    assert standstill_candidate(0.02, 0.15, 0.0, SS) == (True, SS.steps_speed)
    assert SS.steps_speed < SS.steps_gyro  # speed is trusted sooner than the gyro alone


def test_slow_straight_drive_above_the_speed_threshold_is_not_standstill() -> None:
    # 1.5 m/s, no rotation, a gyro as quiet as at rest: speed alone says "moving".
    assert standstill_candidate(0.0, 0.1, 1.5, SS)[0] is False
    assert standstill_candidate(0.0, 0.1, SS.speed_mps + 1e-9, SS)[0] is False
    assert standstill_candidate(0.0, 0.1, SS.speed_mps, SS)[0] is True


def test_speed_zero_but_gyro_rotating_is_not_standstill() -> None:
    # A car cannot turn on the spot: a stale speed must not freeze a real turn.
    assert standstill_candidate(5.0, 0.2, 0.0, SS)[0] is False
    assert standstill_candidate(0.0, 2.0, 0.0, SS)[0] is False  # a bump or a turn in the block


def test_unknown_spread_is_not_checked_when_speed_is_known() -> None:
    assert standstill_candidate(0.0, NAN, 0.0, SS)[0] is True


def test_gyro_only_needs_its_switch_quiet_and_several_steps() -> None:
    off = StandstillParams(gyro_only=False)
    assert standstill_candidate(0.0, 0.05, NAN, off)[0] is False
    on = StandstillParams(gyro_only=True, steps_gyro=7)
    assert standstill_candidate(0.0, 0.05, NAN, on) == (True, 7)
    assert standstill_candidate(0.0, on.gyro_spread_dps * 1.5, NAN, on)[0] is False  # not quiet
    assert standstill_candidate(on.gyro_level_dps * 2, 0.05, NAN, on)[0] is False  # rotating
    assert standstill_candidate(0.0, NAN, NAN, on)[0] is False  # nothing to judge by
    assert standstill_candidate(0.0, 0.0, 0.0, StandstillParams(enabled=False))[0] is False


def test_params_are_checked() -> None:
    with pytest.raises(ValueError, match="speed_mps"):
        StandstillParams(speed_mps=-1.0)
    with pytest.raises(ValueError, match="steps_gyro"):
        StandstillParams(steps_gyro=0)
    with pytest.raises(ValueError, match="samples_per_step"):
        StandstillParams(samples_per_step=0.0)


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
    still = HdrPlusParams().ablated(heading_fix=False)
    tr = run_batch(u, [0.15] * 75, speed, None, 1.0, still)
    a = 10 + SS.steps_speed - 1  # the first zero-rate update
    assert tr.standstill.tolist() == [False] * a + [True] * (70 - a) + [False] * 5
    assert np.all(tr.omega[a:70] == 0.0)
    assert np.all(tr.yaw[a:70] == tr.yaw[a - 1])
    assert tr.yaw[a - 1] > 1.0
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
    vague = HdrPlusParams(bias_p0=1.0, standstill=StandstillParams(steps_speed=1))
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
    p = HdrPlusParams(bias_p0=1.0, bias_q_no_temp=0.0, bank=False)
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
    fast = HdrPlusParams(bias_p0=1.0, bias_q_no_temp=4e-5, stop_offset_var=0.0, bank=False)
    tr = run_batch(u, [0.15] * (2 * n), speed, None, 1.0, fast)
    assert tr.bias_corr_dps[n - 1] == pytest.approx(0.10, abs=0.005)
    assert tr.bias_corr_dps[-1] == pytest.approx(0.18, abs=0.01)
    slow = run_batch(u, [0.15] * (2 * n), speed, None, 1.0, HdrPlusParams(bias_p0=1.0, bank=False))
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
    p = HdrPlusParams(bias_p0=1.0)
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


# -- what a calibration window says ---------------------------------------------------------------


def test_quantization_step_hand_cases() -> None:
    sixteenth = np.round(np.arange(-8, 9) / 16.0, 2)  # 1/16 deg/s printed with 2 decimals
    assert zupt.quantization_step(sixteenth) == pytest.approx(1 / 16, rel=0.15)
    assert zupt.quantization_step(np.arange(-20, 21) * 0.244) == pytest.approx(0.244)
    rng = np.random.default_rng(0)
    assert zupt.quantization_step(rng.normal(0.0, 0.1, 500)) == 0.0  # not on a lattice
    assert zupt.quantization_step([0.0, 0.244, 0.0]) == 0.0  # two codes: the step is unseen
    assert zupt.quantization_step([]) == 0.0


def test_calibration_noise_of_white_noise_at_100_hz() -> None:
    rng = np.random.default_rng(4)
    t = np.arange(3000) / 100.0
    w = 0.2 + 0.05 * rng.standard_normal(3000)
    c = zupt.calibration_noise(w, t, 1.0)
    assert c.samples_per_step == pytest.approx(100.0, rel=0.01)
    assert c.bias_var == pytest.approx(0.05**2 / 3000, rel=0.1)
    assert c.block_var == pytest.approx(0.05**2 / 100, rel=0.5)  # 30 step means
    assert c.quant_step_dps == 0.0 and c.codes == 3000
    q = np.round(w / 0.25) * 0.25  # a coarse ADC: almost every sample on one code
    c = zupt.calibration_noise(q, t, 1.0, quant_step_dps=0.25)
    assert c.quant_step_dps == 0.25 and c.codes <= 3
    with pytest.raises(ValueError):
        zupt.calibration_noise([0.1], [0.0])


# -- limits and exact arithmetic (each assertion pins one comparison or formula) ----------------


def test_every_standstill_limit_is_inclusive() -> None:
    at = StandstillParams(gyro_only=True)
    assert standstill_candidate(0.0, at.spread_dps, 0.0, at)[0] is True
    assert standstill_candidate(at.level_dps, 0.1, 0.0, at)[0] is True
    assert standstill_candidate(-at.level_dps, 0.1, 0.0, at)[0] is True
    assert standstill_candidate(0.0, at.gyro_spread_dps, NAN, at)[0] is True
    assert standstill_candidate(at.gyro_level_dps, 0.05, NAN, at)[0] is True
    assert standstill_candidate(-at.gyro_level_dps, 0.05, NAN, at)[0] is True


def test_one_sample_per_step_is_allowed() -> None:
    # a 1 Hz log averages one sample per step of 1 s
    assert StandstillParams(samples_per_step=1.0).samples_per_step == 1.0
    assert StandstillParams(samples_per_step=0.5).samples_per_step == 0.5
    with pytest.raises(ValueError, match="samples_per_step must be > 0"):
        StandstillParams(samples_per_step=0.0)


def test_block_mean_variance_adds_the_floor_in_quadrature() -> None:
    ss = StandstillParams(samples_per_step=4.0, noise_floor_dps=0.5, spread_dps=2.0)
    assert block_mean_variance(1.0, ss) == (1.0 + 0.25) / 4.0
    assert block_mean_variance(NAN, ss) == (4.0 + 0.25) / 4.0  # unknown: the largest allowed


def test_calibration_noise_counts_samples_per_step_from_the_span() -> None:
    w = np.tile([0.1, -0.1], 51)[:101]
    t = np.arange(101) / 10.0  # 10 Hz over exactly 10 s
    c = zupt.calibration_noise(w, t)  # the default step is 1 s
    assert c.samples_per_step == 10.0
    assert zupt.calibration_noise(w, t, 2.0).samples_per_step == 20.0
    late = t.copy()
    late[0] = -0.9  # a first sample further back: the span is from the first sample
    assert zupt.calibration_noise(w, late).samples_per_step == 100 / 10.9
    short = np.arange(6) / 10.0  # half a second: still 10 samples per second
    assert zupt.calibration_noise(w[:6], short).samples_per_step == pytest.approx(10.0)
    same = np.zeros(5)  # no span at all: one sample per step, no division by zero
    assert zupt.calibration_noise(w[:5], same).samples_per_step == 1.0


def test_calibration_noise_takes_two_samples_and_refuses_fewer_or_mismatched() -> None:
    c = zupt.calibration_noise([0.1, 0.3], [0.0, 0.1])
    assert c.bias_var == pytest.approx(0.02 / 2) and c.codes == 2
    for w, t in (([0.1], [0.0]), ([0.1, 0.2], [0.0, 0.1, 0.2]), ([0.1, np.inf], [0.0, 0.1])):
        with pytest.raises(ValueError, match="2 or more finite samples"):
            zupt.calibration_noise(w, t)


def test_calibration_noise_block_variance_from_whole_steps_only() -> None:
    # Three whole steps of 10 samples (means 0, 1, 2) and a last step of 2 samples (mean 50):
    # a step with fewer than half the samples per step does not count.
    w = np.concatenate([np.zeros(10), np.ones(10), np.full(10, 2.0), [50.0, 50.0]])
    t = np.arange(32) / 10.0
    c = zupt.calibration_noise(w, t, 1.0, quant_step_dps=0.0)
    assert c.samples_per_step == pytest.approx(10.0)
    assert c.block_var == pytest.approx(1.0)  # var([0, 1, 2], ddof=1)
    # steps of 2 s: one whole step (mean 0.5) and a part: too few for a variance of means
    c2 = zupt.calibration_noise(w, t, 2.0, quant_step_dps=0.0)
    assert c2.block_var == pytest.approx(float(np.var(w, ddof=1)) / c2.samples_per_step)


def test_calibration_noise_reads_the_output_step_when_not_given() -> None:
    rng = np.random.default_rng(3)
    w = 0.244 * np.round(rng.normal(0.0, 0.5, 300) / 0.244)
    c = zupt.calibration_noise(w, np.arange(300) / 10.0)
    assert c.quant_step_dps == pytest.approx(0.244)


def test_quantization_step_looks_at_the_central_half_first() -> None:
    # Dense codes on a 0.1 lattice in the middle, a few sparse values far out on a finer one:
    # the central half says 0.1; all values together would say nothing (0).
    w = np.array([-0.2] * 5 + [-0.1] * 10 + [0.0] * 10 + [0.1] * 10 + [0.2] * 5 + [5.0, 5.03, 5.06])
    assert zupt.quantization_step(w) == pytest.approx(0.1)
    # three codes in all, the middle half on one of them: the step is read from all three
    assert zupt.quantization_step([0.0, 0.0, 0.0, 0.0, 0.244, 0.488]) == pytest.approx(0.244)
