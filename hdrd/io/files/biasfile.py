"""The bias file: a static bias record (:class:`hdrd.core.calibrate.BiasRecord`) as YAML,
written atomically by ``hdrd calibrate`` and read by ``hdrd run`` (docs/operations.md).

A whole file ends with a ``# end`` line; a truncated or otherwise invalid one is refused with
one line naming the file and the problem (:class:`BiasFileError`). Rates in deg/s, + = CCW.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from hdrd.core.calibrate import BiasRecord
from hdrd.core.gyronoise import GyroNoise
from hdrd.errors import HdrdError, clipped
from hdrd.io.files.access import (
    MAX_BIAS_BYTES,
    InputFileError,
    atomic_write_text,
    load_yaml,
    read_limited,
)

__all__ = ["MAX_BIAS_N", "MAX_BIAS_STD_DPS", "BiasFileError", "load_bias", "save_bias"]


class BiasFileError(HdrdError, ValueError):
    """A bias file is missing, unreadable, truncated or holds invalid values."""


_BIAS_HEADER = "# hdrd static bias (eps0), written by `hdrd calibrate`; rates in deg/s, + = CCW\n"


def save_bias(path: str | os.PathLike[str], record: BiasRecord) -> None:
    """Write a bias record as YAML, atomically, mode 0644."""
    import yaml  # imported where used: `hdrd replay --bias` never needs it (~18 ms)

    body = yaml.safe_dump(record.to_dict(), sort_keys=False)
    atomic_write_text(path, _BIAS_HEADER + body + "# end\n")


MAX_BIAS_N = 10**12
"""Most samples a bias record may claim (a year at 10 kHz is 3e11)."""
MAX_BIAS_STD_DPS = 1000.0
"""Largest sample spread a bias record may claim, deg/s (beyond any rate gyro's range)."""


def load_bias(path: str | os.PathLike[str], max_abs_bias_dps: float | None = None) -> BiasRecord:
    """Read a bias file; BiasFileError (naming the file and the problem) if it is not whole
    and valid. A truncated file lacks the ``# end`` trailer and is refused. The file must be
    a regular file of at most :data:`hdrd.io.files.access.MAX_BIAS_BYTES`.

    max_abs_bias_dps: refuse a bias_dps beyond +/- this, deg/s (the configuration's
    ``calibration.max_bias_dps``); None: any finite value.
    """
    p = Path(path)
    data = _mapping(p)
    try:
        record = BiasRecord(
            bias_dps=_finite(data, "bias_dps"),
            std_dps=_finite(data, "std_dps"),
            n=_count(data, "n"),
            duration_s=_finite(data, "duration_s"),
            temp_c=None if data.get("temp_c") is None else _finite(data, "temp_c"),
            time=_finite(data, "time"),
            noise=_noise(data.get("noise")),
        )
    except KeyError as e:
        raise BiasFileError(f"bias file {p}: missing key {e.args[0]}") from None
    except (TypeError, ValueError) as e:
        raise BiasFileError(f"bias file {p}: {e}") from None
    if record.n < 1 or record.std_dps < 0 or record.duration_s < 0:
        raise BiasFileError(f"bias file {p}: n, std_dps and duration_s must not be negative")
    if record.n > MAX_BIAS_N or record.std_dps > MAX_BIAS_STD_DPS:
        raise BiasFileError(
            f"bias file {p}: n = {_short(record.n)} or std_dps = {record.std_dps!r} is beyond "
            f"what a measurement gives (n <= {MAX_BIAS_N:.0e}, std_dps <= {MAX_BIAS_STD_DPS:g})"
        )
    if max_abs_bias_dps is not None and not abs(record.bias_dps) <= max_abs_bias_dps:
        raise BiasFileError(
            f"bias file {p}: bias_dps = {record.bias_dps!r} is beyond the "
            f"+/-{max_abs_bias_dps:g} deg/s allowed (calibration.max_bias_dps)"
        )
    return record


def _mapping(p: Path) -> dict[str, object]:
    """The bias file's text, whole (ending in ``# end``), read as a YAML mapping."""
    try:
        text = read_limited(p, MAX_BIAS_BYTES).decode("utf-8")
    except FileNotFoundError:
        raise BiasFileError(f"bias file {p}: not found") from None
    except InputFileError as e:
        raise BiasFileError(f"bias file {p}: cannot be read: {e}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise BiasFileError(f"bias file {p}: cannot be read: {e}") from None
    if not text.rstrip().endswith("# end"):
        raise BiasFileError(f"bias file {p}: truncated (no '# end' line); run `hdrd calibrate`")
    try:
        data = load_yaml(text)
    except InputFileError as e:
        at = f" at {e.where}" if e.where else ""
        raise BiasFileError(f"bias file {p}: not valid YAML{at}: {e}") from None
    # yaml only where a file is read: a replay with --bias loads none (tests/test_fastpaths.py)
    from hdrd.io.files.yamlkeys import duplicate_key

    if (dup := duplicate_key(text)) is not None:
        raise BiasFileError(f"bias file {p}: {dup}")
    if not isinstance(data, dict):
        raise BiasFileError(f"bias file {p}: expected a mapping of bias_dps, std_dps, n, ...")
    return data


def _short(v: object) -> str:
    return clipped(repr(v), 40)


def _noise(data: object) -> GyroNoise | None:
    """The recorded error model of a bias file (absent in older files: None)."""
    if data is None:
        return None
    if not isinstance(data, dict):
        raise ValueError("noise must be a mapping of noise parameters")
    try:
        return GyroNoise.from_mapping(data, source="recorded")
    except ValueError as e:
        raise ValueError(f"noise: {e}") from None


def _finite(data: dict[str, object], key: str) -> float:
    v = data[key]
    try:
        ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
    except OverflowError:  # an integer beyond float range
        ok = False
    if not ok:
        raise ValueError(f"{key} = {_short(v)} is not a finite number")
    return float(v)  # type: ignore[arg-type]


def _count(data: dict[str, object], key: str) -> int:
    v = data[key]
    if isinstance(v, bool) or not isinstance(v, int):
        raise ValueError(f"{key} = {_short(v)} is not an integer")
    return v
