"""Static bias eps0 (hdrd/core/calibrate.py; paper Sec. 2, Eq. 2): the estimate, its standstill
tests and the start-up window. The bias file that records it: test_biasfile.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from hdrd.core import calibrate
from hdrd.core.calibrate import (
    T_BIAS_S,
    BiasRecord,
    CalibrationLimits,
    MotionDetected,
    estimate_bias,
)

HZ = 10.0  # the paper's sample rate


def standstill(
    seconds: float = T_BIAS_S, bias: float = 0.8, sigma: float = 0.05, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    n = int(seconds * HZ)
    t = np.arange(n) / HZ
    return bias + sigma * rng.standard_normal(n), t


def test_tbias_is_the_papers() -> None:
    assert T_BIAS_S == 30.0


def test_bias_on_standstill_samples() -> None:
    w, t = standstill()
    temp = np.full(w.shape, 21.0)
    temp[::3] = np.nan  # unknown readings are skipped, not averaged in
    rec = estimate_bias(w, t, temp_c=temp, when=1_700_000_000.0)
    assert rec.bias_dps == float(np.mean(w))
    assert rec.bias_dps == pytest.approx(0.8, abs=0.02)
    assert rec.std_dps == pytest.approx(0.05, rel=0.15)
    assert rec.n == 300
    assert rec.duration_s == pytest.approx(29.9)
    assert rec.temp_c == 21.0
    assert rec.time == 1_700_000_000.0


def test_bias_without_times_or_temperature() -> None:
    w, _ = standstill(1.0)  # paper Sec. 6: one second is enough for usable results
    rec = estimate_bias(w)
    assert rec.n == 10 and rec.duration_s == 0.0 and rec.temp_c is None
    all_nan = estimate_bias(w, temp_c=np.full(10, np.nan))
    assert all_nan.temp_c is None


def test_negative_bias() -> None:
    w, t = standstill(bias=-1.432)  # the paper's Highway 1 drive had eps0 = 1.432 deg/s
    assert estimate_bias(w, t).bias_dps == pytest.approx(-1.432, abs=0.02)


def test_rejects_spread() -> None:
    w, t = standstill()
    w[100:160] += 15.0  # a 6 s turn at 15 deg/s
    with pytest.raises(MotionDetected, match=r"vehicle moved: rate spread .* > 0.5 deg/s"):
        estimate_bias(w, t)


def test_rejects_trend() -> None:
    w, t = standstill()
    w = w + np.linspace(0.0, 0.6, w.shape[0])  # a slow creep: std ~0.18 passes, trend does not
    assert np.std(w, ddof=1) < 0.5
    with pytest.raises(MotionDetected, match=r"rate trend \+0\.\d+ deg/s .* first and last thirds"):
        estimate_bias(w, t)


def test_rejects_excursion() -> None:
    w, t = standstill()
    w[150] += 6.0  # one bump: spread and trend stay small
    assert np.std(w, ddof=1) < 0.5
    with pytest.raises(MotionDetected, match=r"a sample \d+\.\d+ deg/s from the median > 3.0"):
        estimate_bias(w, t)


def test_limits_are_configurable() -> None:
    w, t = standstill(sigma=0.3)
    estimate_bias(w, t)
    with pytest.raises(MotionDetected, match="spread"):
        estimate_bias(w, t, limits=CalibrationLimits(max_std_dps=0.1))


@pytest.mark.parametrize("w", [[], [0.5], [0.1, float("nan"), 0.2], [0.1, float("inf")]])
def test_rejects_too_few_or_non_finite_samples(w: list[float]) -> None:
    with pytest.raises(MotionDetected):
        estimate_bias(w)


@settings(max_examples=50, deadline=None)
@given(
    bias=st.floats(-2.9, 2.9),  # within the default max_bias_dps
    sigma=st.floats(0.0, 0.2),
    seed=st.integers(0, 1000),
    turn=st.floats(5.0, 100.0),
    at=st.floats(0.0, 0.9),
)
def test_any_turn_in_the_window_is_rejected(
    bias: float, sigma: float, seed: int, turn: float, at: float
) -> None:
    w, t = standstill(bias=bias, sigma=sigma, seed=seed)
    estimate_bias(w, t)  # standstill passes
    k = int(at * w.shape[0])
    w[k : k + 20] += turn  # a 2 s turn of >= 5 deg/s somewhere in the window
    with pytest.raises(MotionDetected, match="vehicle moved"):
        estimate_bias(w, t)


def test_a_steady_rotation_is_not_a_bias() -> None:
    # A turntable (or a ferry) turning at a constant 10 deg/s looks perfectly still to the
    # spread, trend and excursion tests; no CRS03-04 has a bias that large (+/-3 deg/s).
    w, t = standstill(bias=10.0)
    with pytest.raises(
        MotionDetected,
        match=r"mean rate \+(9\.9|10\.0)\d+ deg/s is beyond the \+/-3 deg/s .*"
        r"calibration\.max_bias_dps",
    ):
        estimate_bias(w, t)
    with pytest.raises(MotionDetected, match="beyond"):
        estimate_bias(-w, t)
    # The limit is configurable, and a bias inside it passes.
    assert estimate_bias(w, t, limits=CalibrationLimits(max_bias_dps=12.0)).bias_dps > 9.9
    assert estimate_bias(*standstill(bias=2.9)).bias_dps == pytest.approx(2.9, abs=0.02)


# -- noise-scaled standstill tests and the shared start-up window ------------------------------


def phone_window() -> np.ndarray:
    """The first 6 s of a 1 Hz phone drive (bias 0.01 deg/s, noise 0.01 deg/s): 5 s standing,
    then the first second of a left turn, which averages 0.37 deg/s at 1 Hz."""
    rng = np.random.default_rng(7)
    w = 0.01 + 0.01 * rng.standard_normal(6)
    w[5] += 0.36
    return w


def test_the_start_of_a_turn_at_1_hz_is_not_a_standstill() -> None:
    w = phone_window()
    # The absolute limits alone (as before) take it, and measure a bias 7x too large.
    old = CalibrationLimits(max_shift_se=0.0)
    assert estimate_bias(w, limits=old).bias_dps == pytest.approx(0.07, abs=0.01)
    with pytest.raises(MotionDetected, match=r"1 of 6 samples pull the mean by \+0\.05\d+ deg/s"):
        estimate_bias(w)
    assert estimate_bias(w[:5]).bias_dps == pytest.approx(0.01, abs=0.01)


def test_a_slow_creep_is_caught_relative_to_the_noise() -> None:
    w, t = standstill(sigma=0.05)
    w = w + np.linspace(0.0, 0.15, w.shape[0])  # a trend of 0.1 deg/s: under the absolute 0.2
    assert estimate_bias(w, t, limits=CalibrationLimits(max_shift_se=0.0)).n == 300
    with pytest.raises(MotionDetected, match="rate trend .* standard errors"):
        estimate_bias(w, t)


def test_noise_sigma_survives_a_bump_and_a_coarse_adc() -> None:
    rng = np.random.default_rng(3)
    w = 0.2 + 0.05 * rng.standard_normal(300)
    assert calibrate.noise_sigma(w) == pytest.approx(0.05, rel=0.15)
    w[10] += 2.0  # one bump does not inflate it
    assert calibrate.noise_sigma(w) == pytest.approx(0.05, rel=0.15)
    # A coarse ADC (1/16 deg/s) reading one code in most samples: the MAD is 0, the spread
    # without the farthest sample is not, and the standstill passes.
    q = np.zeros(60)
    q[[3, 17, 31, 44, 58]] = 0.0625
    q[25] = -0.0625
    assert float(np.median(np.abs(q - np.median(q)))) == 0.0
    assert calibrate.noise_sigma(q) > 0.015  # not the floor
    estimate_bias(q)
    assert calibrate.noise_sigma(np.zeros(5), 0.01) == 0.01  # the floor


@settings(max_examples=50, deadline=None)
@given(
    bias=st.floats(-2.9, 2.9),
    sigma=st.floats(0.0, 0.3),
    seed=st.integers(0, 1000),
    n=st.sampled_from([12, 60, 300, 3000]),
)
def test_gaussian_standstill_passes_the_noise_scaled_tests(
    bias: float, sigma: float, seed: int, n: int
) -> None:
    """Whatever the absolute limits accept of pure Gaussian noise, the noise-scaled tests
    accept too, and the record is the window's own: its mean, spread and count."""
    w = bias + sigma * np.random.default_rng(seed).standard_normal(n)
    absolute_only: BiasRecord | None
    try:
        absolute_only = estimate_bias(w, limits=CalibrationLimits(max_shift_se=0.0))
    except MotionDetected:
        absolute_only = None
    assume(absolute_only is not None)  # the absolute limits refused it: nothing to compare
    rec = estimate_bias(w)
    assert rec == absolute_only
    assert (rec.bias_dps, rec.std_dps, rec.n) == (float(np.mean(w)), float(np.std(w, ddof=1)), n)


