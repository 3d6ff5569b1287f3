"""Numbers as a person reads them: published messages rounded for a terminal. Pure.

A message's numbers carry every digit the computation gave (a yaw of -0.0025271484375000014).
For a program reading a pipe or a file that is right: it gets full precision
(docs/protocol.md). On a terminal the digits beyond what a value means are noise, so
``hdrd run --stdout`` and ``hdrd tail`` print :func:`for_display` of each message there: each
known key rounded to the decimals its unit and sensor resolve (:data:`DECIMALS`), any other
number to :data:`SIGNIFICANT` significant digits, and no number longer than a line can hold.
:func:`fit` writes one number into a table column of a given width.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

__all__ = ["DECIMALS", "SIGNIFICANT", "fit", "for_display", "shown_number"]

DECIMALS: dict[str, int] = {
    "time": 2,  # UNIX s, the host clock: 10 ms
    "t": 3,  # device s: 1 ms
    "omega_raw": 4,  # deg/s: a 16-bit ADC resolves 0.0076 deg/s of the CRS03-04
    "omega": 4,
    "I": 4,
    "bias": 4,
    "bias_sd": 5,
    "R": 3,
    "yaw": 2,  # deg, as NMEA's headings (2 decimals)
    "heading": 2,
    "heading_offset": 2,
    "gps_course": 2,
    "gps_speed": 2,  # m/s
    "temp": 2,  # degC: the ADC reports 0.01 degC
    "gap_s": 3,
    "stale_s": 3,
}
"""Decimals shown on a terminal, per message key (docs/protocol.md's units)."""

SIGNIFICANT = 6
"""Significant digits shown of a number whose key is not in :data:`DECIMALS`."""

_BIG = 1e15
"""Beyond this magnitude a number is shown in exponent form (no line of digits)."""


def _int_exponent(v: int) -> str:
    """An integer beyond float range in exponent form: ``9e+399``."""
    digits = str(abs(v))
    return f"{'-' if v < 0 else ''}{digits[0]}e+{len(digits) - 1}"


def _short_int(v: int) -> float | int | str:
    """An integer as shown: itself, or in exponent form when it has more than 15 digits
    (a float; beyond float range, text such as ``9e+399``)."""
    if abs(v) < _BIG:
        return v
    try:
        return float(f"{v:.{SIGNIFICANT}g}")
    except OverflowError:
        return _int_exponent(v)


def shown_number(key: str, v: float) -> float:
    """A float as a terminal shows it under message key ``key``: rounded to the key's
    decimals, else to :data:`SIGNIFICANT` digits; -0.0 shows as 0.0; a heading stays in
    [0, 360) (359.996 shows as 0.0, as NMEA writes it)."""
    if not math.isfinite(v):
        return v
    d = DECIMALS.get(key)
    if d is None or abs(v) >= _BIG:
        r = float(f"{v:.{SIGNIFICANT}g}")
    else:
        r = round(v, d)
    if key == "heading" and r == 360.0 and v < 360.0:
        r = 0.0
    return r + 0.0  # + 0.0 turns -0.0 into 0.0


def _shown(key: str, v: Any) -> Any:
    if isinstance(v, bool) or v is None or isinstance(v, str):
        return v
    if isinstance(v, int):
        return _short_int(v)
    if isinstance(v, float):
        return shown_number(key, v)
    if isinstance(v, Mapping):
        return {k: _shown(str(k), x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_shown(key, x) for x in v]
    return v


def for_display(msg: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of ``msg`` with its numbers as a person reads them (see the module doc);
    strings, booleans and the keys' order unchanged."""
    return {k: _shown(str(k), v) for k, v in msg.items()}


def fit(v: float | int, fmt: str, width: int) -> str:
    """``v`` formatted with ``fmt`` (``.2f``, ``d`` ...; never ``-0.00``), or, when that is wider than
    ``width`` characters (a yaw of 1e300 would print 300 digits), in exponent form with as
    many significant digits as fit (at least one)."""
    text = format(v, fmt)
    if text.startswith("-") and text.strip("-0.") == "":
        text = text[1:]  # -0.0025 at 2 decimals is 0.00, not -0.00
    if len(text) <= width:
        return text
    try:
        f = float(v)
    except OverflowError:  # an integer beyond float range
        return _int_exponent(int(v))
    for p in range(SIGNIFICANT, 0, -1):
        short = f"{f:.{p}g}"
        if len(short) <= width:
            return short
    return short
