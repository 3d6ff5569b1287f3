"""The zero-rate update inside HDR+: standstill detected over step sequences and the bias
measured at stops (hdrd/core/standstill.py through hdrd/core/hdrplus.py). The detector alone,
step by step, and the calibration window's noise: test_standstill.py.

Rates in deg/s, + = CCW; speeds m/s; temperatures degC. Inputs are hand-made step sequences
(block mean u = raw mean - eps0, within-block spread), not simulator output, so each test
states exactly what the detector sees.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hdrd.core.hdrplus import INITIAL_PLUS_STATE, run_batch, step
from hdrd.core.plusparams import Hypothesis, PlusParams
from hdrd.core.standstill import StopDetection
from hdrd.core.steps import StepInput

NAN = math.nan
SS = StopDetection()


def one(q: float = 0.0, **kw: object) -> PlusParams:
    """A bank of one steady unit whose bias walks by q, (deg/s)^2/s, with a vague start-up
    prior (a bias known to +-1 deg/s) and no stop scatter, unless kw says otherwise."""
    base: dict[str, object] = {
        "bank": (Hypothesis("one", 1.0, q, 0.0, 0.0),),
        "bias_p0": 1.0,
        "stop_scatter_dps": 0.0,
    }
    base.update(kw)
    return PlusParams(**base)  # type: ignore[arg-type]


# -- the detector over step sequences, inside HDR+ -------------------------------------------


def _run(u: list[float], spread: list[float], speed: list[float], params: PlusParams) -> np.ndarray:
    return run_batch(u, spread, speed, None, 1.0, params).standstill


def test_a_stationary_block_sequence_is_detected_with_speed() -> None:
    n, k = 20, SS.steps_speed
    still = _run([0.01] * n, [0.15] * n, [0.0] * n, PlusParams())
    assert still.tolist() == [False] * (k - 1) + [True] * (n - k + 1)
    one = PlusParams(standstill=StopDetection(steps_speed=1))
    assert _run([0.01] * n, [0.15] * n, [0.0] * n, one).all()


def test_a_halt_shorter_than_steps_speed_is_not_used() -> None:
    # A rolling halt between two manoeuvres (one or two steps at zero speed, the car still
    # yawing as it brakes) must not be taken for a bias measurement.
    u = [2.0] * 5 + [-0.1, -0.1] + [-2.0] * 5
    speed = [1.0] * 5 + [0.0, 0.0] + [1.0] * 5
    tr = run_batch(u, [0.2] * 12, speed, None, 1.0, PlusParams())
    assert not tr.standstill.any()
    assert np.all(np.abs(tr.bias_corr_dps) < 0.01)


def test_a_slow_straight_drive_is_not_detected() -> None:
    n = 30
    still = _run([0.01] * n, [0.15] * n, [2.0] * n, PlusParams())
    assert not still.any()


def test_gyro_only_detection_requires_quiet_for_several_steps() -> None:
    p = PlusParams(standstill=StopDetection(gyro_only=True, steps_gyro=5))
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
    assert not _run(quiet, [0.1] * 12, [NAN] * 12, PlusParams()).any()


def test_yaw_does_not_integrate_at_standstill() -> None:
    # A 10 s turn at 5 deg/s with a residual bias of 0.2 makes the yaw 52 deg; at the stop
    # omega is 0 whatever u is, and the yaw moves only by the heading correction the stop's
    # evidence makes (a steady unit's: the stop says the bias was 0.2 all along, so the 2 deg
    # it added in the turn are taken back), never by integrating u.
    u = [5.2] * 10 + [0.2] * 60 + [5.2] * 5
    speed = [10.0] * 10 + [0.0] * 60 + [10.0] * 5
    tr = run_batch(u, [0.15] * 75, speed, None, 1.0, one(1e-9, bias_p0=0.04))
    a = 10 + SS.steps_speed - 1  # the first zero-rate update
    assert tr.standstill.tolist() == [False] * a + [True] * (70 - a) + [False] * 5
    assert np.all(tr.omega[a:70] == 0.0)
    assert tr.yaw[9] == pytest.approx(52.0, abs=0.3)  # the turn integrated the residual bias
    assert tr.yaw[69] == pytest.approx(50.0, abs=0.3)  # the stop took it back ...
    assert np.all(np.abs(np.diff(tr.yaw[a + 5 : 70])) < 0.01)  # ... and then holds
    # ... and after the stop the bias it measured (0.2) is removed
    assert tr.bias_corr_dps[69] == pytest.approx(0.2, abs=0.01)
    assert tr.omega[70] == pytest.approx(5.0, abs=0.02)


def test_zero_rate_update_through_step_publishes_standstill() -> None:
    # A start-up bias known to +-1 deg/s only; stops count from their first step.
    vague = one(standstill=StopDetection(steps_speed=1))
    s = INITIAL_PLUS_STATE
    s, o = step(s, StepInput(0.5, 0.1, 0.0, NAN, 1.0), vague)
    assert o.standstill and o.omega == 0.0 and o.yaw == 0.0 and o.straight == 0.0
    assert o.bias_corr_dps == pytest.approx(0.5, rel=0.01)
    s, o = step(s, StepInput(0.5, 0.1, 5.0, NAN, 1.0), vague)
    assert not o.standstill and abs(o.omega) < 0.05


# -- the bias at stops ------------------------------------------------------------------------


def test_bias_converges_to_the_true_bias_on_a_noisy_stationary_segment() -> None:
    rng = np.random.default_rng(1)
    true_bias, sigma, n_samples, steps = 0.137, 0.16, 10, 120
    # Block means of n_samples white samples: the spread is sigma, the mean's noise sigma/sqrt(n).
    u = true_bias + sigma / math.sqrt(n_samples) * rng.standard_normal(steps)
    # A bias that does not wander and a vague start-up prior: the filter's answer is then
    # about the mean of the block means, as good as the samples allow.
    tr = run_batch(u, np.full(steps, sigma), np.zeros(steps), None, 1.0, one())
    used = steps - (SS.steps_speed - 1)  # the first steps of a stop are not measurements
    expect_sd = sigma / math.sqrt(n_samples * used)
    assert abs(tr.bias_corr_dps[-1] - true_bias) < 4 * expect_sd
    # The filter knows how well it knows: its sd is about that of the mean (the stop's own
    # scatter from step to step, which here is the samples' noise, sets each step's variance)
    assert tr.bias_sd_dps[-1] == pytest.approx(expect_sd, rel=0.3)
    assert np.all(np.diff(tr.bias_sd_dps[SS.steps_speed - 1 :]) <= 1e-12)


def test_a_wandering_bias_is_followed_from_stop_to_stop() -> None:
    # Two stops a minute apart read 0.10 and 0.18: a unit whose bias walks by 4e-5
    # (deg/s)^2/s (a CRS03-04 in a warming cabin) follows the second most of the way; a good
    # gyro (3e-7) much less: a minute could not have moved its bias by 0.08 deg/s.
    n = 40
    u = [0.10] * n + [0.5] * 60 + [0.18] * n
    speed = [0.0] * n + [10.0] * 60 + [0.0] * n
    fast = run_batch(u, 0.15, speed, None, 1.0, one(4e-5))
    assert fast.bias_corr_dps[n - 1] == pytest.approx(0.10, abs=0.005)
    assert fast.bias_corr_dps[-1] == pytest.approx(0.18, abs=0.015)
    slow = run_batch(u, 0.15, speed, None, 1.0, one(3e-7))
    assert 0.10 < slow.bias_corr_dps[-1] < 0.16


def test_a_stop_s_noise_is_what_its_readings_show() -> None:
    # A band-limited gyro's samples are correlated: its spread says 0.05/sqrt(10) per step,
    # its readings scatter 0.04 from step to step. The stop is trusted as far as the readings
    # show, not as the spread would have it.
    rng = np.random.default_rng(4)
    u = 0.05 + rng.normal(0.0, 0.04, 60)
    tr = run_batch(u, 0.05, 0.0, None, 1.0, one())
    assert tr.bias_sd_dps[-1] == pytest.approx(0.04 / math.sqrt(58), rel=0.35)