@pytest.mark.parametrize(("n", "at_most"), [(5, 0.0), (6, 0.006), (8, 0.002), (10, 0.0005)])
def test_few_samples_rarely_fail_the_noise_scaled_tests(n: int, at_most: float) -> None:
    # Few samples tell little of their own noise: with 6 (1 Hz, 6 s) the tests refuse about
    # 3 in 1000 Gaussian windows; below 6 they are not applied.
    rng = np.random.default_rng(n)
    loose = CalibrationLimits(max_std_dps=1e9, max_trend_dps=1e9, max_excursion_dps=1e9)
    refused = 0
    for _ in range(4000):
        try:
            estimate_bias(0.1 * rng.standard_normal(n), limits=loose)
        except MotionDetected:
            refused += 1
    assert refused / 4000 <= at_most


def test_startup_window_measures_after_its_steps_and_restarts_on_motion() -> None:
    win = calibrate.StartupWindow.for_seconds(3.5, 1.0)
    assert win.blocks == 3
    w, _ = standstill(3.0)
    win.add_many(w[:10], np.full(10, 20.0))
    assert win.close_block() is None
    for x in w[10:20].tolist():
        win.add(x, None)
    assert win.close_block() is None and win.n == 20
    win.add_many(w[20:30])
    rec = win.close_block()
    assert rec is not None and rec.n == 30 and rec.duration_s == 3.0
    assert rec.bias_dps == estimate_bias(w).bias_dps and rec.temp_c == 20.0
    assert win.n == 0 and win.attempts == 1
    moving = w + np.linspace(0.0, 3.0, 30)
    for k in range(3):
        win.add_many(moving[k * 10 : (k + 1) * 10])
        if k < 2:
            assert win.close_block() is None
    with pytest.raises(MotionDetected):
        win.close_block()
    assert win.n == 0 and win.closed == 0 and win.attempts == 2


