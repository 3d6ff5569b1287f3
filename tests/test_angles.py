"""hdrd.core.angles: an angle difference wrapped to [-180, 180), a heading to compass [0, 360),
for a float and for a numpy array alike (the one home of both; every wrap in hdrd is one of
these)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from hdrd.core.angles import compass, wrap180

ANGLES = st.floats(-1e6, 1e6, allow_nan=False) | st.floats(-1e-12, 1e-12, allow_nan=False)


def test_the_edges() -> None:
    assert wrap180(0.0) == 0.0
    assert wrap180(180.0) == -180.0  # [-180, 180): +180 maps to -180
    assert wrap180(-180.0) == -180.0
    assert wrap180(359.0) == -1.0 and wrap180(-358.0) == 2.0
    assert compass(-1.0) == 359.0 and compass(360.0) == 0.0 and compass(725.0) == 5.0
    # (0 - 1e-20) % 360 is 360.0 in floating point: a compass says north, never 360
    assert -1e-20 % 360.0 == 360.0
    assert compass(-1e-20) == 0.0 and compass(1e-20) == 1e-20
    assert math.copysign(1.0, compass(-0.0)) == 1.0


@given(ANGLES)
def test_wrap180_is_in_range_and_congruent(x: float) -> None:
    w = wrap180(x)
    assert -180.0 <= w < 180.0
    assert math.isclose(math.remainder(w - x, 360.0), 0.0, abs_tol=1e-6)


@given(ANGLES)
def test_compass_is_in_range_and_congruent(x: float) -> None:
    h = compass(x)
    assert 0.0 <= h < 360.0
    assert math.isclose(math.remainder(h - x, 360.0), 0.0, abs_tol=1e-6)


@given(st.lists(ANGLES | st.just(math.nan), max_size=30))
def test_an_array_wraps_as_its_floats_do_bit_for_bit(xs: list[float]) -> None:
    a = np.array(xs, dtype=np.float64)
    for f in (wrap180, compass):
        got = f(a)
        assert got.dtype == np.float64 and got.shape == a.shape
        want = np.array([f(x) for x in xs], dtype=np.float64)
        assert got.tobytes() == want.tobytes()  # the same bits, NaN and signed zero included
