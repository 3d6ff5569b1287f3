"""The sensor faults the daemon publishes, said in its log (an edge: it reads a clock).

The pipeline leaves out of a step each sample the gyro cannot have given and counts it in the
step's message (docs/protocol.md, "What is not a rate"): ``supply_faults`` with ``supply_v``,
the supply reading farthest from the nominal supply, and ``saturated``. A fault lasts: a
divider that opened gives one in every sample, for as long as the car drives. So the log gets
one warning per kind at most every ``interval_s``, counting what was left out since the one
before and naming the worst supply reading seen meanwhile.
"""

from __future__ import annotations

import math

from hdrd.core.sensor import SensorModel
from hdrd.core.throttle import Throttle
from hdrd.io.logs import log
from hdrd.io.wire.protocol import Message

__all__ = ["FaultLog"]


class FaultLog:
    """``supply_fault`` and ``samples_saturated`` warnings from published messages, each at
    most once per ``interval_s`` (s, the monotonic clock the caller passes)."""

    def __init__(self, sensor: SensorModel, interval_s: float) -> None:
        self.sensor = sensor
        self._supply, self._sat = Throttle(interval_s), Throttle(interval_s)
        self.supply_faults = 0
        """Samples with a supply fault since start."""
        self.saturated = 0
        """Saturated samples since start."""
        self._supply_new = self._sat_new = 0  # since the last warning of each kind
        self._worst_v = math.nan  # the supply reading farthest from nominal, since then

    @property
    def interval_s(self) -> float:
        """At most one warning of each kind per this many seconds."""
        return self._supply.interval_s

    @interval_s.setter
    def interval_s(self, value: float) -> None:
        self._supply.interval_s = self._sat.interval_s = value

    def on_messages(self, msgs: list[Message], now: float, steps: bool = True) -> None:
        """The faults of published messages (a listener of the loop,
        :mod:`hdrd.daemon.listeners`); a warning for each kind that is due."""
        for m in msgs:
            n = m.get("supply_faults", 0)
            if n:
                self.supply_faults += n
                self._supply_new += n
                self._worst_v = self._worse(self._worst_v, m["supply_v"])
            s = m.get("saturated", 0)
            self.saturated += s
            self._sat_new += s
        if self._supply_new and self._supply.due(now):
            s = self.sensor
            log.warning(
                "supply_fault",
                supply_v=round(self._worst_v, 3),
                samples=self._supply_new,
                total=self.supply_faults,
                allowed=f"{s.supply_min_v:.3g} .. {s.supply_max_v:.3g} V, changing by at most "
                f"{s.supply_max_step_v:g} V from one sample to the next",
                reason="the gyro's supply as the monitor (ref) reads it is not a supply the "
                "gyro runs on: these samples are not a rate and were left out; check the "
                "divider and the supply wiring",
            )
            self._supply_new, self._worst_v = 0, math.nan
        if self._sat_new and self._sat.due(now):
            log.warning(
                "samples_saturated",
                samples=self._sat_new,
                total=self.saturated,
                range_dps=self.sensor.range_dps,
                reason="at an ADC rail or beyond sensor.range_dps: not a rate the gyro "
                "measures; left out",
            )
            self._sat_new = 0

    def _worse(self, a: float, b: float) -> float:
        """Of two supply readings (V, NaN: none) the one farther from the nominal supply."""
        nominal = self.sensor.supply_nominal_v
        if a != a:
            return b
        return b if abs(b - nominal) > abs(a - nominal) else a