# -- every limit is inclusive: a value exactly at it passes, the next float beyond it does not ---


def _above(x: float) -> float:
    return float(np.nextafter(x, np.inf))


def _below(x: float) -> float:
    return float(np.nextafter(x, -np.inf))


LOOSE = dict(
    max_std_dps=1e9, max_trend_dps=1e9, max_excursion_dps=1e9, max_bias_dps=1e9, max_shift_se=0.0
)


def test_spread_exactly_at_its_limit_passes() -> None:
    w, _ = standstill(3.0, sigma=0.3)
    std = float(np.std(w, ddof=1))
    at = {**LOOSE, "max_std_dps": std}
    assert estimate_bias(w, limits=CalibrationLimits(**at)).std_dps == std
    with pytest.raises(MotionDetected, match="rate spread"):
        estimate_bias(w, limits=CalibrationLimits(**{**at, "max_std_dps": _below(std)}))


def test_trend_exactly_at_its_limit_passes() -> None:
    w, _ = standstill(3.0)
    w = w + np.linspace(0.0, 0.3, w.shape[0])
    trend = float(np.mean(w[-10:]) - np.mean(w[:10]))
    at = {**LOOSE, "max_trend_dps": trend}
    estimate_bias(w, limits=CalibrationLimits(**at))
    with pytest.raises(MotionDetected, match="rate trend"):
        estimate_bias(w, limits=CalibrationLimits(**{**at, "max_trend_dps": _below(trend)}))
    # a falling trend is held to the same limit, by its size
    r = w[::-1]
    fall = float(np.mean(r[-10:]) - np.mean(r[:10]))
    assert fall < 0
    estimate_bias(r, limits=CalibrationLimits(**{**at, "max_trend_dps": -fall}))
    with pytest.raises(MotionDetected, match="rate trend -"):
        estimate_bias(r, limits=CalibrationLimits(**{**at, "max_trend_dps": _below(-fall)}))


