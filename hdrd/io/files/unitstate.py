"""The unit's state file, beside the bias file: what this unit's trips have shown of it.

``hdrd run`` with GPS learns on the road what the unit's profile holds (its motion offset,
whenever it sees stops and GPS courses both) and the record of its outage policies
(:mod:`hdrd.core.selfcheck`); it keeps them here, so that the unit's next trip starts from what
its last trips showed (docs/hdrplus.md, "What the unit's trips teach"). YAML, written
atomically, with a schema ``version`` and a ``# end`` line; a file that is truncated, of
another version or holds a value out of range is refused in one line naming it and the
problem (:class:`UnitStateError`). Rates deg/s (a motion offset: the driving bias minus the
bias at rest); headings deg; times UNIX s.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from hdrd.core.gyronoise import GyroNoise
from hdrd.core.selfcheck import OutageRecord
from hdrd.errors import HdrdError, clipped
from hdrd.io.files.access import (
    MAX_BIAS_BYTES,
    InputFileError,
    atomic_write_text,
    load_yaml,
    read_limited,
)

__all__ = [
    "MAX_OFFSET_DPS",
    "VERSION",
    "UnitState",
    "UnitStateError",
    "load_unit_state",
    "save_unit_state",
    "unit_state_path",
]

VERSION = 1
"""The state file's schema version; another one is refused (the daemon starts without it)."""

MAX_OFFSET_DPS = 5.0
"""The largest motion offset a state file may hold, deg/s (beyond any gyro's)."""


class UnitStateError(HdrdError, ValueError):
    """A unit state file that is unreadable, truncated, of another version or out of range."""


@dataclass(frozen=True)
class UnitState:
    """What this unit's trips showed: its motion offset and how well it is known (deg/s;
    NaN: not learned yet), the trips that taught it, the outage policies' record, and when it
    was written (UNIX s)."""

    motion_offset_dps: float = math.nan
    motion_offset_sd_dps: float = math.nan
    trips: int = 0
    outage_record: OutageRecord = field(default_factory=OutageRecord)
    updated: float = 0.0

    def profile(self) -> GyroNoise | None:
        """The learned part of the unit's profile (source ``learned``), or None."""
        if not (math.isfinite(self.motion_offset_dps) and math.isfinite(self.motion_offset_sd_dps)):
            return None
        return GyroNoise(
            motion_offset_dps=self.motion_offset_dps,
            motion_offset_sd_dps=self.motion_offset_sd_dps,
            source="learned",
        )


_HEADER = (
    "# hdrd unit state: what this unit's trips showed (docs/hdrplus.md); written by hdrd run\n"
)


def unit_state_path(bias_file: str | os.PathLike[str]) -> Path:
    """The state file beside a bias file: ``unit.yaml`` in its folder."""
    return Path(bias_file).with_name("unit.yaml")


def save_unit_state(path: str | os.PathLike[str], state: UnitState) -> None:
    """Write the state, atomically, mode 0644."""
    import yaml

    data: dict[str, object] = {"version": VERSION}
    if math.isfinite(state.motion_offset_dps) and math.isfinite(state.motion_offset_sd_dps):
        data["motion_offset_dps"] = round(state.motion_offset_dps, 6)
        data["motion_offset_sd_dps"] = round(state.motion_offset_sd_dps, 6)
    data["trips"] = state.trips
    data["outage_record"] = state.outage_record.to_dict()
    data["updated"] = round(state.updated, 3)
    body = yaml.safe_dump(data, sort_keys=False)
    atomic_write_text(path, _HEADER + body + "# end\n")


def load_unit_state(path: str | os.PathLike[str]) -> UnitState | None:
    """Read a state file; None when there is none yet; UnitStateError (one line naming the
    file and the problem) when it cannot be used."""
    p = Path(path)
    try:
        text = read_limited(p, MAX_BIAS_BYTES).decode("utf-8")
    except FileNotFoundError:
        return None
    except (InputFileError, OSError, UnicodeDecodeError) as e:
        raise UnitStateError(f"unit state {p}: cannot be read: {e}") from None
    if not text.rstrip().endswith("# end"):
        raise UnitStateError(
            f"unit state {p}: truncated (no '# end' line); delete it to start afresh"
        )
    try:
        data = load_yaml(text)
    except InputFileError as e:
        raise UnitStateError(f"unit state {p}: not valid YAML: {e}") from None
    if not isinstance(data, dict):
        raise UnitStateError(f"unit state {p}: expected a mapping with version {VERSION}")
    if data.get("version") != VERSION:
        v = clipped(repr(data.get("version")), 40)
        raise UnitStateError(f"unit state {p}: version {v}, this hdrd reads version {VERSION}")
    try:
        return _state(data)
    except ValueError as e:
        raise UnitStateError(f"unit state {p}: {e}") from None


def _state(data: dict[str, object]) -> UnitState:
    unknown = set(data) - {"version", "motion_offset_dps", "motion_offset_sd_dps", "trips",
                           "outage_record", "updated"}  # fmt: skip
    if unknown:
        raise ValueError(f"unknown key {sorted(unknown)[0]!r}")
    m = _number(data, "motion_offset_dps", -MAX_OFFSET_DPS, MAX_OFFSET_DPS)
    sd = _number(data, "motion_offset_sd_dps", 0.0, MAX_OFFSET_DPS)
    if math.isnan(m) != math.isnan(sd):
        raise ValueError("motion_offset_dps and motion_offset_sd_dps go together")
    trips = data.get("trips", 0)
    if isinstance(trips, bool) or not isinstance(trips, int) or not 0 <= trips <= 10**9:
        raise ValueError(f"trips = {clipped(repr(trips), 40)} is not a count")
    updated = _number(data, "updated", 0.0, 1e11)
    record = OutageRecord.from_dict(data.get("outage_record", {}))
    return UnitState(m, sd, trips, record, 0.0 if math.isnan(updated) else updated)


def _number(data: dict[str, object], key: str, lo: float, hi: float) -> float:
    """data[key] as a float in [lo, hi]; NaN when absent."""
    if key not in data:
        return math.nan
    v = data[key]
    try:
        ok = not isinstance(v, bool) and isinstance(v, (int, float)) and lo <= float(v) <= hi
    except OverflowError:
        ok = False
    if not ok:
        raise ValueError(f"{key} = {clipped(repr(v), 40)} must be a number in {lo:g}..{hi:g}")
    return float(v)  # type: ignore[arg-type]
