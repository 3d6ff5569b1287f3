"""Drive profiles: the drives ``hdrd fakegyro`` and ``hdrd run --simulate`` play, and the
frames the gyro's ADC sends for them.

- :func:`load_profile`: a drive by name: "standstill" and "constant" built in
  (:func:`builtin_profile`), any other a road type of the simulator
  (:func:`hdrd.sim.drive.simulate_drive`); :class:`ProfileError` for one that cannot be made;
- :func:`profile_frames`: a drive's raw rates as the ADC's frames (counts through the sensor
  model, the device clock, sequence numbers, temperatures).

Pure and seeded. Rates deg/s, + = counter-clockwise; time s from the drive's start.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from hdrd.core.sensor import SensorModel
from hdrd.errors import HdrdError
from hdrd.io.files.drivelog import DriveLog
from hdrd.io.wire.codec import FRAME_DTYPE
from hdrd.io.wire.protocol import CLOCK_WRAP_US, TEMP_NOT_FITTED
from hdrd.sim.drive import simulate_drive
from hdrd.sim.grades import grade_model

__all__ = [
    "BUILTIN_DRIVES",
    "MAX_PROFILE_SAMPLES",
    "ProfileError",
    "builtin_profile",
    "load_profile",
    "profile_frames",
]


BUILTIN_DRIVES = ("standstill", "constant")


class ProfileError(HdrdError, ValueError):
    """A drive profile that cannot be made (unknown drive, bad value, too many samples)."""


def builtin_profile(
    drive: str = "standstill",
    minutes: float = 20.0,
    seed: int = 1,
    hz: float = 10.0,
    rate_dps: float = 0.0,
    bias_dps: float = 0.2,
    noise_dps: float = 0.05,
    temp_c: float = 25.0,
    lead_in_s: float = 30.0,
) -> DriveLog:
    """A simple drive without the road simulator: ``lead_in_s`` of standstill, then ``minutes`` of
    standstill ("standstill") or of a constant true yaw rate ``rate_dps`` ("constant").

    Raw gyro ``omega`` = true rate + ``bias_dps`` + white noise of std ``noise_dps`` (deg/s,
    + = CCW, seeded); ``omega_truth`` the true rate; ``temp_c`` constant. Time from 0 s.
    """
    if drive not in BUILTIN_DRIVES:
        raise ProfileError(
            f"unknown built-in drive {drive!r} (built in: {', '.join(BUILTIN_DRIVES)})"
        )
    for name, v in (("minutes", minutes), ("hz", hz), ("lead_in_s", lead_in_s)):
        if not (math.isfinite(v) and v >= 0) or (name == "hz" and v == 0):
            raise ProfileError(
                f"{name} must be a finite number {'> 0' if name == 'hz' else '>= 0'}, got {v!r}"
            )
    for name, v in (
        ("rate_dps", rate_dps),
        ("bias_dps", bias_dps),
        ("noise_dps", noise_dps),
        ("temp_c", temp_c),
    ):
        if not math.isfinite(v):
            raise ProfileError(f"{name} must be a finite number, got {v!r}")
    n = _profile_samples(minutes, hz, lead_in_s)
    t = np.arange(n, dtype=np.float64) / hz
    truth = np.where(t >= lead_in_s, rate_dps if drive == "constant" else 0.0, 0.0)
    rng = np.random.default_rng(seed)
    omega = truth + bias_dps + rng.normal(0.0, noise_dps, n) if noise_dps > 0 else truth + bias_dps
    return DriveLog(
        t=t,
        omega=omega,
        temp_c=np.full(n, temp_c),
        omega_truth=truth,
        name=drive,
        meta={
            "drive": drive,
            "rate_dps": repr(rate_dps),
            "bias_dps": repr(bias_dps),
            "noise_dps": repr(noise_dps),
            "lead_in_s": repr(lead_in_s),
            "seed": str(seed),
        },
    )


MAX_PROFILE_SAMPLES = 50_000_000
"""Most samples a generated drive may have (each a few float64 columns: ~1 GB at most)."""


def _profile_samples(minutes: float, hz: float, lead_in_s: float = 0.0) -> int:
    """Samples of a drive of ``minutes`` after ``lead_in_s`` at ``hz``; ProfileError if it
    has none or more than MAX_PROFILE_SAMPLES (1e308 minutes used to overflow, 1e6 minutes
    to fill the memory)."""
    total = (lead_in_s + minutes * 60.0) * hz
    if not total <= MAX_PROFILE_SAMPLES:
        raise ProfileError(
            f"a drive of {minutes:g} min at {hz:g} Hz is {total:.3g} samples; "
            f"at most {MAX_PROFILE_SAMPLES:,} are made"
        )
    n = int(round(total))
    if n < 1:
        raise ProfileError(f"a drive of {minutes} min at {hz} Hz has no samples")
    return n


def load_profile(
    drive: str,
    minutes: float = 20.0,
    seed: int = 1,
    hz: float = 10.0,
    rate_dps: float = 0.0,
    grade: str | None = None,
) -> DriveLog:
    """A drive by name: "standstill" and "constant" are built in (:func:`builtin_profile`);
    any other name is a road type of the simulator (:func:`hdrd.sim.drive.simulate_drive`),
    with the gyro of ``grade`` (:mod:`hdrd.sim.grades`; None: the default CRS03-04 model)."""
    if drive in BUILTIN_DRIVES:
        return builtin_profile(drive, minutes, seed, hz, rate_dps)
    for name, v in (("minutes", minutes), ("hz", hz)):
        if not (math.isfinite(v) and v > 0):
            raise ProfileError(f"{name} must be a finite number > 0, got {v!r}")
    _profile_samples(minutes, hz)
    try:
        model = None
        if grade is not None:
            model = grade_model(grade, seed)
        return simulate_drive(drive, minutes, seed, hz=hz, model=model)
    except ValueError as e:
        raise ProfileError(str(e)) from None


def profile_frames(
    log: DriveLog,
    sensor: SensorModel | None = None,
    supply_v: float | None = None,
    t0_us: int = 0,
    seq0: int = 0,
) -> npt.NDArray[np.void]:
    """The frames the ADC sends for a drive: a :data:`hdrd.io.wire.codec.FRAME_DTYPE` array.

    rate = ``sensor.to_counts(log.omega, supply_v)`` (rounded, clipped to the rails); ref =
    the supply monitor's counts for ``supply_v``, 0 (not wired) when None; temp from
    ``log.temp_c`` in 0.01 degC (NaN or no column: not fitted); t_us = t0_us + t * 1e6,
    wrapped at 2**32; seq from ``seq0``, wrapped at 2**16.
    """
    sensor = sensor or SensorModel()
    n = len(log)
    arr = np.zeros(n, FRAME_DTYPE)
    arr["seq"] = (seq0 + np.arange(n, dtype=np.int64)) & 0xFFFF
    arr["t_us"] = (
        t0_us + np.rint(np.asarray(log.t, np.float64) * 1e6).astype(np.int64)
    ) % CLOCK_WRAP_US
    arr["rate"] = sensor.to_counts(log.omega, supply_v)
    arr["ref"] = 0 if supply_v is None else sensor.ref_counts_for(supply_v)
    if log.temp_c is None:
        arr["temp"] = TEMP_NOT_FITTED
    else:
        cc = np.clip(np.rint(np.nan_to_num(log.temp_c, nan=0.0) * 100.0), -32767, 32767).astype(
            np.int64
        )
        arr["temp"] = np.where(np.isnan(log.temp_c), TEMP_NOT_FITTED, cc)
    return arr