def test_excursion_exactly_at_its_limit_passes() -> None:
    w = np.array([0.5, 0.5, 0.5, 0.5, 2.0, 0.5, 0.5])
    at = {**LOOSE, "max_excursion_dps": 1.5}
    estimate_bias(w, limits=CalibrationLimits(**at))
    with pytest.raises(MotionDetected, match="a sample 1.50 deg/s from the median"):
        estimate_bias(w, limits=CalibrationLimits(**{**at, "max_excursion_dps": _below(1.5)}))
    with pytest.raises(MotionDetected, match="from the median"):
        estimate_bias(-w, limits=CalibrationLimits(**{**at, "max_excursion_dps": _below(1.5)}))


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_bias_exactly_at_its_limit_passes(sign: float) -> None:
    w = sign * np.full(12, 2.5)
    at = {**LOOSE, "max_bias_dps": 2.5}
    assert estimate_bias(w, limits=CalibrationLimits(**at)).bias_dps == sign * 2.5
    with pytest.raises(MotionDetected, match="beyond the"):
        estimate_bias(w, limits=CalibrationLimits(**{**at, "max_bias_dps": _below(2.5)}))


def test_the_noise_scaled_tests_start_at_six_samples() -> None:
    # A window whose last sample jumps: refused by the shift test from 6 samples on, not
    # looked at with 5 (too few to know their own noise).
    w = np.array([0.0, 0.001, -0.001, 0.0005, 0.2, 0.0, 0.0015, -0.0005, 0.2])
    loose = CalibrationLimits(max_std_dps=1e9, max_trend_dps=1e9, max_excursion_dps=1e9)
    assert calibrate.NOISE_TEST_MIN_SAMPLES == 6
    estimate_bias(w[:5], limits=loose)
    with pytest.raises(MotionDetected, match="pull the mean"):
        estimate_bias(np.append(w[:4], [0.0, 0.2]), limits=loose)
    # max_shift_se 0 switches both off, whatever the window
    estimate_bias(w, limits=CalibrationLimits(**LOOSE))


def _shift_and_se(w: np.ndarray, floor: float = 0.01) -> tuple[float, float, int]:
    """What the shift test computes: (|shift|, standard error of the mean, samples in the core)."""
    sigma = calibrate.noise_sigma(w, floor)
    med = float(np.median(w))
    core = w[np.abs(w - med) <= calibrate.SHIFT_INNER_SIGMAS * sigma]
    return (
        abs(float(np.mean(w)) - float(np.mean(core))),
        sigma / math.sqrt(w.shape[0]),
        core.shape[0],
    )


def test_shift_exactly_at_its_limit_passes() -> None:
    rng = np.random.default_rng(5)
    w = 0.05 * rng.standard_normal(40)
    w[7] += 0.6  # one sample far out: outside the core, it pulls the mean
    shift, se, n_core = _shift_and_se(w)
    assert n_core == 39
    limit = shift / se
    while limit * se < shift:  # the float whose product with se is exactly the shift, or just above
        limit = _above(limit)
    base = {"max_std_dps": 1e9, "max_trend_dps": 1e9, "max_excursion_dps": 1e9, "max_trend_se": 1e9}
    assert limit * se == shift  # there is one for this window
    estimate_bias(w, limits=CalibrationLimits(**base, max_shift_se=limit))
    with pytest.raises(MotionDetected, match="1 of 40 samples pull the mean"):
        estimate_bias(w, limits=CalibrationLimits(**base, max_shift_se=_below(limit)))


