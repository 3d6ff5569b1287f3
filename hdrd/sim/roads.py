"""Simulated gyros on real roads: a *route* (a real drive's true yaw rate, speed and heading,
e.g. an INS's, ``tools/convert_real.py boreas``) carrying the simulator's gyro of a grade.

Pure and deterministic for a seed. Where :func:`hdrd.sim.drive.simulate_legs` makes up the
road, :func:`road_drive` takes it from the route and assembles the rest as a simulated drive
does: a start-up standstill of ``lead_in_s`` prepended (so that evaluate can measure the
static bias, metadata ``lead_in_s``), the cabin temperature
(:class:`hdrd.sim.vehicle.CabinTemperature`), the gyro's output
(:meth:`hdrd.sim.gyro.GyroModel.apply`, given the speed so that a ``motion_offset`` applies)
and a GPS course (:func:`hdrd.sim.gps.gps_course`). The seed is split into independent
streams as a simulated drive's are (the route's, unused here; the temperature's, the GPS's, the
gyro's), so another gyro model on the same route and seed changes only ``omega``.

The columns: ``omega`` the simulated gyro (deg/s, + = CCW, bias included); ``omega_truth`` the
route's true rate resampled to ``hz`` (linear), zero over the lead-in; ``heading_truth`` the
true compass heading at every row, exact with ``omega_truth`` (heading0 - its trapezoid
integral, heading0 the route's first heading); ``speed`` (m/s); ``temp_c``; ``gps_course``
the 1 Hz course of :class:`hdrd.sim.gps.GpsModel` (noise atan(vel_noise / speed) and a floor;
empty between epochs and below its speed threshold) and ``gps_speed`` the true speed at those
fixes. Units: time s from power-on, headings compass deg (clockwise from north).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict

import numpy as np
import numpy.typing as npt

from hdrd import __version__
from hdrd.core.grades import Grade
from hdrd.errors import HdrdError
from hdrd.io.files.drivelog import DriveLog
from hdrd.sim.effects import MotionOffset
from hdrd.sim.gps import GpsModel, gps_course, heading_from_rate
from hdrd.sim.grades import grade_model
from hdrd.sim.gyro import GyroModel
from hdrd.sim.vehicle import CabinTemperature

__all__ = ["RouteError", "grade_on_road", "road_drive", "route_stops", "route_truth"]

FloatArray = npt.NDArray[np.float64]

DEFAULT_GPS = GpsModel()
"""1 Hz course, unusable below 2 m/s, no outages (a simulated drive's default)."""


class RouteError(HdrdError, ValueError):
    """A drive log that cannot serve as a route; the message names it and says why."""


def route_truth(route: DriveLog) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """(t s from the route's start, true rate deg/s CCW, speed m/s, first compass heading deg)
    of a route: its ``omega_truth`` (else its ``omega`` when its metadata says ``route``), its
    ``speed`` and the first known ``heading_truth``. RouteError when one is missing, not
    finite everywhere, or the route has fewer than two rows."""
    name = route.name or "route"
    rate = route.omega_truth
    if rate is None and "route" in route.meta:
        rate = route.omega
    if rate is None or route.speed is None or route.heading_truth is None:
        raise RouteError(
            f"{name}: a route needs omega_truth (or route metadata), speed and heading_truth"
        )
    if len(route) < 2:
        raise RouteError(f"{name}: fewer than two rows")
    if not (np.isfinite(rate).all() and np.isfinite(route.speed).all()):
        raise RouteError(f"{name}: the true rate and the speed must be known at every row")
    known = np.flatnonzero(np.isfinite(route.heading_truth))
    if known.shape[0] == 0:
        raise RouteError(f"{name}: no heading_truth")
    # The heading at the first row, back from the first known one along the true rate.
    i = int(known[0])
    turned = float(np.sum(0.5 * (rate[1 : i + 1] + rate[:i]) * np.diff(route.t[: i + 1])))
    heading0 = (float(route.heading_truth[i]) + turned) % 360.0
    t = np.asarray(route.t - route.t[0], dtype=np.float64)
    return t, np.asarray(rate, np.float64), np.asarray(route.speed, np.float64), heading0


def _on_grid(
    route: DriveLog, hz: float, lead_in_s: float, start_s: float
) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """(t, true rate, speed, heading at power-on) on a uniform grid of ``hz`` from power-on:
    standing still for ``lead_in_s``, then the route from ``start_s`` (s after its first row)
    resampled (linear)."""
    if not (math.isfinite(hz) and hz > 0):
        raise ValueError(f"hz must be > 0, got {hz!r}")
    if not (math.isfinite(lead_in_s) and lead_in_s >= 0):
        raise ValueError(f"lead_in_s must be >= 0, got {lead_in_s!r}")
    rt, rate, speed, heading0 = route_truth(route)
    if not (math.isfinite(start_s) and 0.0 <= start_s < float(rt[-1])):
        raise ValueError(f"start_s must be in [0, {float(rt[-1]):g}) s, got {start_s!r}")
    turned = np.concatenate(([0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(rt))))
    heading = (heading0 - float(np.interp(start_s, rt, turned))) % 360.0
    n = int(math.floor((lead_in_s + float(rt[-1]) - start_s) * hz + 1e-9)) + 1
    t = np.arange(n) / hz
    moving = t >= lead_in_s
    w = np.where(moving, np.interp(t - lead_in_s + start_s, rt, rate), 0.0)
    v = np.where(moving, np.interp(t - lead_in_s + start_s, rt, speed), 0.0)
    return t, w, np.maximum(v, 0.0), heading


def route_stops(
    route: DriveLog, min_s: float = 5.0, max_speed_mps: float = 0.3
) -> list[tuple[float, float]]:
    """(start, end) of each stop of a route, s after its first row: the runs of rows at or
    below ``max_speed_mps`` lasting at least ``min_s``, the standing start and end included.
    Where a drive may start (``start_s``) with the car standing."""
    rt, _, speed, _ = route_truth(route)
    still = np.concatenate(([False], speed <= max_speed_mps, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(still))
    runs = zip(edges[0::2], edges[1::2] - 1, strict=True)
    return [(float(rt[a]), float(rt[b])) for a, b in runs if rt[b] - rt[a] >= min_s]


def road_drive(
    route: DriveLog,
    model: GyroModel,
    seed: int,
    hz: float = 10.0,
    lead_in_s: float = 30.0,
    temperature: CabinTemperature | None = None,
    gps: GpsModel = DEFAULT_GPS,
    name: str = "",
    meta: dict[str, str] | None = None,
    start_s: float = 0.0,
) -> DriveLog:
    """The route driven with the gyro ``model`` (module docstring): one row per sample at
    ``hz`` from power-on, ``lead_in_s`` of standstill first, then the route from ``start_s``
    (s after its first row; a stop of it, :func:`route_stops`, starts the drive standing).
    temperature: the cabin (None: drawn from the seed, as a simulated drive's); meta: extra
    metadata lines."""
    t, omega_true, speed, heading0 = _on_grid(route, hz, lead_in_s, start_s)
    streams = np.random.SeedSequence(seed).spawn(4)  # route, temperature, GPS, gyro
    temp_rng, gps_rng, gyro_rng = (np.random.default_rng(s) for s in streams[1:])
    if temperature is None:
        temperature = CabinTemperature.random(temp_rng)
    temp = temperature.profile(t, lead_in_s, temp_rng)
    heading = heading_from_rate(t, omega_true, heading0)
    omega = model.apply(t, omega_true, temp, gyro_rng, speed)
    course = gps_course(t, heading, speed, gps_rng, gps)
    info = {
        "source": f"hdrd {__version__} sim.roads",
        "route": route.name or "route",
        "route_source": route.meta.get("source", ""),
        "seed": str(seed),
        "hz": f"{hz:g}",
        "lead_in_s": f"{lead_in_s:g}",
        "route_start_s": f"{start_s:g}",
        "heading0_deg": f"{heading0:.3f}",
        "temperature": json.dumps(asdict(temperature)),
        "gyro_model": json.dumps(model.to_dict()["effects"]),
        "gps": json.dumps(asdict(gps)),
        "heading_truth": "exact: heading0 - integral of omega_truth (trapezoid), every row",
        "gps_course": f"GPS course at {gps.rate_hz:g} Hz epochs, empty between them and below "
        f"{gps.min_speed_mps:g} m/s",
        **(meta or {}),
    }
    return DriveLog(
        t=t,
        omega=omega,
        temp_c=temp,
        heading_truth=heading,
        omega_truth=omega_true,
        speed=speed,
        gps_course=course,
        gps_speed=np.where(np.isfinite(course), speed, np.nan),
        name=name or f"{route.name or 'route'}-{seed}",
        meta=info,
    )


def grade_on_road(
    route: DriveLog,
    grade: str,
    seed: int,
    motion_offset_dps: float = 0.0,
    hz: float | None = None,
    lead_in_s: float = 30.0,
    gps: GpsModel = DEFAULT_GPS,
    start_s: float = 0.0,
) -> DriveLog:
    """The route driven with a gyro of ``grade`` (:func:`hdrd.sim.grades.grade_model` of the
    seed: its turn-on bias drawn from it), plus a ``motion_offset`` of ``motion_offset_dps``
    (deg/s, read while the vehicle moves; 0: none), sampled at ``hz`` (None: the grade's own
    rate), from ``start_s`` of the route. Named ``<route>-<grade>[-mo]-<seed>`` (and
    ``-at<start_s>`` when it is not 0)."""
    model = grade_model(grade, seed)
    if motion_offset_dps != 0.0:
        model = model.with_effect(MotionOffset(offset_dps=motion_offset_dps))
    rate = Grade.from_table(grade).rate_hz if hz is None else hz
    tag = f"{grade}-mo" if motion_offset_dps != 0.0 else grade
    at = f"-at{start_s:g}" if start_s else ""
    return road_drive(
        route,
        model,
        seed,
        hz=rate,
        lead_in_s=lead_in_s,
        gps=gps,
        name=f"{route.name or 'route'}-{tag}-{seed}{at}",
        meta={"grade": grade, "motion_offset_dps": f"{motion_offset_dps:g}"},
        start_s=start_s,
    )
