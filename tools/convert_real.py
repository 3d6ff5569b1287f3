#!/usr/bin/env python3
"""Convert the two real recordings in ../shared/data/ into hdrd drive logs (docs/drive-format.md).

    python tools/convert_real.py smartloc  --out /tmp/smartloc_berlin.csv
    python tools/convert_real.py comma2k19 --out /tmp/comma2k19.csv
    python tools/convert_real.py all --out-dir /tmp/real

The recordings are third-party (see each folder's README.txt and licence) and are read in
place, never copied into this repository; write the output outside it (e.g. /tmp).

Sign conventions (checked against the data, see the README.txt files):

- smartLoc Berlin: ``odom3`` wz (rad/s) is the car's yaw rate about the up axis, counter-clockwise
  positive: its integral is minus the reference course change (-172.5 deg vs +190.3 deg, the
  difference being the sensor's bias drift). omega = degrees(wz). speed = odom vx (m/s).
  heading_truth = course over ground of the ground-truth track (ECEF -> local ENU, central
  differences), only where the track's speed exceeds 2 m/s; no omega_truth, no temperature.
  One row per odometry epoch (~5 Hz, 0.2/0.3 s steps).
- comma2k19: the phone's ``IMU/gyro_uncalibrated`` z (rad/s) is about the *down* axis of the
  [forward, right, down] frame, i.e. clockwise positive: omega = -degrees(gz) (raw, with its
  ~3.9 deg/s bias). heading_truth = heading of the fused pose's forward axis (ECEF -> NED,
  atan2(E, N)) at the gyro row nearest each 20 Hz pose frame, empty elsewhere; omega_truth =
  minus the time derivative of that (unwrapped) heading, interpolated to the gyro rows;
  speed = CAN speed interpolated. One row per gyro sample (~104 Hz). The drive never stops,
  so the static bias cannot be measured from the log: use ``--bias`` (metadata
  ``android_bias_dps`` holds Android's own estimate, in hdrd's CCW convention).

Times are shifted to start at 0 (the original start is in the metadata).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import numpy.typing as npt

from hdrd.drivelog import DriveLog, write_drive

FloatArray = npt.NDArray[np.float64]

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
MIN_COURSE_SPEED_MPS = 2.0

# WGS84
_A = 6378137.0
_E2 = 6.69437999014e-3


def geodetic_lat_lon(x: float, y: float, z: float) -> tuple[float, float]:
    """Geodetic latitude and longitude (rad) of an ECEF point (m), WGS84."""
    lon = math.atan2(y, x)
    p = math.hypot(x, y)
    lat = math.atan2(z, p * (1 - _E2))
    for _ in range(5):
        n = _A / math.sqrt(1 - _E2 * math.sin(lat) ** 2)
        h = p / math.cos(lat) - n
        lat = math.atan2(z, p * (1 - _E2 * n / (n + h)))
    return lat, lon


def enu_axes(lat: float, lon: float) -> tuple[FloatArray, FloatArray]:
    """Unit East and North vectors in ECEF at a geodetic latitude/longitude (rad)."""
    east = np.array([-math.sin(lon), math.cos(lon), 0.0])
    north = np.array(
        [-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat)]
    )
    return east, north


def course_from_positions(
    t: FloatArray, ecef: FloatArray, min_speed: float = MIN_COURSE_SPEED_MPS
) -> tuple[FloatArray, FloatArray]:
    """Course over ground (compass deg, clockwise from north; NaN below min_speed) and
    ground speed (m/s) from ECEF positions (n, 3) by central differences."""
    lat, lon = geodetic_lat_lon(*ecef[0])
    east, north = enu_axes(lat, lon)
    d = ecef - ecef[0]
    e, n = d @ east, d @ north
    ve, vn = np.gradient(e, t), np.gradient(n, t)
    speed = np.hypot(ve, vn)
    course = np.mod(np.degrees(np.arctan2(ve, vn)), 360.0)
    return np.where(speed > min_speed, course, np.nan), speed


# -- smartLoc ------------------------------------------------------------------------------


def _records(path: Path, kind: str, ncols: int) -> FloatArray:
    rows = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            parts = line.split()
            if parts and parts[0] == kind:
                rows.append([float(v) for v in parts[1 : 1 + ncols]])
    if not rows:
        raise ValueError(f"{path}: no {kind!r} records")
    return np.asarray(rows, dtype=np.float64)


def smartloc_to_drive(folder: Path = DATA / "smartloc_berlin") -> DriveLog:
    """The smartLoc Berlin Potsdamer Platz drive as a drive log (see the module docstring)."""
    odom = _records(folder / "Berlin_Potsdamer_Platz_Input.txt", "odom3", 7)
    gt = _records(folder / "Berlin_Potsdamer_Platz_GT.txt", "point3", 4)
    t = odom[:, 0]
    if gt.shape[0] != t.shape[0] or np.max(np.abs(gt[:, 0] - t)) > 1e-6:
        raise ValueError("smartLoc: ground truth and odometry epochs differ")
    keep = np.concatenate(([True], np.diff(t) > 0))  # the format needs strictly increasing t
    t, odom, gt = t[keep], odom[keep], gt[keep]
    heading, _ = course_from_positions(t, gt[:, 1:4])
    return DriveLog(
        t=t - t[0],
        omega=np.degrees(odom[:, 6]),
        heading_truth=heading,
        speed=odom[:, 1],
        name="smartloc_berlin",
        meta={
            "source": "TU Chemnitz smartLoc, Berlin Potsdamer Platz (libRSF datasets/smartLoc), CC BY-SA 4.0",
            "omega": "car's odometry yaw rate odom3 wz, deg/s, CCW positive, ~5 Hz",
            "heading_truth": f"course of the ground-truth track (ECEF->ENU), speed > {MIN_COURSE_SPEED_MPS:g} m/s",
            "t0_s": f"{odom[0, 0]:.6f}",
        },
    )


# -- comma2k19 --------------------------------------------------------------------------------


def _quat_forward(q: FloatArray) -> FloatArray:
    """First column of the rotation matrix of quaternions [w, x, y, z]: the forward axis in ECEF."""
    w, x, y, z = q.T
    return np.stack((1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)), axis=1)


def comma2k19_to_drive(folder: Path = DATA / "comma2k19_example") -> DriveLog:
    """The comma2k19 example minute as a drive log (see the module docstring)."""

    def load(rel: str) -> np.ndarray:
        return np.load(folder / rel)  # files are .npy without an extension

    gt = load("processed_log/IMU/gyro_uncalibrated/t").astype(np.float64)
    gz = load("processed_log/IMU/gyro_uncalibrated/value")[:, 2].astype(np.float64)
    bias = load("processed_log/IMU/gyro_bias/value")[:, 2].astype(np.float64)
    keep = np.concatenate(([True], np.diff(gt) > 0))
    gt, gz = gt[keep], gz[keep]
    omega = -np.degrees(gz)  # z is down: clockwise positive -> CCW positive

    ft = load("global_pose/frame_times").astype(np.float64)
    q = load("global_pose/frame_orientations").astype(np.float64)
    pos = load("global_pose/frame_positions").astype(np.float64)
    lat, lon = geodetic_lat_lon(*pos[0])
    east, north = enu_axes(lat, lon)
    fwd = _quat_forward(q)
    heading = np.mod(np.degrees(np.arctan2(fwd @ east, fwd @ north)), 360.0)
    cw_rate = np.gradient(np.degrees(np.unwrap(np.radians(heading))), ft)

    heading_truth = np.full(gt.shape[0], np.nan)
    inside = (ft >= gt[0]) & (ft <= gt[-1])
    idx = np.clip(np.searchsorted(gt, ft[inside]), 1, gt.shape[0] - 1)
    idx = np.where(np.abs(gt[idx - 1] - ft[inside]) < np.abs(gt[idx] - ft[inside]), idx - 1, idx)
    heading_truth[idx] = heading[inside]
    omega_truth = -np.interp(gt, ft, cw_rate, left=np.nan, right=np.nan)

    st = load("processed_log/CAN/speed/t").astype(np.float64)
    sv = load("processed_log/CAN/speed/value")[:, 0].astype(np.float64)
    speed = np.interp(gt, st, sv, left=np.nan, right=np.nan)
    return DriveLog(
        t=gt - gt[0],
        omega=omega,
        heading_truth=heading_truth,
        omega_truth=omega_truth,
        speed=speed,
        name="comma2k19",
        meta={
            "source": "comma.ai comma2k19 Example_1 segment 40 (Toyota RAV4, 2018-08-02), MIT",
            "omega": "phone gyro_uncalibrated z, negated (z down -> CCW positive), deg/s, ~104 Hz, raw",
            "heading_truth": "fused pose (laika) forward-axis heading, at the row nearest each 20 Hz frame",
            "omega_truth": "minus d/dt of the pose heading, interpolated",
            "android_bias_dps": f"{-math.degrees(float(np.mean(bias))):.4f}",
            "t0_s": f"{gt[0]:.6f}",
        },
    )


CONVERTERS = {
    "smartloc": (smartloc_to_drive, "smartloc_berlin"),
    "comma2k19": (comma2k19_to_drive, "comma2k19_example"),
}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("which", choices=(*CONVERTERS, "all"))
    p.add_argument(
        "--data", type=Path, help="the recording's folder (default ../shared/data/<name>)"
    )
    p.add_argument("--out", type=Path, help="drive log CSV to write (one recording)")
    p.add_argument("--out-dir", type=Path, help="with 'all': directory for <name>.csv")
    args = p.parse_args(argv)
    jobs = list(CONVERTERS) if args.which == "all" else [args.which]
    if args.which == "all" and (args.out_dir is None or args.data is not None):
        p.error("'all' needs --out-dir (and takes the default data folders)")
    if args.which != "all" and args.out is None:
        p.error("--out is required")
    for name in jobs:
        convert, folder = CONVERTERS[name]
        src = args.data if args.data is not None else DATA / folder
        try:
            log = convert(src)
        except (OSError, ValueError) as e:
            print(f"convert_real: {name}: {e}", file=sys.stderr)
            return 1
        out = args.out if args.which != "all" else args.out_dir / f"{log.name}.csv"
        out.parent.mkdir(parents=True, exist_ok=True)
        write_drive(out, log)
        fixes = int(np.isfinite(log.heading_truth).sum()) if log.heading_truth is not None else 0
        print(
            f"{out}: {len(log)} rows, {log.duration_s:.1f} s at {log.rate_hz:.1f} Hz, {fixes} heading fixes"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
