"""gpsd's JSON protocol, pure (``gpsd_json(5)``): :func:`parse_line` turns one line into a
small frozen dataclass (:class:`Fix` for a ``TPV``, :class:`Version`, :class:`Devices`, ...; or
``None`` for a class hdrd does not use) and raises :class:`GpsdProtocolError` for a line that
is not a gpsd JSON object. Course is compass deg clockwise from true north, speed m/s; an
unknown attribute is absent, never null. The socket that reads them is
:class:`hdrd.io.net.gpsd.GpsdClient`'s.
"""

from __future__ import annotations

import calendar
import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hdrd.errors import HdrdError, clipped

__all__ = [
    "WATCH_COMMAND",
    "Device",
    "Devices",
    "Fix",
    "GpsdError",
    "GpsdProtocolError",
    "Report",
    "Version",
    "Watch",
    "parse_line",
    "parse_time",
]

WATCH_COMMAND = b'?WATCH={"enable":true,"json":true}\n'
"""What a client sends to have gpsd send its reports as JSON."""


class GpsdProtocolError(HdrdError, ValueError):
    """A line that is not a gpsd JSON report; ``str()`` says why."""


# -- reports ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Version:
    """``VERSION``: the first line gpsd sends on connect."""

    release: str
    rev: str | None = None
    proto_major: int | None = None
    proto_minor: int | None = None


@dataclass(frozen=True, slots=True)
class Device:
    """``DEVICE``: one device gpsd reads (alone, or inside ``DEVICES``)."""

    path: str | None = None
    driver: str | None = None
    activated: str | None = None
    """When gpsd opened it (ISO 8601); None once closed (gpsd then sends 0)."""
    bps: int | None = None


@dataclass(frozen=True, slots=True)
class Devices:
    """``DEVICES``: the devices gpsd knows about."""

    devices: tuple[Device, ...] = ()


@dataclass(frozen=True, slots=True)
class Watch:
    """``WATCH``: gpsd's answer to our ``?WATCH``."""

    enable: bool | None = None
    json: bool | None = None


@dataclass(frozen=True, slots=True)
class Fix:
    """``TPV``: a time-position-velocity report.

    mode: 0 unknown, 1 no fix, 2 2D fix, 3 3D fix. time: UNIX s (GPS time), None if not
    sent. track_deg: course over ground, compass deg clockwise from true north [0, 360).
    speed_mps: ground speed, m/s. epd: course error estimate, deg; eps: speed error
    estimate, m/s (95 %). lat/lon: deg; alt_m: altitude (MSL when given), m.
    """

    mode: int
    time: float | None = None
    track_deg: float | None = None
    speed_mps: float | None = None
    epd: float | None = None
    eps: float | None = None
    lat: float | None = None
    lon: float | None = None
    alt_m: float | None = None
    climb_mps: float | None = None
    device: str | None = None
    status: int | None = None

    @property
    def has_fix(self) -> bool:
        """A 2D or 3D fix."""
        return self.mode >= 2


@dataclass(frozen=True, slots=True)
class GpsdError:
    """``ERROR``: gpsd did not like a request."""

    message: str


Report = Version | Devices | Device | Watch | Fix | GpsdError

_TIME_RE = re.compile(r"(\d{4})-(\d\d)-(\d\d)T(\d\d):(\d\d):(\d\d)(\.\d+)?Z?\Z")


def _finite(v: int | float) -> float | None:
    """*v* as a finite float; None for NaN, +-inf and integers beyond float range (JSON
    integers have no size limit: ``1`` followed by 400 zeros is valid JSON)."""
    try:
        f = float(v)
    except OverflowError:
        return None
    return f if math.isfinite(f) else None


