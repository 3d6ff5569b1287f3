"""Numbers as a person reads them on a terminal (hdrd/io/net/display.py): rounded to what each key
means, never a line of digits, the message otherwise unchanged. Pure."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdrd.io.net.display import DECIMALS, fit, for_display, shown_number


def test_each_key_to_what_it_means() -> None:
    msg = {
        "class": "HDR",
        "v": 1,
        "time": 1718000041.0123456,
        "t": 41.00049999,
        "step": 41,
        "omega_raw": 0.31212345,
        "omega": 0.070212345,
        "yaw": -0.0025271484375000014,
        "heading": 93.423456,
        "I": -0.08444444,
        "W": 1,
        "R": 0.5381234,
        "bias": 0.24190000000000003,
        "status": "ok",
        "temp": 12.943111,
        "zz_unknown": 1.23456789,
    }
    assert for_display(msg) == {
        "class": "HDR",
        "v": 1,
        "time": 1718000041.01,
        "t": 41.0,
        "step": 41,
        "omega_raw": 0.3121,
        "omega": 0.0702,
        "yaw": 0.0,  # -0.0025 is noise; and no "-0.0"
        "heading": 93.42,
        "I": -0.0844,
        "W": 1,
        "R": 0.538,
        "bias": 0.2419,
        "status": "ok",
        "temp": 12.94,
        "zz_unknown": 1.23457,  # 6 significant digits
    }
    assert list(for_display(msg)) == list(msg)
    assert json.dumps(for_display({"yaw": -0.0001})) == '{"yaw": 0.0}'


def test_a_heading_stays_below_360_and_huge_numbers_are_short() -> None:
    assert shown_number("heading", 359.996) == 0.0
    assert shown_number("yaw", 1e300) == 1e300 and shown_number("omega", -1e20) == -1e20
    shown = for_display({"step": 10**300, "n": -(10**400), "big": 123456789012345678})
    assert shown == {"step": 1e300, "n": "-1e+400", "big": 1.23457e17}
    assert all(len(json.dumps(v)) < 12 for v in shown.values())
    assert for_display({"x": [1.23456789, {"omega": 0.123456}], "ok": True, "s": "a"}) == {
        "x": [1.23457, {"omega": 0.1235}],
        "ok": True,
        "s": "a",
    }
    assert math.isnan(shown_number("yaw", math.nan))


@given(st.floats(allow_nan=False, allow_infinity=False), st.sampled_from([*DECIMALS, "other"]))
def test_a_shown_number_is_close_and_short(v: float, key: str) -> None:
    r = shown_number(key, v)
    assert len(repr(r)) <= 25
    if key == "heading" and 0.0 <= v < 360.0:
        assert 0.0 <= r < 360.0
    tol = 0.5 * 10 ** -DECIMALS[key] if key in DECIMALS and abs(v) < 1e15 else abs(v) * 1e-5
    if key == "heading" and r == 0.0 and v > 359.0:
        v -= 360.0
    assert abs(r - v) <= tol + 1e-9 * abs(v)


@pytest.mark.parametrize(
    "v, fmt, width, want",
    [
        (1e300, ".2f", 9, "1e+300"),
        (-1e300, ".2f", 9, "-1e+300"),
        (-3.14159, ".2f", 9, "-3.14"),
        (10**300, "d", 6, "1e+300"),
        (-(10**400), "d", 6, "-1e+400"),
        (123456.789, ".4f", 8, "123457"),
        (41, "d", 6, "41"),
        (-0.0025, ".2f", 9, "0.00"),
        (-0.0, ".4f", 8, "0.0000"),
        (-0.005, ".2f", 9, "-0.01"),
    ],
)
def test_fit_a_column(v: Any, fmt: str, width: int, want: str) -> None:
    assert fit(v, fmt, width) == want
