"""What the daemon learns of its unit, kept across trips: the unit state file beside the bias
file (:mod:`hdrd.io.files.unitstate`) read at start and written as the trip goes on.

Used only when the static bias comes from a bias file (``hdrd calibrate``'s, the service's):
the unit is then the one that file belongs to. A state file that cannot be used is said in
one line (``unit_state_rejected``) and the daemon starts as for a fresh unit; one that cannot
be written is said once (``unit_state_not_written``) and the daemon runs on. Written every
:data:`SAVE_EVERY_S` while the daemon runs and at its stop, atomically.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import structlog

from hdrd.daemon.stepper import Stepper
from hdrd.io.files.unitstate import (
    UnitState,
    UnitStateError,
    load_unit_state,
    save_unit_state,
    unit_state_path,
)

__all__ = ["SAVE_EVERY_S", "UnitKeeper"]

log = structlog.get_logger("hdrd")

SAVE_EVERY_S = 300.0
"""The state file is written this often while the daemon runs, s (and at its stop)."""


class UnitKeeper:
    """The unit's state file for one daemon run."""

    def __init__(self, bias_file: str | None) -> None:
        self.path: Path | None = unit_state_path(bias_file) if bias_file else None
        self.state: UnitState | None = None
        self._saved_at = -math.inf
        self._failed = False
        if self.path is None:
            return
        try:
            self.state = load_unit_state(self.path)
        except UnitStateError as e:
            log.warning(
                "unit_state_rejected", path=str(self.path), error=str(e), fallback="a fresh unit"
            )
        if self.state is not None:
            log.info(
                "unit_state",
                path=str(self.path),
                trips=self.state.trips,
                motion_offset_dps=_num(self.state.motion_offset_dps),
                outage_policy=self.state.outage_record.policy(),
            )

    def due(self, now: float) -> bool:
        """Time to write (``now``: a monotonic clock, s)."""
        return self.path is not None and now - self._saved_at >= SAVE_EVERY_S

    def save(self, stepper: Stepper, now: float, wall: float) -> None:
        """Write what the stepper has learned of the unit: its motion offset (once
        observable: :meth:`hdrd.daemon.stepper.Stepper.learned_offset`, else the one it
        started with), the outage policies' record, this trip counted once."""
        if self.path is None:
            return
        self._saved_at = now
        start = self.state or UnitState()
        learned = stepper.learned_offset()
        m, sd = (
            learned
            if learned is not None
            else (start.motion_offset_dps, start.motion_offset_sd_dps)
        )
        state = replace(
            start,
            motion_offset_dps=m,
            motion_offset_sd_dps=sd,
            outage_record=stepper.outage_record,
            trips=(self.state.trips if self.state is not None else 0) + 1,
            updated=wall,
        )
        try:
            save_unit_state(self.path, state)
        except OSError as e:
            if not self._failed:
                log.warning(
                    "unit_state_not_written", path=str(self.path), error=e.strerror or str(e)
                )
            self._failed = True


def _num(v: float) -> float | None:
    return round(v, 6) if math.isfinite(v) else None