def parse_time(value: Any) -> float | None:
    """gpsd's time, ISO 8601 UTC (``2005-06-08T10:34:48.283Z``) or, in old gpsd, UNIX s,
    -> UNIX s. None for anything else (a bad time is not a reason to drop a fix)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return _finite(value)
    if not isinstance(value, str):
        return None
    m = _TIME_RE.match(value)
    if not m:
        return None
    y, mo, d, h, mi, s = (int(x) for x in m.groups()[:6])
    if not (1 <= y and 1 <= mo <= 12 and 1 <= d <= 31 and h < 24 and mi < 60 and s <= 60):
        return None  # year 0000 has no calendar date (datetime starts at year 1)
    frac = float(m.group(7)) if m.group(7) else 0.0
    return calendar.timegm((y, mo, d, h, mi, s, 0, 0, 0)) + frac


def _num(obj: Mapping[str, Any], key: str) -> float | None:
    """A finite number, None when absent or not finite (NaN, +-inf, an integer beyond float
    range); GpsdProtocolError when of the wrong type."""
    v = obj.get(key)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise GpsdProtocolError(f"{key!r} is not a number: {_shown(v)}")
    return _finite(v)


def _nonneg(obj: Mapping[str, Any], key: str) -> float | None:
    """:func:`_num` for a magnitude (a speed, an error estimate): a negative value is not one
    gpsd sends, so it is treated as unknown (None) rather than trusted."""
    v = _num(obj, key)
    return None if v is None or v < 0.0 else v


def _shown(v: Any) -> str:
    """A short, printable rendering of a bad value for an error message."""
    try:
        text = repr(v)
    except (ValueError, RecursionError):  # an int beyond the str-conversion limit, deep nesting
        text = f"<{type(v).__name__}>"
    return clipped(text, 40)


def _int(obj: Mapping[str, Any], key: str) -> int | None:
    v = _num(obj, key)
    return None if v is None else int(v)


def _str(obj: Mapping[str, Any], key: str) -> str | None:
    v = obj.get(key)
    if v is None:
        return None
    if not isinstance(v, str):
        raise GpsdProtocolError(f"{key!r} is not a string: {_shown(v)}")
    return v


def _bool(obj: Mapping[str, Any], key: str) -> bool | None:
    v = obj.get(key)
    if v is None:
        return None
    if not isinstance(v, bool):
        raise GpsdProtocolError(f"{key!r} is not true/false: {_shown(v)}")
    return v


def _device(obj: Mapping[str, Any]) -> Device:
    act = obj.get("activated")
    return Device(
        path=_str(obj, "path"),
        driver=_str(obj, "driver"),
        # ISO time when opened; gpsd sends the number 0 when it closes the device
        activated=act if isinstance(act, str) else None,
        bps=_int(obj, "bps"),
    )


def _fix(obj: Mapping[str, Any]) -> Fix:
    mode = _int(obj, "mode")
    track = _num(obj, "track")
    alt = _num(obj, "altMSL")
    return Fix(
        mode=0 if mode is None else mode,
        time=parse_time(obj.get("time")),
        track_deg=None if track is None else track % 360.0,
        speed_mps=_nonneg(obj, "speed"),
        epd=_nonneg(obj, "epd"),
        eps=_nonneg(obj, "eps"),
        lat=_num(obj, "lat"),
        lon=_num(obj, "lon"),
        alt_m=_num(obj, "alt") if alt is None else alt,
        climb_mps=_num(obj, "climb"),
        device=_str(obj, "device"),
        status=_int(obj, "status"),
    )


def parse_line(line: bytes | str) -> Report | None:
    """One line of gpsd output -> a report; None for a class hdrd does not use.

    Raises GpsdProtocolError (with the reason) for a line that is not a JSON object with a
    string ``class``, or whose known attributes have the wrong type; never anything else,
    whatever the line (numbers of any length, nesting of any depth, any bytes).
    A number that is not finite or beyond float range reads as absent (None); so does a
    negative speed or error estimate (``speed``, ``epd``, ``eps``: magnitudes).
    """
    if isinstance(line, bytes):
        try:
            line = line.decode("utf-8")
        except UnicodeDecodeError as e:
            raise GpsdProtocolError(f"not UTF-8: {e.reason}") from None
    line = line.strip()
    if not line:
        raise GpsdProtocolError("empty line")
    try:
        obj = json.loads(line)
    except json.JSONDecodeError as e:
        raise GpsdProtocolError(f"not JSON: {e.msg}") from None
    except ValueError:  # an integer of more than sys.get_int_max_str_digits() digits
        raise GpsdProtocolError("not JSON hdrd reads: a number with too many digits") from None
    except RecursionError:
        raise GpsdProtocolError("not JSON hdrd reads: nested too deeply") from None
    if not isinstance(obj, dict):
        raise GpsdProtocolError("not a JSON object")
    cls = obj.get("class")
    if not isinstance(cls, str):
        raise GpsdProtocolError("no 'class'")
    try:
        return _report(cls, obj)
    except GpsdProtocolError:
        raise
    except (ValueError, OverflowError, TypeError, RecursionError) as e:
        # A guard: every value is type-checked above, so this is a case we did not foresee;
        # the line is reported bad (counted, skipped) rather than stopping the caller.
        raise GpsdProtocolError(f"unusable {cls[:20]!r} report: {type(e).__name__}") from None


def _report(cls: str, obj: Mapping[str, Any]) -> Report | None:
    if cls == "TPV":
        return _fix(obj)
    if cls == "VERSION":
        return _version(obj)
    if cls == "DEVICES":
        return _devices(obj)
    if cls == "DEVICE":
        return _device(obj)
    if cls == "WATCH":
        return Watch(enable=_bool(obj, "enable"), json=_bool(obj, "json"))
    if cls == "ERROR":
        return GpsdError(_str(obj, "message") or "")
    return None


def _version(obj: Mapping[str, Any]) -> Version:
    return Version(
        release=_str(obj, "release") or _str(obj, "version") or "",
        rev=_str(obj, "rev"),
        proto_major=_int(obj, "proto_major"),
        proto_minor=_int(obj, "proto_minor"),
    )


def _devices(obj: Mapping[str, Any]) -> Devices:
    devs = obj.get("devices", [])
    if not isinstance(devs, list) or not all(isinstance(d, dict) for d in devs):
        raise GpsdProtocolError("'devices' is not a list of objects")
    return Devices(tuple(_device(d) for d in devs))