def test_a_sample_exactly_four_sigmas_out_is_in_the_core() -> None:
    # Nine samples whose noise sigma is exactly 0.1 (the floor), and one exactly 4 sigmas
    # from the median: it belongs to the core, so it does not count as pulling the mean.
    w = np.array([0.0] * 9 + [0.4])
    sigma = calibrate.noise_sigma(w, 0.1)
    assert sigma == 0.1 and float(np.median(w)) == 0.0
    assert _shift_and_se(w, 0.1)[2] == 10
    limits = CalibrationLimits(
        max_std_dps=1e9, max_trend_dps=1e9, max_excursion_dps=1e9, max_trend_se=1e9,
        noise_floor_dps=0.1, max_shift_se=1e-9,
    )  # fmt: skip
    estimate_bias(w, limits=limits)  # shift 0: every sample is in the core
    w[-1] = _above(0.4)
    with pytest.raises(MotionDetected, match="1 of 10 samples"):
        estimate_bias(w, limits=limits)


def test_scaled_trend_limit_and_its_floor() -> None:
    # Twelve samples, a step between the first and last thirds: third = 4.
    w = np.array([0.0] * 4 + [0.05] * 4 + [0.1] * 4)
    sigma = calibrate.noise_sigma(w, 0.01)
    se_trend = sigma * math.sqrt(2.0 / 4)
    trend = 0.1
    base = {"max_std_dps": 1e9, "max_trend_dps": 1e9, "max_excursion_dps": 1e9, "max_shift_se": 1e9}
    # the floor alone: a trend below trend_floor_dps is never refused
    estimate_bias(w, limits=CalibrationLimits(**base, max_trend_se=0.0, trend_floor_dps=trend))
    with pytest.raises(MotionDetected, match=r"rate trend \+0\.1000 deg/s .* standard errors"):
        estimate_bias(
            w, limits=CalibrationLimits(**base, max_trend_se=0.0, trend_floor_dps=_below(trend))
        )
    # the scaled limit: trend / se_trend standard errors exactly
    k = trend / se_trend
    while k * se_trend < trend:
        k = _above(k)
    assert k * se_trend == trend
    estimate_bias(w, limits=CalibrationLimits(**base, max_trend_se=k, trend_floor_dps=0.0))
    with pytest.raises(MotionDetected, match="standard errors"):
        estimate_bias(
            w, limits=CalibrationLimits(**base, max_trend_se=_below(k), trend_floor_dps=0.0)
        )


def test_noise_sigma_takes_the_largest_of_its_three() -> None:
    # the MAD: a Laplace-like window whose sample std without the farthest is smaller
    w = np.array([-1.0, -1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    dev = np.abs(w - np.median(w))
    mad = 1.4826 * float(np.median(dev))
    loo = float(np.std(np.delete(w, int(np.argmax(dev))), ddof=1))
    assert calibrate.noise_sigma(w) == max(mad, loo) and mad == 0.0 and loo > 0.0
    v = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 10.0])
    dev = np.abs(v - np.median(v))
    mad = 1.4826 * float(np.median(dev))
    loo = float(np.std(v[:5], ddof=1))
    assert calibrate.noise_sigma(v) == max(mad, loo) and mad > loo
    assert calibrate.noise_sigma(v, 100.0) == 100.0
    # two samples: no leave-one-out spread, the MAD (or the floor)
    assert calibrate.noise_sigma(np.array([0.0, 1.0])) == 1.4826 * 0.5
    assert calibrate.noise_sigma(np.array([0.0, 1.0]), 2.0) == 2.0


def test_what_the_record_holds() -> None:
    w = np.array([0.3, 0.5, 0.4, 0.4])
    rec = estimate_bias(w, [10.0, 10.1, 10.2, 10.35], temp_c=[20.0, np.nan, 22.0, np.nan], when=7.5)
    assert rec.duration_s == 10.35 - 10.0 and rec.temp_c == 21.0 and rec.time == 7.5
    assert (
        rec.n == 4 and rec.bias_dps == float(np.mean(w)) and rec.std_dps == float(np.std(w, ddof=1))
    )
    assert estimate_bias(w, temp_c=[np.nan] * 4).temp_c is None
    assert estimate_bias(w, []).duration_s == 0.0
    assert rec.to_dict() == {
        "bias_dps": rec.bias_dps, "std_dps": rec.std_dps, "n": 4, "duration_s": rec.duration_s,
        "temp_c": 21.0, "time": 7.5,
    }  # fmt: skip
    with pytest.raises(MotionDetected, match="only 1 sample"):
        estimate_bias([0.1])
    estimate_bias([0.1, 0.1])  # two are enough


