"""Heading-error metrics (paper Eqs. 12, 13) on hand-made cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.analysis.metrics import (
    abs_wrap180,
    align_index,
    e_psi,
    e_psi_continuous,
    gyro_heading,
    heading_error,
    improvement,
    ne_psi,
    reference,
    truth_at,
    wrap360,
)
from hdrd.core.angles import wrap180

nan = math.nan


def test_wrap360_edges() -> None:
    assert wrap360(-1.0) == 359.0
    assert wrap360(360.0) == 0.0


@given(st.floats(-1e5, 1e5, allow_nan=False))
def test_abs_wrap180_is_abs_of_wrap180(d: float) -> None:
    assert float(abs_wrap180(d)) == pytest.approx(abs(float(wrap180(d))), abs=1e-9)
    assert 0.0 <= float(abs_wrap180(d)) <= 180.0


def test_error_across_north_is_small() -> None:
    # Truth 1 deg; gyro (aligned at step 0 to 359) then turned 2 deg right (CW, yaw -2).
    truth = np.array([359.0, 1.0])
    yaw = np.array([0.0, -2.0])
    err = heading_error(yaw, truth)
    assert err.tolist() == [0.0, 0.0]
    # Turned the wrong way: 4 deg off, not 356.
    err = heading_error(np.array([0.0, 2.0]), truth)
    assert err[1] == pytest.approx(-4.0)
    assert e_psi(np.array([0.0, 2.0]), truth) == pytest.approx(2.0)  # mean of |0|, |-4|


def test_right_turn_through_north_matches_truth() -> None:
    # A right turn (clockwise, negative yaw in the CCW convention) from 350 through 0 to 10.
    truth = np.array([350.0, 355.0, 0.0, 5.0, 10.0])
    yaw = np.array([0.0, -5.0, -10.0, -15.0, -20.0]) + 123.0  # any offset: alignment removes it
    assert e_psi(yaw, truth) == pytest.approx(0.0, abs=1e-12)
    h = gyro_heading(yaw, truth)
    assert h.tolist() == pytest.approx([350.0, 355.0, 360.0, 365.0, 370.0])  # continuous


def test_missing_truth_rows_are_skipped() -> None:
    truth = np.array([10.0, nan, nan, 10.0, 10.0])
    # A huge (wrong) yaw where truth is unknown must not count.
    yaw = np.array([0.0, 90.0, -170.0, 1.0, 3.0])
    err = heading_error(yaw, truth)
    assert np.isnan(err[1]) and np.isnan(err[2])
    assert e_psi(yaw, truth) == pytest.approx((0.0 + 1.0 + 3.0) / 3)


def test_alignment_at_first_valid_sample() -> None:
    truth = np.array([nan, nan, 200.0, 190.0, 185.0])
    yaw = np.array([50.0, 60.0, 70.0, 80.0, 85.0])  # left turn: heading goes down
    assert align_index(yaw, truth) == 2
    h = gyro_heading(yaw, truth)
    assert h[2:].tolist() == pytest.approx([200.0, 190.0, 185.0])
    assert e_psi(yaw, truth) == pytest.approx(0.0)
    # Aligned at an explicit step instead: a constant offset everywhere else.
    assert heading_error(yaw, truth, k=3)[2] == pytest.approx(0.0)
    yaw2 = yaw.copy()
    yaw2[4] += 6.0
    assert heading_error(yaw2, truth)[4] == pytest.approx(-6.0)


def test_yaw_nan_before_truth_is_not_an_alignment_point() -> None:
    truth = np.array([100.0, 100.0, 100.0])
    yaw = np.array([nan, 5.0, 5.0])
    assert align_index(yaw, truth) == 1


def test_no_truth_gives_nan() -> None:
    truth = np.full(4, nan)
    assert math.isnan(e_psi(np.zeros(4), truth))
    assert np.isnan(heading_error(np.zeros(4), truth)).all()
    assert align_index(np.zeros(4), truth) is None


def test_ne_psi_units() -> None:
    # Eq. 13: deg divided by minutes. 30 deg average error over a 15-minute drive = 2 deg/min.
    assert ne_psi(30.0, 15.0) == 2.0
    # The paper's City 1: 17 deg over 19.4 min = 0.87 deg/min (Table II).
    assert ne_psi(17.0, 19.4) == pytest.approx(0.876, abs=1e-3)
    with pytest.raises(ValueError):
        ne_psi(1.0, 0.0)


def test_improvement() -> None:
    assert improvement(61.0, 7.0) == pytest.approx(8.714, abs=1e-3)
    assert improvement(1.0, 0.0) == math.inf
    assert math.isnan(improvement(0.0, 0.0))


def test_two_dimensional_yaw_is_per_column() -> None:
    rng = np.random.default_rng(3)
    truth = wrap360(rng.uniform(0, 360, 50))
    truth[[0, 7, 8]] = nan
    yaw = rng.normal(0, 200, (50, 4))
    cols = e_psi(yaw, truth)
    assert isinstance(cols, np.ndarray) and cols.shape == (4,)
    for j in range(4):
        assert cols[j] == pytest.approx(e_psi(yaw[:, j], truth), rel=1e-12)


@settings(max_examples=50)
@given(
    st.lists(st.floats(-500, 500), min_size=3, max_size=30),
    st.floats(-1000, 1000),
    st.integers(-3, 3),
)
def test_epsi_invariant_to_yaw_offset_and_truth_turns(
    yaw: list[float], offset: float, turns: int
) -> None:
    y = np.asarray(yaw)
    truth = wrap360(np.linspace(0, 400, y.shape[0]))
    base = e_psi(y, truth)
    assert e_psi(y + offset, truth) == pytest.approx(base, abs=1e-6)
    assert e_psi(y, truth + 360.0 * turns) == pytest.approx(base, abs=1e-6)
    assert 0.0 <= base <= 180.0


def test_truth_at_interpolates_across_north() -> None:
    t = np.array([0.0, 1.0, 2.0, 3.0])
    h = np.array([358.0, 2.0, nan, 10.0])
    q = np.array([0.5, 1.0, 1.5, 2.5, -0.1, 3.0, 3.5])
    out = truth_at(t, h, q, max_gap_s=2.0)
    assert out[0] == pytest.approx(0.0)  # between 358 and 2: 0, not 180
    assert out[1] == 2.0  # exactly on a fix
    assert out[2] == pytest.approx(4.0)  # 1 -> 3 s (2 s gap, allowed): 2 + 0.25 * 8
    assert out[3] == pytest.approx(8.0)
    assert np.isnan(out[4])  # before the first fix
    assert out[5] == 10.0  # the last fix itself
    assert np.isnan(out[6])  # after the last fix
    # A gap longer than allowed is never bridged.
    assert np.isnan(truth_at(t, h, np.array([1.5]), max_gap_s=1.5)[0])


def test_truth_at_without_fixes() -> None:
    assert np.isnan(truth_at(np.arange(3.0), np.full(3, nan), np.array([1.0]))).all()


def test_continuous_epsi_counts_whole_turns() -> None:
    # A gyro that drifts a full turn (1 deg per step, 400 steps) against a constant truth:
    # wrapped, the error comes back to 0 after 360 steps; continuous, it keeps growing.
    n = 400
    truth = np.full(n, 10.0)
    yaw = np.arange(n, dtype=float)
    assert e_psi(yaw, truth) < 90.0
    assert e_psi_continuous(yaw, truth) == pytest.approx(np.mean(np.arange(n)))
    # The truth crossing north is unwrapped, not a 360 deg jump.
    truth2 = wrap360(350.0 - np.arange(n) * 0.1)
    yaw2 = np.arange(n) * 0.1
    assert e_psi_continuous(yaw2, truth2) == pytest.approx(0.0, abs=1e-9)
    t3 = truth2.copy()
    t3[:5] = nan  # aligned at the first fix
    assert e_psi_continuous(yaw2 + 7.0, t3) == pytest.approx(0.0, abs=1e-9)
    assert math.isnan(e_psi_continuous(yaw2, np.full(n, nan)))


def test_alignment_over_a_window_is_the_circular_mean() -> None:
    # truth around north, gyro straight: the reference is the circular mean (359.5 .. 0.5),
    # not the arithmetic one (180); a 2-D yaw gets one reference per column.
    truth = np.array([359.0, 1.0, 0.0, 359.5, 0.5, 90.0])
    yaw = np.zeros(6)
    assert wrap180(reference(yaw, truth, 0, 5)) == pytest.approx(0.0, abs=1e-9)
    assert reference(yaw, truth, 0, 1) == 359.0  # one step: the truth there
    # the yaw's own turn within the window is taken out (CCW yaw lowers the heading)
    turning = np.array([0.0, -1.0, -2.0, -3.0, -4.0, 0.0])
    ramp = np.array([10.0, 11.0, 12.0, 13.0, 14.0, 0.0])
    assert reference(turning, ramp, 0, 5) == pytest.approx(10.0)
    both = np.stack([yaw, turning], axis=1)
    assert np.allclose(reference(both, ramp, 0, 5), [12.0, 10.0])
    # Eψ over a window: a noisy truth around a straight gyro scores its noise, not the
    # first sample's error
    rng = np.random.default_rng(1)
    noisy = (100.0 + rng.normal(0.0, 2.0, 400)) % 360.0
    noisy[0] = 120.0  # a first fix 20 deg off
    flat = np.zeros(400)
    assert e_psi(flat, noisy, 0, 1) > 15.0
    assert e_psi(flat, noisy, 1, 10) < 2.5
