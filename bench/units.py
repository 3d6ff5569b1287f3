"""The units of the training routes: simulated gyros that hold what real units were measured
to do, on the set's real road and on simulated drives.

    from units import unit_logs; unit_logs("tune", 64)

Measured on real units (facts, not data; the issue that set HDR+'s targets lists them): a
motion offset of 0 to 0.1 deg/s in magnitude, fixed per unit (two units in one car: -0.09 and
~0); stops that read 0.005-0.04 deg/s off a still-good driving bias; phone biases wandering
0.01-0.03 deg/s within minutes (bias instability ~0.01 deg/s, tau 30-40 s); a unit stored in
0.573 deg/s codes, undithered at rest. Each unit k of a set draws from its seed: a grade
(crs03, phone, automotive, tactical, in turn), a motion offset (0 for 30 % of units, else
uniform 0.01-0.1 deg/s of either sign: :class:`hdrd.sim.gyro.MotionOffset`), a stop scatter
(none for half, else uniform 0.005-0.04 deg/s: :class:`hdrd.sim.gyro.StopOffset`), a phone's
wander (:class:`hdrd.sim.gyro.BiasInstability` of 0.01 deg/s at its Allan floor, tau 35 s), one
unit in seven stored in 0.573 deg/s codes, and a logged temperature for one in five (a real log
seldom has one). Even units drive the set's Boreas route (bench/holds.py ``ROUTES``) from one
of its stops, odd ones a simulated drive of 20 minutes (city, mixed, suburbs, highway, rural in
turn; the simulator's roads are straighter than real ones, the route's are real). Seeds: tune
1000 + k, judge 5000 + k.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from hdrd.core.grades import GM_PEAK, Grade
from hdrd.io.files.drivelog import DriveLog
from hdrd.sim.drive import simulate_drive
from hdrd.sim.effects import BiasInstability, MotionOffset, Quantization, StopOffset
from hdrd.sim.grades import grade_model
from hdrd.sim.gyro import GyroModel
from hdrd.sim.roads import road_drive, route_stops

__all__ = ["Unit", "draw_unit", "unit_logs", "unit_model"]

GRADES = ("crs03", "phone", "automotive", "tactical")
DRIVES = ("city", "mixed", "suburbs", "highway", "rural")
FIRST_SEED = {"tune": 1000, "judge": 5000}
CODE_DPS = 0.573
"""The coarse unit's output step, deg/s (0.01 rad/s)."""


@dataclass(frozen=True)
class Unit:
    """One unit of the population (module docstring); rates deg/s."""

    grade: str
    motion_offset_dps: float
    stop_sd_dps: float
    wander: bool
    coarse: bool
    temperature: bool

    @property
    def kind(self) -> str:
        """Its group in the tables: what is most telling of it."""
        if self.coarse:
            return "coarse (0.573 codes)"
        if abs(self.motion_offset_dps) >= 0.05:
            return "offset >= 0.05"
        if self.motion_offset_dps != 0.0:
            return "offset < 0.05"
        return "no offset"


def draw_unit(seed: int, k: int) -> Unit:
    """Unit k of a set, drawn from its seed (module docstring)."""
    rng = np.random.default_rng(seed)
    grade = GRADES[k % len(GRADES)]
    offset = 0.0 if rng.random() < 0.3 else float(rng.uniform(0.01, 0.1) * rng.choice([-1, 1]))
    stop_sd = 0.0 if rng.random() < 0.5 else float(rng.uniform(0.005, 0.04))
    temperature = bool(rng.random() < 0.2)
    return Unit(grade, offset, stop_sd, grade == "phone", k % 7 == 3, temperature)


def unit_model(u: Unit, seed: int) -> GyroModel:
    """The unit's gyro: its grade's, with its facts put in."""
    m = grade_model(u.grade, seed)
    if u.motion_offset_dps:
        m = m.with_effect(MotionOffset(offset_dps=u.motion_offset_dps))
    if u.stop_sd_dps:
        m = m.with_effect(StopOffset(sd_dps=u.stop_sd_dps))
    if u.wander:
        m = m.with_effect(BiasInstability(sigma_dps=0.01 / GM_PEAK, tau_s=35.0))
    if u.coarse:
        m = m.with_effect(Quantization(step_dps=CODE_DPS))
    return m


def unit_logs(which: str, n: int, route: DriveLog) -> list[tuple[Unit, DriveLog]]:
    """The set's n units and their drives (module docstring); ``route``: the set's Boreas
    route (bench/holds.py ``route_log``)."""
    starts = [math.floor(a) + 1.0 for a, _ in route_stops(route) if route.duration_s - a >= 660]
    out = []
    for k in range(n):
        seed = FIRST_SEED[which] + k
        u = draw_unit(seed, k)
        m = unit_model(u, seed)
        rate = Grade.from_table(u.grade).rate_hz
        if k % 2 == 0:
            log = road_drive(
                route, m, seed, hz=rate, start_s=starts[k % len(starts)], name=f"unit-road-{k}"
            )
        else:
            drive = DRIVES[k % len(DRIVES)]
            log = replace(
                simulate_drive(drive, 20.0, seed, hz=rate, model=m), name=f"unit-{drive}-{k}"
            )
        if not u.temperature:
            log = replace(log, temp_c=None)
        out.append((u, log))
    return out