def test_startup_window_details() -> None:
    win = calibrate.StartupWindow(2, block_s=0.5)
    assert np.isnan(win.mean_dps) and win.n == 0
    win.add(0.45)
    win.add(0.55, 30.0)
    assert win.mean_dps == 0.5 and win.n == 2
    assert win.close_block() is None and win.closed == 1
    win.add_many([0.5, 0.5], [np.nan, 32.0])
    rec = win.close_block()
    assert rec is not None and rec.n == 4 and rec.duration_s == 1.0 and rec.temp_c == 31.0
    assert rec.bias_dps == pytest.approx(0.5) and win.closed == 0 and win.n == 0
    assert win.attempts == 1
    # measure() leaves the window as it is, even when it refuses it
    win.add_many([0.0, 5.0, 0.0])
    with pytest.raises(MotionDetected):
        win.measure()
    assert win.n == 3 and win.attempts == 2
    win.clear()
    assert win.n == 0 and win.closed == 0
    with pytest.raises(ValueError, match="at least 1 step"):
        calibrate.StartupWindow(0)
    # for_seconds takes the whole steps within the seconds (never a sample past them), no
    # step lost to a rounding error, and at least one step
    for seconds, T, blocks in [
        (3.0, 1.0, 3),
        (3.0000001, 1.0, 3),
        (3.9999, 1.0, 3),
        (0.3, 0.1, 3),
        (29.4, 1.0, 29),
        (0.0, 1.0, 1),
        (0.5, 2.0, 1),
    ]:
        w = calibrate.StartupWindow.for_seconds(seconds, T)
        assert (w.blocks, w.block_s) == (blocks, T)


def test_what_a_failed_scaled_trend_says() -> None:
    w = np.array([0.0] * 4 + [0.05] * 4 + [0.1] * 4)
    sigma = calibrate.noise_sigma(w, 0.01)
    se_trend = sigma * math.sqrt(2.0 / 4)
    loose = {"max_std_dps": 1e9, "max_trend_dps": 1e9, "max_excursion_dps": 1e9}
    with pytest.raises(MotionDetected) as e:
        estimate_bias(w, limits=CalibrationLimits(**loose, max_shift_se=1e9, max_trend_se=1.0))
    assert (
        f"rate trend +0.1000 deg/s between the window's first and last thirds, "
        f"{0.1 / se_trend:.1f} standard errors (noise {sigma:.4f} deg/s) > 1 allowed"
        in str(e.value)
    )


def test_a_window_of_three_compares_its_first_and_last_samples() -> None:
    # Thirds of fewer than 6 samples are single samples: 0.3 deg/s from first to last is a
    # trend (a pair of samples at each end would halve it to within the limit).
    with pytest.raises(MotionDetected, match=r"rate trend \+0\.300"):
        estimate_bias([0.0, 0.0, 0.3])
    with pytest.raises(MotionDetected, match=r"rate trend \+0\.300"):
        estimate_bias([0.0, 0.0, 0.0, 0.3, 0.3])
    assert estimate_bias([0.0, 0.1, 0.2]).n == 3  # 0.2: at the limit


def test_float32_samples_are_measured_in_float64() -> None:
    # A drive log read as float32: the record is what the same values give in float64.
    rng = np.random.default_rng(2)
    w = (0.8 + 0.05 * rng.standard_normal(300)).astype(np.float32)
    t = (1e4 + np.arange(300) * 0.1).astype(np.float32)
    tc = (20.0 + 0.01 * np.arange(300)).astype(np.float32)
    got = estimate_bias(w, t, temp_c=tc)
    want = estimate_bias(w.astype(np.float64), t.astype(np.float64), temp_c=tc.astype(np.float64))
    assert got == want
    assert got.duration_s == float(np.float64(t[-1]) - np.float64(t[0]))


def test_two_samples_are_measured_without_a_warning() -> None:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "degrees of freedom <= 0" from a 1-sample spread
        assert calibrate.noise_sigma(np.array([0.0, 1.0])) == 1.4826 * 0.5
        estimate_bias([0.1, 0.12])
