"""Reading a configuration: the rule for each key, YAML -> :class:`hdrd.config.Config` with
every key checked, the file at its default path, and the command line's overrides.

Pure apart from :func:`load_config` reading the file. A value outside its rule raises
:class:`hdrd.config.ConfigError` naming the key, the value and what is allowed.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from dataclasses import fields, is_dataclass, replace
from pathlib import Path
from typing import Any

from hdrd.config import Config, ConfigError, HdrConfig, shown_value
from hdrd.core import methods
from hdrd.core.grades import GRADES
from hdrd.core.hdr import HdrParams
from hdrd.errors import clipped
from hdrd.io.files.access import MAX_CONFIG_BYTES, InputFileError, load_yaml, read_limited
from hdrd.io.net.publish import parse_hostport
from hdrd.io.wire.protocol import PROTOCOLS

__all__ = ["DEFAULT_CONFIG_PATH", "RULES", "apply_overrides", "load_config", "parse_config"]

DEFAULT_CONFIG_PATH = Path("/etc/hdrd/hdrd.yaml")


# -- rules ------------------------------------------------------------------------------

Check = Callable[[Any], bool]


def _num(
    lo: float | None = None, hi: float | None = None, lo_open: bool = False, hi_open: bool = False
) -> tuple[Check, str]:
    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {_fmt(lo)}")
    if hi is not None:
        parts.append(f"{'<' if hi_open else '<='} {_fmt(hi)}")
    desc = "a finite number" + (" " + " and ".join(parts) if parts else "")

    def check(v: float) -> bool:
        if lo is not None and (v <= lo if lo_open else v < lo):
            return False
        if hi is not None and (v >= hi if hi_open else v > hi):
            return False
        return True

    check.bounds = (lo, hi, lo_open, hi_open)  # type: ignore[attr-defined] # for the tests
    return check, desc


def _fmt(v: float) -> str:
    """A bound as written in a message: integers in full, others short (0.01, 1e-06)."""
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e16 else f"{v:g}"


def _choice(*options: Any) -> tuple[Check, str]:
    return (lambda v: v in options), "one of " + ", ".join(str(o) for o in options)


def _method() -> tuple[Check, str]:
    """A registered drift reducer (:data:`hdrd.core.methods.REGISTRY`, read when checked)."""
    return (
        (lambda v: isinstance(v, str) and v in methods.REGISTRY),
        "one of " + ", ".join(methods.names()),
    )


def _drive() -> tuple[Check, Callable[[], str]]:
    """A simulated drive (:data:`hdrd.sim.vehicle.DRIVE_TYPES`, read when checked: the
    simulator is not loaded with the configuration)."""

    def drives() -> tuple[str, ...]:
        # the simulator is not loaded with the configuration (a drive type is checked lazily)
        from hdrd.sim.vehicle import DRIVE_TYPES

        return tuple(DRIVE_TYPES)

    return (lambda v: v in drives()), lambda: "one of " + ", ".join(drives())


MAX_DESTINATIONS = 16
"""Most destinations of ``output.udp`` (and ``output.nmea_udp``): each is sent every step, and
its name resolved on every reload."""
_HOSTPORTS = f"a list of at most {MAX_DESTINATIONS} HOST:PORT (port 1..65535; IPv6 as [::1]:PORT)"


def _hostports(v: tuple[str, ...]) -> bool:
    """True if every item is a HOST:PORT, and there are at most :data:`MAX_DESTINATIONS`;
    ValueError naming the first that is not, and why."""
    if len(v) > MAX_DESTINATIONS:
        raise ValueError(f"{len(v)} destinations are more than {MAX_DESTINATIONS}")
    for item in v:
        try:
            parse_hostport(item)
        except ValueError as e:
            raise ValueError(f"{clipped(repr(item), 60)} is not: {e}") from None
    return True


_POS = _num(0, lo_open=True)
MAX_FIX_AGE_S = 10.0
"""Largest ``gpsd.max_fix_age_s``, s: a course older than that has been carried by the gyro
through ten 1 s steps, and a speed that old (the standstill test's) says nothing of now; a
1 Hz receiver that missed ten fixes has lost the sky."""
_NONNEG = _num(0)
# Upper (and some lower) bounds keep every later computation finite: a value inside them
# cannot overflow a float, divide by zero or wait forever anywhere in hdrd (a test steps
# the pipeline with every key at both ends of its range). docs/configuration.md says why
# each bound is where it is.
_SECONDS = _num(0, 3600, lo_open=True)
RULES: dict[str, tuple[Check, str | Callable[[], str]]] = {
    "device.port": (
        (lambda v: bool(v.strip()) and "\0" not in v),
        "a non-empty device path or pyserial URL, without a NUL character",
    ),
    "device.protocol": _choice(*PROTOCOLS),
    "device.baud": _num(50, 20_000_000),
    "device.reconnect_min_s": _SECONDS,
    "device.reconnect_max_s": _SECONDS,
    "device.stale_after_s": _SECONDS,
    "device.clock_rate": _num(0, 1_000_000),
    "sensor.adc_bits": _num(8, 32),
    "sensor.vref_v": _num(0.01, 100),
    "sensor.null_v": _num(0, 100),
    "sensor.scale_v_per_dps": _num(1e-6, 100),
    "sensor.polarity": _choice(1, -1),
    "sensor.range_dps": _num(0, 100_000, lo_open=True),
    "sensor.ref_divider": _num(0.01, 100),
    "sensor.supply_nominal_v": _num(0.01, 100),
    "sensor.supply_tolerance": _num(0, 1, lo_open=True),
    "sensor.supply_max_step_v": _num(0, 100, lo_open=True),
    "hdr.method": _method(),
    "hdr.i_c": _num(0, 10),
    "hdr.tau": _num(0, 3600),
    "hdr.theta_w": _num(0, 100_000, lo_open=True),
    "hdr.c1": _num(0, 1000),
    "hdr.c2": _num(0, 10),
    "hdr.T": _num(0.01, 60),
    "calibration.t_bias_s": _SECONDS,
    "calibration.startup_s": _num(0, 600, lo_open=True),
    # A path is handed to the OS, which cannot take a NUL character (ValueError).
    "calibration.bias_file": ((lambda v: "\0" not in v), "a path without a NUL character"),
    "calibration.on_bad_bias_file": _choice("error", "calibrate"),
    "calibration.max_std_dps": _POS,
    "calibration.max_trend_dps": _POS,
    "calibration.max_excursion_dps": _POS,
    "calibration.max_bias_dps": _num(0, 1000, lo_open=True),
    "calibration.no_data_timeout_s": _SECONDS,
    "output.heading0_deg": _num(0, 360, hi_open=True),
    "output.udp": (_hostports, _HOSTPORTS),
    "output.nmea_udp": (_hostports, _HOSTPORTS),
    "output.nmea_talker": (
        (lambda v: len(v) == 2 and v.isascii() and v.isalpha() and v.isupper()),
        "two capital letters, e.g. HN, or II for gpsd",
    ),
    "log.level": _choice("debug", "info", "warning", "error"),
    "log.format": _choice("auto", "json", "console"),
    "log.bad_frame_interval_s": _SECONDS,
    "simulate.drive": _drive(),
    "simulate.seed": _num(0, 2**32 - 1),
    "simulate.rate_hz": _num(1, 10_000),
    "simulate.speedup": _num(0.001, 1_000_000),
    "simulate.grade": _choice(*GRADES),
    "gyro.grade": _choice("none", *GRADES),
    "gyro.white_dps_per_rthz": _num(0, 100),
    "gyro.bias_instability_dps": _num(0, 100),
    "gyro.bias_tau_s": _num(1, 1_000_000),
    "gyro.rrw_dps_per_sqrt_s": _num(0, 100),
    "gyro.temp_coeff_dps_per_c": _num(0, 100),
    "gyro.quant_step_dps": _num(0, 100),
    "gyro.motion_offset_dps": _num(-5, 5),
    "gyro.motion_offset_sd_dps": _num(0, 5),
    "gyro.stop_scatter_dps": _num(0, 5),
    "gpsd.host": ((lambda v: bool(v.strip())), "a host name or address"),
    "gpsd.port": _num(1, 65535),
    "gpsd.min_speed_mps": _NONNEG,
    "gpsd.max_fix_age_s": _num(0, MAX_FIX_AGE_S, lo_open=True),
    "gpsd.max_epd_deg": _num(0, 180, lo_open=True),
    "gpsd.align_gain": _num(0, 1),
    "gpsd.bias_window_s": _POS,
    "gpsd.bias_gain": _num(0, 1),
    "gpsd.device": (
        (lambda v: "\0" not in v and v == v.strip()),
        "a device path as gpsd names it (no NUL, no surrounding spaces), or empty for the "
        "first receiver with a fix",
    ),
}


_YAML11_TEXT_NUMBER = re.compile(r"[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)[eE][-+]?[0-9]+")
"""A number in exponent form that YAML 1.1 (PyYAML) reads as text: its floats need a dot
and a signed exponent (``1.0e+9``), so ``1.0e9`` and ``1e-2`` are strings to it; YAML 1.2
reads them as numbers, and so does a number key here. Other text stays text (``"0.5"``,
quoted, is a string, refused)."""


def _coerce(key: str, value: Any, default: Any) -> Any:
    """Check the YAML value's type against the default's type; return it in that type.

    A number key also takes a number that YAML 1.1 reads as text (``1e-2``, ``1.0e9``:
    :data:`_YAML11_TEXT_NUMBER`)."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(key, value, "must be true or false")
        return value
    if isinstance(default, int):
        return _coerce_int(key, value)
    if isinstance(default, float):
        return _coerce_float(key, value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ConfigError(key, value, "must be a string")
        return value
    if isinstance(default, tuple):
        return _coerce_strings(key, value)
    raise AssertionError(f"no coercion for {key}")  # pragma: no cover - a programming error


def _coerce_int(key: str, value: Any) -> int:
    if isinstance(value, str) and _YAML11_TEXT_NUMBER.fullmatch(value):
        raise ConfigError(key, value, "must be an integer, written out in digits")
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(key, value, "must be an integer")
    return value


def _coerce_float(key: str, value: Any) -> float:
    written = value
    if isinstance(value, str) and _YAML11_TEXT_NUMBER.fullmatch(value):
        value = float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(key, value, "must be a number")
    try:
        number = float(value)
    except OverflowError:  # an integer too large for a float
        raise ConfigError(key, value, "must be a finite number") from None
    if not math.isfinite(number):
        raise ConfigError(key, written, "must be a finite number")
    return number


def _coerce_strings(key: str, value: Any) -> tuple[str, ...]:
    """A list of strings, or one string as a list of one."""
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(key, value, "must be a list of strings")
    return tuple(value)


def _check(key: str, value: Any) -> None:
    rule = RULES.get(key)
    if rule is None:
        return
    check, allowed = rule[0], rule[1]() if callable(rule[1]) else rule[1]
    try:
        ok = check(value)
    except ValueError as e:  # a check that says what is wrong
        raise ConfigError(key, value, f"must be {allowed}; {e}") from None
    if not ok:
        raise ConfigError(key, value, f"must be {allowed}")


def _build(cls: type, data: Any, prefix: str) -> Any:
    """A section dataclass from a YAML mapping, every key checked."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(prefix, data, "must be a mapping of keys")
    defaults = cls()
    # hdr's parameters live flat in the YAML section beside `method`.
    flat = {f.name: f for f in fields(HdrParams)} if cls is HdrConfig else {}
    values: dict[str, Any] = {}
    params: dict[str, Any] = {}
    for k, v in data.items():
        _one_key(cls, defaults, prefix, k, v, values, params)
    if flat:
        values["params"] = replace(defaults.params, **params)
    return replace(defaults, **values)


def _one_key(
    cls: type,
    defaults: Any,
    prefix: str,
    k: Any,
    v: Any,
    values: dict[str, Any],
    params: dict[str, Any],
) -> None:
    """One key of a section, checked, into ``values`` (or hdr's ``params``)."""
    names = [f.name for f in fields(cls) if f.name not in _DERIVED and f.name != "params"]
    flat = [f.name for f in fields(HdrParams)] if cls is HdrConfig else []
    key = f"{prefix}.{k}" if prefix else str(k)
    if key in RENAMED:
        raise ConfigError(key, v, RENAMED[key])
    if cls is HdrConfig and k == "i_c" and _increment_is_auto(key, v, values):
        return
    if k in flat:
        v = _coerce(key, v, getattr(defaults.params, k))
        _check(key, v)
        params[k] = v
    elif k in names:
        values[k] = _value(key, v, getattr(defaults, k))
    else:
        what = "unknown key" if prefix else "unknown section"
        raise ConfigError(key, v, f"{what} (allowed: " + ", ".join(names + flat) + ")")


def _increment_is_auto(key: str, value: Any, values: dict[str, Any]) -> bool:
    """``hdr.i_c``: True for ``auto`` (recorded in ``values``); False for a number, left to
    be read as one; a ConfigError for other text."""
    values["i_c_auto"] = value == "auto"
    if value == "auto":
        return True
    if isinstance(value, str) and not _YAML11_TEXT_NUMBER.fullmatch(value):
        raise ConfigError(key, value, f"must be auto or {RULES[key][1]}")
    return False


_DERIVED = ("i_c_auto",)
"""Fields no key names directly (``hdr.i_c: auto`` sets ``i_c_auto``)."""

RENAMED: dict[str, str] = {
    "plus": "is now the `gyro:` section (the same keys: gyro.grade, gyro.white_dps_per_rthz, "
    "...): rename it",
    "hdr.i_c_from": "was removed: write hdr.i_c: auto (the increment from the gyro's error "
    "model, the default) or hdr.i_c: NUMBER (that increment whatever the gyro)",
}
"""Keys of older configurations, refused with what to write instead."""


def _value(key: str, value: Any, default: Any) -> Any:
    """One key's value, checked: a section of its own when the default is a dataclass."""
    if is_dataclass(default):
        return _build(type(default), value, key)
    value = _coerce(key, value, default)
    _check(key, value)
    return value


def parse_config(data: Any, source: str | None = None) -> Config:
    """A validated :class:`Config` from parsed YAML (a mapping of sections)."""
    try:
        if data is None:
            raise ConfigError("(file)", "", "the file is empty; expected a mapping of sections")
        if not isinstance(data, dict):
            raise ConfigError(
                "(file)", data, f"the file holds {shown_value(data)}, not a mapping of sections"
            )
        data = _top_level_method(data)
        cfg: Config = _build(Config, data, "")
        _cross_check(cfg)
        return cfg
    except ConfigError as e:
        raise (e.with_source(source) if source else e) from None


def _top_level_method(data: dict[Any, Any]) -> dict[Any, Any]:
    """A top-level ``method: hdr+`` (an older spelling) is ``hdr.method``; giving both with
    different values is an error. Returns the mapping with it moved into ``hdr``."""
    if "method" not in data:
        return data
    data = dict(data)
    v = data.pop("method")
    check, allowed = RULES["hdr.method"]
    if not isinstance(v, str) or not check(v):
        raise ConfigError("method", v, f"must be {allowed}")
    hdr = data.get("hdr")
    if hdr is None:
        hdr = {}
    if not isinstance(hdr, dict):
        return data  # _build reports the bad hdr section
    if "method" in hdr and hdr["method"] != v:
        raise ConfigError("method", v, f"conflicts with hdr.method = {hdr['method']!r}; give one")
    data["hdr"] = {**hdr, "method": v}
    return data


def _cross_check(cfg: Config) -> None:
    if cfg.device.reconnect_max_s < cfg.device.reconnect_min_s:
        raise ConfigError(
            "device.reconnect_max_s",
            cfg.device.reconnect_max_s,
            "must be >= device.reconnect_min_s",
        )


def load_config(path: str | os.PathLike[str] | None = None) -> tuple[Config, str]:
    """Load and validate a config file; returns (config, where it came from).

    path None: DEFAULT_CONFIG_PATH if it exists, else the built-in defaults (which equal the
    shipped config/hdrd.yaml). An explicit path that does not exist is an error.
    """
    if path is None:
        if not DEFAULT_CONFIG_PATH.exists():
            return Config(), "built-in defaults"
        path = DEFAULT_CONFIG_PATH
    p = Path(path)

    try:
        text = read_limited(p, MAX_CONFIG_BYTES).decode("utf-8")
    except FileNotFoundError:
        raise ConfigError("(file)", str(p), "no such file", str(p)) from None
    except InputFileError as e:
        raise ConfigError("(file)", str(p), f"cannot be read: {e}", str(p)) from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(
            "(file)", str(p), f"cannot be read ({e.__class__.__name__})", str(p)
        ) from None
    try:
        data = load_yaml(text)
    except InputFileError as e:
        raise ConfigError("(yaml)", e.where or "?", e.problem, str(p)) from None
    # yaml only where a file is read: a replay with --bias loads none (tests/test_fastpaths.py)
    from hdrd.io.files.yamlkeys import duplicate_key

    if (dup := duplicate_key(text)) is not None:
        raise ConfigError(
            dup.path,
            f"line {dup.first_line} and line {dup.second_line}",
            "given twice; give each key once (YAML would keep the last without a word)",
            str(p),
        )
    return parse_config(data, str(p)), str(p)


_SECTIONS = tuple(f.name for f in fields(Config))


def apply_overrides(cfg: Config, overrides: dict[str, Any]) -> Config:
    """Return cfg with 'section.key' values replaced (command-line flags), each validated."""
    for dotted, value in overrides.items():
        if value is None:
            continue
        section, _, key = dotted.partition(".")
        if section not in _SECTIONS:
            raise ConfigError(
                dotted, value, "unknown section (allowed: " + ", ".join(_SECTIONS) + ")"
            )
        sec = getattr(cfg, section)
        data = {key: list(value) if isinstance(value, tuple) else value}
        if section == "hdr":
            merged = {"method": sec.method, **sec.params.as_dict(), **data}
            if sec.i_c_auto and "i_c" not in data:
                merged["i_c"] = "auto"
            new = _build(HdrConfig, merged, section)
        else:
            merged = {f.name: getattr(sec, f.name) for f in fields(sec)}
            merged = {k: list(v) if isinstance(v, tuple) else v for k, v in merged.items()}
            merged.update(data)
            new = _build(type(sec), merged, section)
        cfg = replace(cfg, **{section: new})
    _cross_check(cfg)
    return cfg
