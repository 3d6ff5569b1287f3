"""hdrd.core.standstill: the standstill detector on single steps, its parameters and limits,
a block mean's variance, and what a calibration window says of the gyro's noise (sample
rate, white noise, quantization step). Pure. Rates deg/s, + = CCW; speeds m/s.

The detector over step sequences inside HDR+ and the bias refined at stops (the zero-rate
update): test_zupt.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hdrd.core import standstill as zupt
from hdrd.core.standstill import StopDetection, block_mean_variance, standstill_candidate

NAN = math.nan
SS = StopDetection()


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
    off = StopDetection(gyro_only=False)
    assert standstill_candidate(0.0, 0.05, NAN, off)[0] is False
    on = StopDetection(gyro_only=True, steps_gyro=7)
    assert standstill_candidate(0.0, 0.05, NAN, on) == (True, 7)
    assert standstill_candidate(0.0, on.gyro_spread_dps * 1.5, NAN, on)[0] is False  # not quiet
    assert standstill_candidate(on.gyro_level_dps * 2, 0.05, NAN, on)[0] is False  # rotating
    assert standstill_candidate(0.0, NAN, NAN, on)[0] is False  # nothing to judge by
    assert standstill_candidate(0.0, 0.0, 0.0, StopDetection(enabled=False))[0] is False


def test_params_are_checked() -> None:
    with pytest.raises(ValueError, match="speed_mps"):
        StopDetection(speed_mps=-1.0)
    with pytest.raises(ValueError, match="steps_gyro"):
        StopDetection(steps_gyro=0)
    with pytest.raises(ValueError, match="samples_per_step"):
        StopDetection(samples_per_step=0.0)


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


def test_every_standstill_limit_is_inclusive() -> None:
    at = StopDetection(gyro_only=True)
    assert standstill_candidate(0.0, at.spread_dps, 0.0, at)[0] is True
    assert standstill_candidate(at.level_dps, 0.1, 0.0, at)[0] is True
    assert standstill_candidate(-at.level_dps, 0.1, 0.0, at)[0] is True
    assert standstill_candidate(0.0, at.gyro_spread_dps, NAN, at)[0] is True
    assert standstill_candidate(at.gyro_level_dps, 0.05, NAN, at)[0] is True
    assert standstill_candidate(-at.gyro_level_dps, 0.05, NAN, at)[0] is True


def test_one_sample_per_step_is_allowed() -> None:
    # a 1 Hz log averages one sample per step of 1 s
    assert StopDetection(samples_per_step=1.0).samples_per_step == 1.0
    assert StopDetection(samples_per_step=0.5).samples_per_step == 0.5
    with pytest.raises(ValueError, match="samples_per_step must be > 0"):
        StopDetection(samples_per_step=0.0)


def test_block_mean_variance_adds_the_floor_in_quadrature() -> None:
    ss = StopDetection(samples_per_step=4.0, noise_floor_dps=0.5, spread_dps=2.0)
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
