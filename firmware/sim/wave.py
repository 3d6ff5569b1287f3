#!/usr/bin/env python3
"""Write a waveform CSV for firmware/sim/run from one of hdrd's simulated drives.

    python3 firmware/sim/wave.py WAVE.csv [--drive city] [--minutes 10] [--seed 1]
                                 [--hz 100] [--signal gyro|truth] [--supply wander|constant]

Rows ``t, rate_volts, supply_volts``: t in s from power-on; supply_volts the gyro's supply, V;
rate_volts the CRS03-04's output, V, for a yaw rate omega (deg/s, + = CCW, a left turn),
ratiometric to the supply as the datasheet gives it (hdrd.core.sensor's model, inverted):

    rate_volts = (supply / 5 V) * (2.5 V + polarity * 0.010 V/(deg/s) * omega)

``--signal gyro`` (default): omega is the analog output of hdrd's CRS03-04-like gyro model
(hdrd.sim.crs03_default_model without its ADC quantisation: static bias, drift, white noise,
10 Hz bandwidth) on the drive; ``truth``: the drive's true yaw rate.

``--supply wander`` moves the supply inside the CRS03-04's 4.75 .. 5.25 V (slow swings and a
faster ripple), so the supply monitor's ratiometric correction is exercised; ``constant`` holds
it at 5.00 V. The drive starts with hdrd's 30 s standstill lead-in. Needs hdrd importable
(installed, or PYTHONPATH at the repository).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def supply_wander(t: FloatArray) -> FloatArray:
    """A gyro supply that wanders inside 4.75 .. 5.25 V: slow swings plus a faster ripple, V."""
    return 5.0 + 0.12 * np.sin(2 * np.pi * t / 47.0) + 0.05 * np.sin(2 * np.pi * t / 3.1 + 1.0)


def drive_wave(
    drive: str,
    minutes: float,
    seed: int,
    hz: float = 100.0,
    signal: str = "gyro",
    supply: str = "wander",
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(t s, rate_volts V, supply_volts V) of a simulated drive (see the module doc)."""
    from hdrd.core.sensor import SensorModel
    from hdrd.sim import crs03_default_model, simulate_drive

    model = crs03_default_model().without("quantization")
    log = simulate_drive(drive, minutes, seed, hz=hz, model=model)
    assert log.omega_truth is not None
    omega = log.omega if signal == "gyro" else log.omega_truth
    t = log.t - log.t[0]
    vs = supply_wander(t) if supply == "wander" else np.full_like(t, 5.0)
    m = SensorModel()
    k = vs / m.supply_nominal_v
    v = k * (m.null_v + m.polarity * m.scale_v_per_dps * omega)
    return t, v, vs


def write_wave(path: str, t: FloatArray, rate_v: FloatArray, supply_v: FloatArray) -> None:
    """The CSV firmware/sim/run reads: a header, then ``t, rate_volts, supply_volts`` rows."""
    rows = np.column_stack([t, rate_v, supply_v])
    np.savetxt(
        path,
        rows,
        fmt=("%.6f", "%.7f", "%.7f"),
        delimiter=",",
        header="t,rate_volts,supply_volts",
        comments="",
    )


def read_wave(path: str) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(t s, rate_volts V, supply_volts V) of a waveform CSV (header line optional)."""
    with open(path, encoding="ascii") as f:
        first = f.readline()
    skip = 0 if first[:1].isdigit() or first[:1] in "+-." else 1
    rows = np.loadtxt(path, delimiter=",", skiprows=skip, comments="#", ndmin=2)
    return rows[:, 0], rows[:, 1], rows[:, 2]


def rate_at(
    t_query: npt.ArrayLike,
    wave: tuple[FloatArray, FloatArray, FloatArray],
    sensor: object | None = None,
) -> FloatArray:
    """The yaw rate the waveform carries at times t_query (s), deg/s (+ = CCW): the gyro's
    ratiometric output read back through ``sensor`` (an hdrd.core.sensor.SensorModel; default
    the CRS03-04's), with the voltages interpolated linearly as firmware/sim/run does."""
    from hdrd.core.sensor import SensorModel

    m = sensor if isinstance(sensor, SensorModel) else SensorModel()
    t, v, vs = wave
    tq = np.asarray(t_query, dtype=np.float64)
    k = np.interp(tq, t, vs) / m.supply_nominal_v
    return m.polarity * (np.interp(tq, t, v) - m.null_v * k) / (m.scale_v_per_dps * k)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="CSV to write")
    ap.add_argument("--drive", default="city", help="hdrd drive type (city, rural, mixed, ...)")
    ap.add_argument("--minutes", type=float, default=10.0, help="driving minutes after the lead-in")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--hz", type=float, default=100.0, help="rows per second")
    ap.add_argument("--signal", choices=("gyro", "truth"), default="gyro")
    ap.add_argument("--supply", choices=("wander", "constant"), default="wander")
    a = ap.parse_args(argv)
    try:
        t, v, vs = drive_wave(a.drive, a.minutes, a.seed, a.hz, a.signal, a.supply)
    except ValueError as e:
        print(f"wave.py: {e}", file=sys.stderr)
        return 2
    write_wave(a.out, t, v, vs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
