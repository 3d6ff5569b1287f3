#!/usr/bin/env python3
"""Convert real recordings into hdrd drive logs (docs/drive-format.md): those of ../shared/data/
and those of public repositories listed in tools/real_sources.yaml (docs/real-data.md).

    python tools/convert_real.py smartloc   --out /tmp/smartloc_berlin.csv
    python tools/convert_real.py comma2k19  --out /tmp/comma2k19.csv
    python tools/convert_real.py rtklib     --out /tmp/rtklib_drive0708.csv
    python tools/convert_real.py driveplotr --out-dir /tmp/real   # 28 logs, nds_drive<NN>.csv
    python tools/convert_real.py all --out-dir /tmp/real [--data ../shared/data]
    python tools/convert_real.py oan   --data CLONE --out-dir /tmp/real   # 3 logs, oan_<stamp>.csv
    python tools/convert_real.py psins --data CLONE --out /tmp/real/psins_fog_mems.csv
    python tools/convert_real.py boreas --data CLONE --out-dir /tmp/real  # 2 routes, boreas_<stamp>.csv

``--data`` (alias ``--src``) is the recording's folder, for oan, psins and boreas a clone of the public
repository (its work tree, or a bare git directory read at the recorded commit); with ``all``
the folder holding the recordings' folders. Defaults: ../shared/data beside the repository (or
$HDRD_REAL_DATA); for the public ones, ``$HDRD_MIRRORS/<owner>+<name>/repo`` when
$HDRD_MIRRORS names a folder of repository snapshots, else none (a missing clone is named with
its ``git clone`` command). ``all`` converts the ../shared/data recordings only.

The recordings are third-party (see each folder's README.txt and licence, and
tools/real_sources.yaml) and are read in place, never copied into this repository; write the
output outside it (e.g. /tmp). A public source's file whose sha256 differs from the recorded one
is refused.

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

- rtklib_drive0708: a roof-mounted ADIS16465 IMU at 100 Hz (``imu_1934.csv``: ax, ay, az in g;
  gx, gy, gz in deg/s; a millisecond counter) and RTKLIB's RTK solution at 4 Hz
  (``gnss_1934_sf.pos``, GPST, with vn, ve). The IMU's z axis points up (az = +1 g at rest), so
  its rates are counter-clockwise positive about up; the IMU is tilted ~7 deg, so omega = the
  gyro vector projected on the static gravity direction (the mean accelerometer vector over
  the start-up standstill). Time: RTKLIB's tag file gives the GPST of the first sample and the
  tick span; the counter is mapped linearly over that span, then ``imu_t_off`` (-0.125 s, the
  source's drive_config.py) is added. heading_truth = course over ground atan2(ve, vn) where
  the RTK speed exceeds 2 m/s, at the IMU row nearest each 4 Hz epoch; speed = RTK horizontal
  speed interpolated to the IMU rows. **Sign, verified**: over the 4 Hz epochs with speed > 3
  m/s, the gyro's mean rate between epochs correlates +0.98 with minus the course rate (the
  compass course turns clockwise, yaw counter-clockwise; regression slope 0.96 against the
  course rate, which is itself noisy), best at zero time lag; integrated from the lead-in's
  bias the heading follows the RTK course with a mean error of 1.3 deg over the drive, and
  with the sign flipped it is hundreds of degrees off (mean 435 deg, unwrapped); the test
  checks both.
- driveplotr_nds: 28 drives of one car (``nds_data.csv``, one row per second: a 1 Hz point
  sample of a faster sensor). One log per drive (``nds_drive<NN>``): omega = gyro_z (deg/s,
  counter-clockwise positive, quantised in 1/16 deg/s), heading_truth = gps_heading_raw
  (compass degrees, [0, 360); ``gps_heading`` is the same unwrapped) where speed > 2 m/s,
  speed = speed_mph * 0.44704 (GPS or OBD). **Sign, verified**: per drive the gyro's mean over
  two consecutive samples correlates +0.60 to +0.89 with minus the GPS course rate (over
  pairs of fixes at > 3 m/s) on each of the 21 drives with more than 100 such pairs; the
  short, nearly straight drives 2, 3, 19 and 28 have too little turning to say (-0.09..0.36). Rows without a gyro value are
  dropped; the logs keep their gaps (up to 74 s where the logger paused).
- oan (Open Aided Navigation, data/nsr/drive/; three drives ``oan_<date>_<time>``): a phone
  (STM LSM6DSL gyro, 50 Hz, rad/s) held upright in the car, recorded by Nav Sensor Recorder
  with the phone's GNSS fix at 1 Hz (speed, and heading = Android's bearing, compass degrees;
  -3000 or 0 when standing). The phone's y axis is near vertical (~85 deg from z), so omega =
  the gyro vector projected on the mean accelerometer vector (specific force, up) over the
  lead-in (the whole drive where there is none). Times: the sensors' and the fixes' ns stamps
  (one clock). heading_truth = the bearing where the fix's speed > 2 m/s and it lies in
  [0, 360), at the gyro row nearest each fix; speed = the fixes' speed interpolated. Lead-in:
  the first fix reads standstill, rows before it take its speed; margin 2 s. The phone was
  handled while the city drive's car still stood (at 121.6 s: a 1 s mean rate over 20 deg/s,
  two samples beyond 1,000 deg/s), so that drive starts 2 s after it (``_after_handling``),
  its lead-in (bias and vertical) measured as the phone then sat. **Sign, verified**: the
  gyro's mean rate between fixes correlates +0.947, +0.975 and +0.969 (991, 98, 882 fix pairs
  over 3 m/s) with minus the GNSS course rate, best at zero lag (0.77-0.79 and 0.86-0.92 one
  fix earlier or later); integrated from the lead-in's bias (0.036 and -0.0005 deg/s; none on
  the 100 s drive) the heading follows the course with a mean |error| of 14.2, 7.9 and 3.6 deg
  (wrapped to +-180: the city drive's course has a 53 s gap), and with the sign flipped 63.9,
  91.3 and 88.0 deg.
- psins (PSINS data/transfer_align_fog_mems.mat; one run ``psins_fog_mems``): 100 s of a car at
  11.5-15.8 m/s on a nearly straight road (4 deg of course change). ``mimu``: a MEMS IMU's
  angle and velocity increments at 100 Hz (rad, m/s; z up: +9.69 m/s^2 at rest); ``fogavp``: a
  FOG INS's pitch, roll, yaw (rad), vE, vN, vU, lat, lon, h at 10 Hz, used as the reference.
  PSINS's yaw is counter-clockwise from north (its vn2att: atan2(-vE, vN)), so heading_truth =
  -yaw (compass), at the row nearest each epoch; omega_truth = d(yaw)/dt; speed = the INS's
  horizontal speed. omega = the increments / 0.01 s projected on the run's mean specific force
  (no standstill; tilt ~2.3 deg); no lead-in. **Sign, verified**: the gyro's 1 s means
  correlate +0.84 with the INS yaw rate (slope 0.93, offset 0.027 deg/s: the bias), the
  10-sample means +0.62 at zero lag (0.50 half a second off); over the 10 Hz epochs it
  correlates +0.62 with minus the INS velocity's course rate; integrated with the bias
  mean(omega - omega_truth) = 0.028 deg/s the heading stays within 0.4 deg (mean) of the INS,
  1.0 deg flipped (little turning: the correlations are the evidence). The INS heading and its
  velocity's course differ by ~4.4 deg on average (mounting).
- boreas (pyboreas ``pyboreas/test/demo/gt/<sequence>/applanix/lidar_poses.csv``; two drives
  ``boreas_20210805_1334`` (18.6 min, 7.9 km, tunes) and ``boreas_20210902_1142`` (17.2 min,
  8.0 km, judges), each from a standing start to a stop, with 4 and 6 stops of 6-81 s between)
  are *routes*, not gyros: the Applanix POS
  LV's post-processed (RTS-smoothed GNSS + IMU + wheel encoder) pose of the lidar frame at
  ~9.64 Hz (the lidar's scans; GPSTime is UTC microseconds). omega = omega_truth =
  degrees(angvel_z) (a perfect gyro; metadata ``route``), heading_truth = degrees(heading) +
  43.2 (compass), speed = hypot(vel_east, vel_north). **Axis and sign, verified**: angvel_z
  is the rate about the lidar frame's z axis, which T_applanix_lidar puts within 0.06 deg of
  the Applanix z (up); it correlates -0.99915 / -0.99932 with the time derivative of the
  unwrapped ``heading`` (slope -1.0001 / -1.0010; 1 s means -0.99991, slope -0.996: the body
  axis tilts with roll and pitch of up to 5.7 deg) at zero lag (-0.996 one sample off), while
  angvel_x and angvel_y do not (|r| < 0.03); integrated, it follows minus the heading's change
  to within 1.5 / 2.2 deg over 2,990 / 2,888 deg of turning (mean 0.42 / 0.71 deg, at most
  1.7 / 2.0 deg, over any 120 s), and with the sign flipped it is 517 / 523 deg off. Against
  the course over ground from the Applanix velocities (compass, atan2(vel_east, vel_north)),
  1 s means of angvel_z correlate -0.987 / -0.985 with the course's rate at > 5 m/s (slope
  -0.97): angvel_z is counter-clockwise positive about up, hdrd's sign. **Heading**: the
  ``heading`` turns *against* angvel_z, so it is clockwise (compass sense; pyboreas's
  yawPitchRollToRot takes Barfoot's C3, the negative of an ENU yaw), range [-180, 180). It is
  the lidar frame's, not the car's: the course over ground minus ``heading`` is 43.21 / 43.17
  deg (circular mean over 3,348 / 3,290 rows of straight road: speed > 5 m/s, |angvel_z| < 1
  deg/s; sd 0.50 / 0.52 deg; 43.17-43.22 at > 3, 5 or 10 m/s), in line with T_applanix_lidar's
  42.66 deg yaw of the lidar frame (lidar x axis 47.34 deg clockwise of the Applanix y axis,
  forward; the 0.55 deg left is the Applanix frame's misalignment to the car's direction of
  travel). In turns the course leads the heading by 0.36 deg per m/s^2 of lateral acceleration
  (sideslip at the lidar's lever arm). The positions' course (easting/northing differences)
  equals the velocities' (mean difference 0.002 deg). A lead-in from the speed (<= 0.3 m/s,
  1 s margin): 8 s and 3 s.

Each log that starts at standstill says so in ``lead_in_s`` (docs/drive-format.md): the seconds
from the first sample during which the vehicle stood still, so that the static bias can be
measured there. From the speed: the initial run of rows with speed <= 0.3 m/s (RTK) or
<= 0.3 m/s and |omega - median| <= 0.5 deg/s (driveplotr: its GPS speed lags and reads ~0.1 m/s
while the car already turns out of a parking space), ended a margin before the first row that
fails (1 s for rtklib, 3 s for driveplotr's lagging speed); a lead-in under 3 s is not written.
smartLoc, comma2k19, psins and the 100 s oan drive start moving: they carry no ``lead_in_s``.

Times are shifted to start at 0 (the original start is in the metadata).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.io.files.drivelog import DriveLog, write_drive

FloatArray = npt.NDArray[np.float64]

DATA = Path(
    os.environ.get("HDRD_REAL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")
)
"""../shared/data beside the repository (or $HDRD_REAL_DATA): the recordings' folders."""
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


# -- start-up standstill -------------------------------------------------------------------

LEAD_IN_MIN_S = 3.0
"""A start-up standstill shorter than this is not written as ``lead_in_s``."""


def lead_in_seconds(
    t: FloatArray,
    speed: FloatArray,
    omega: FloatArray | None = None,
    *,
    max_speed_mps: float = 0.3,
    max_rate_dev_dps: float = 0.5,
    margin_s: float = 1.0,
    min_s: float = LEAD_IN_MIN_S,
) -> float | None:
    """Seconds of standstill at the start of a log (from t[0]), or None when under ``min_s``.

    The initial run of rows whose speed (m/s) is known and at most ``max_speed_mps`` and, when
    ``omega`` (deg/s) is given, whose rate averaged over 1 s (a single 1 Hz sample, or 100
    samples at 100 Hz: engine-start vibration spikes are not motion) is within
    ``max_rate_dev_dps`` of that run's median (a rotating
    car is not standing, whatever a lagging speed says); the lead-in ends ``margin_s`` before
    the first row that fails. Whole seconds, rounded down.
    """
    ok = np.isfinite(speed) & (speed <= max_speed_mps)
    if not ok[0]:
        return None
    end = int(np.argmin(ok)) if not ok.all() else ok.shape[0]
    if omega is not None and end > 0:
        w = _moving_mean(t, omega, 1.0)
        med = float(np.median(w[:end]))
        bad = np.flatnonzero(np.abs(w[:end] - med) > max_rate_dev_dps)
        if bad.shape[0]:
            end = int(bad[0])
    if end == 0:
        return None
    t_fail = float(t[end]) if end < t.shape[0] else float(t[-1])
    lead = math.floor(t_fail - float(t[0]) - margin_s)
    return float(lead) if lead >= min_s else None


def _moving_mean(t: FloatArray, x: FloatArray, window_s: float) -> FloatArray:
    """Mean of x over the rows within +-window_s/2 of each row (x itself at <= 1 row per window)."""
    c = np.concatenate(([0.0], np.cumsum(x)))
    lo = np.searchsorted(t, t - window_s / 2, side="left")
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    return (c[hi] - c[lo]) / np.maximum(hi - lo, 1)


def _nearest_rows(
    t_rows: FloatArray, t_events: FloatArray, tol_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """(row index, event mask): the row nearest each event time, for events within ``tol_s``
    of a row."""
    idx = np.clip(np.searchsorted(t_rows, t_events), 1, t_rows.shape[0] - 1)
    idx = np.where(
        np.abs(t_rows[idx - 1] - t_events) < np.abs(t_rows[idx] - t_events), idx - 1, idx
    )
    ok = np.abs(t_rows[idx] - t_events) <= tol_s
    return idx[ok], ok


# -- rtklib drive 0708 ----------------------------------------------------------------------

RTKLIB_IMU_T_OFF_S = -0.125
"""drive_config.py's imu_t_off: added to the IMU time stamps for the logging delay, s."""


def _rtklib_imu(path: Path) -> FloatArray:
    """The IMU rows (ax, ay, az g; gx, gy, gz deg/s; counter ms): complete numeric lines only,
    the last line dropped (the recording may end mid-line)."""
    rows = []
    with open(path, encoding="utf-8") as f:
        lines = f.read().splitlines()
    for line in lines[:-1]:
        parts = line.split(",")
        if len(parts) != 7:
            continue
        try:
            rows.append([float(v) for v in parts])
        except ValueError:
            continue
    if len(rows) < 2:
        raise ValueError(f"{path}: fewer than 2 IMU rows")
    return np.asarray(rows, dtype=np.float64)


def _rtklib_tag(path: Path) -> tuple[float, float]:
    """(GPST of the first sample as seconds of the GPS-time scale counted like UNIX time, span
    of the tag's ticks in s) from RTKLIB's binary time-tag file."""
    import struct

    data = path.read_bytes()
    if len(data) < 76 + 8 or not data.startswith(b"TIMETAG"):
        raise ValueError(f"{path}: not an RTKLIB time-tag file")
    (time_s,) = struct.unpack("<I", data[64:68])
    (frac,) = struct.unpack("<d", data[68:76])
    n = (len(data) - 76) // 8
    last_tick_ms, _ = struct.unpack("<II", data[76 + 8 * (n - 1) : 76 + 8 * n])
    return time_s + frac, last_tick_ms / 1000.0


def _rtklib_pos(path: Path) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(GPST s, vn m/s, ve m/s) of every solution epoch; the columns located by the header."""
    import datetime as dt

    names: list[str] | None = None
    t, vn, ve = [], [], []
    with open(path, encoding="utf-8") as f:
        for line in f:
            if line.startswith("%"):
                head = line[1:].split()
                if "vn(m/s)" in head:
                    names = ["date", "time", *head[1:]]  # "GPST" spans the date and time tokens
                continue
            if names is None:
                raise ValueError(f"{path}: no header line with vn(m/s) before the data")
            p = line.split()
            if len(p) < len(names):
                continue
            stamp = dt.datetime.strptime(f"{p[0]} {p[1]}", "%Y/%m/%d %H:%M:%S.%f")
            t.append(stamp.replace(tzinfo=dt.timezone.utc).timestamp())
            vn.append(float(p[names.index("vn(m/s)")]))
            ve.append(float(p[names.index("ve(m/s)")]))
    if len(t) < 2:
        raise ValueError(f"{path}: fewer than 2 solution epochs")
    return np.asarray(t), np.asarray(vn), np.asarray(ve)


def rtklib_to_drive(folder: Path = DATA / "rtklib_drive0708") -> DriveLog:
    """rtklibexplorer's drive 0708 as a drive log (see the module docstring)."""
    imu = _rtklib_imu(folder / "imu_1934.csv")
    start, span = _rtklib_tag(folder / "imu_1934.csv.tag")
    ms = imu[:, 6]
    if not np.all(np.diff(ms) > 0):
        raise ValueError("rtklib: the IMU counter is not strictly increasing")
    t_gps = start + (ms - ms[0]) * span / (ms[-1] - ms[0]) + RTKLIB_IMU_T_OFF_S
    t_pos, vn, ve = _rtklib_pos(folder / "gnss_1934_sf.pos")
    speed_pos = np.hypot(vn, ve)
    speed = np.interp(t_gps, t_pos, speed_pos, left=np.nan, right=np.nan)
    t = t_gps - t_gps[0]
    lead = lead_in_seconds(t, speed, imu[:, 5], margin_s=1.0)
    # The vertical: the mean specific force over the start-up standstill (or the first 10 s).
    still = t < (lead if lead is not None else 10.0)
    up = imu[still, 0:3].mean(axis=0)
    up /= np.linalg.norm(up)
    omega = imu[:, 3:6] @ up
    course = np.mod(np.degrees(np.arctan2(ve, vn)), 360.0)
    moving = speed_pos > MIN_COURSE_SPEED_MPS
    heading = np.full(t.shape[0], np.nan)
    rows, ok = _nearest_rows(t_gps, t_pos, 0.02)
    heading[rows] = np.where(moving[ok], course[ok], np.nan)
    meta = {
        "source": "rtklibexplorer GNSS_IMU data/drive_0708 (ADIS16465 IMU + RTK), BSD-3-Clause",
        "omega": "IMU gyro vector projected on the static gravity direction (z up), deg/s, CCW positive, 100 Hz",
        "heading_truth": f"RTK course over ground atan2(ve, vn), speed > {MIN_COURSE_SPEED_MPS:g} m/s, at the row nearest each 4 Hz epoch",
        "speed": "RTK horizontal speed, interpolated",
        "t0_s": f"{t_gps[0]:.3f} (GPST, seconds counted like UNIX time)",
        "imu_tilt_deg": f"{math.degrees(math.acos(min(1.0, abs(float(up[2]))))):.2f}",
    }
    if lead is not None:
        meta["lead_in_s"] = f"{lead:g}"
    return DriveLog(
        t=t, omega=omega, heading_truth=heading, speed=speed, name="rtklib_drive0708", meta=meta
    )


# -- DrivePlotR naturalistic driving sample --------------------------------------------------

MPH = 0.44704
"""m/s per mile per hour."""


def _float_or_nan(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan


def driveplotr_to_drives(folder: Path = DATA / "driveplotr_nds") -> list[DriveLog]:
    """The 28 DrivePlotR drives as drive logs, in drive order (see the module docstring)."""
    import csv

    path = folder / "nds_data.csv"
    cols = ("drive", "time_utc", "speed_mph", "gps_heading_raw", "gyro_z")
    data: dict[str, list[float]] = {c: [] for c in cols}
    with open(path, encoding="utf-8", newline="") as f:
        reader = csv.DictReader(f)
        missing = [c for c in cols if c not in (reader.fieldnames or [])]
        if missing:
            raise ValueError(f"{path}: missing column(s) {', '.join(missing)}")
        for row in reader:
            for c in cols:
                data[c].append(_float_or_nan(row[c]))
    a = {c: np.asarray(v, dtype=np.float64) for c, v in data.items()}
    drives = []
    for d in sorted({int(x) for x in a["drive"][np.isfinite(a["drive"])]}):
        m = (a["drive"] == d) & np.isfinite(a["time_utc"]) & np.isfinite(a["gyro_z"])
        order = np.argsort(a["time_utc"][m], kind="stable")
        tu = a["time_utc"][m][order]
        keep = np.concatenate(([True], np.diff(tu) > 0))
        tu = tu[keep]
        if tu.shape[0] < 2:
            continue
        omega = a["gyro_z"][m][order][keep]
        speed = a["speed_mph"][m][order][keep] * MPH
        course = np.mod(a["gps_heading_raw"][m][order][keep], 360.0)
        heading = np.where(speed > MIN_COURSE_SPEED_MPS, course, np.nan)
        t = tu - tu[0]
        lead = lead_in_seconds(t, speed, omega, margin_s=3.0)
        meta = {
            "source": "DrivePlotR nds_data (github.com/hardtme/DrivePlotR), MIT",
            "drive": str(d),
            "omega": "gyro_z, deg/s, CCW positive, 1 Hz point samples (quantised 1/16 deg/s)",
            "heading_truth": f"GPS course gps_heading_raw, speed > {MIN_COURSE_SPEED_MPS:g} m/s",
            "speed": "speed_mph (GPS or OBD) in m/s",
            "t0_s": f"{tu[0]:.0f}",
        }
        if lead is not None:
            meta["lead_in_s"] = f"{lead:g}"
        drives.append(
            DriveLog(
                t=t,
                omega=omega,
                heading_truth=heading,
                speed=speed,
                name=f"nds_drive{d:02d}",
                meta=meta,
            )
        )
    if not drives:
        raise ValueError(f"{path}: no drives")
    return drives


# -- public repositories (tools/real_sources.yaml) -------------------------------------------

SOURCES_YAML = Path(__file__).resolve().parent / "real_sources.yaml"
MIRRORS: Path | None = Path(os.environ["HDRD_MIRRORS"]) if os.environ.get("HDRD_MIRRORS") else None
"""$HDRD_MIRRORS: a folder of repository snapshots (``<owner>+<name>/repo``, a clone or a bare
git directory), where the recordings of tools/real_sources.yaml are read without --data. No
default: a clone is wherever its user put it."""


def public_source(key: str) -> dict[str, Any]:
    """The entry ``sources.<key>`` of tools/real_sources.yaml (repo, commit, files, drives...)."""
    import yaml

    with open(SOURCES_YAML, encoding="utf-8") as f:
        doc = yaml.safe_load(f)
    return dict(doc["sources"][key])


def default_clone(key: str) -> Path | None:
    """Default location of a public source: its repository's snapshot under $HDRD_MIRRORS
    (None without it)."""
    if MIRRORS is None:
        return None
    return MIRRORS / public_source(key)["repo"].replace("/", "+") / "repo"


def clone_command(key: str) -> str:
    """The commands that make a clone of public source ``key`` at its recorded commit."""
    meta = public_source(key)
    folder = meta["repo"].rsplit("/", 1)[-1]
    return (
        f"git clone https://github.com/{meta['repo']} {folder} && "
        f"git -C {folder} checkout {meta['commit']}"
    )


def no_clone(key: str) -> str:
    """Why public source ``key`` cannot be read without --data, and how to get it."""
    return f"no clone of github.com/{public_source(key)['repo']} given; {clone_hint(key)}"


def clone_hint(key: str) -> str:
    """How to make public source ``key`` readable: its clone command, and where to name it."""
    repo = public_source(key)["repo"]
    return (
        f"clone it (`{clone_command(key)}`) and pass the clone with --data, or set "
        f"HDRD_MIRRORS to a folder holding it as {repo.replace('/', '+')}/repo "
        "(docs/real-data.md)"
    )


def _clone(key: str, src: Path | None) -> Path:
    """``src``, else the snapshot under $HDRD_MIRRORS; ValueError naming the clone command."""
    src = default_clone(key) if src is None else src
    if src is None:
        raise ValueError(no_clone(key))
    return src


def read_source_file(src: Path, key: str, path: str) -> bytes:
    """The bytes of ``path`` of public source ``key``: from a clone's work tree (src/path), or
    from a bare git directory at the recorded commit; refused when its sha256 is not the one
    recorded in tools/real_sources.yaml (another version of the file)."""
    import hashlib
    import subprocess

    meta = public_source(key)
    files = {f["path"]: f for f in meta["files"]}
    if path not in files:
        raise ValueError(f"{path}: not listed for {key} in {SOURCES_YAML.name}")
    if (src / path).is_file():
        data = (src / path).read_bytes()
    elif (src / "HEAD").is_file() and (src / "objects").is_dir():
        run = subprocess.run(
            ["git", "--git-dir", str(src), "show", f"{meta['commit']}:{path}"],
            capture_output=True,
            check=False,
        )
        if run.returncode != 0:
            raise ValueError(f"{src}: git cannot show {meta['commit'][:12]}:{path}")
        data = run.stdout
    else:
        raise ValueError(
            f"{src}: holds no {path}; clone github.com/{meta['repo']} (commit "
            f"{meta['commit'][:12]}) and pass the clone with --data"
        )
    digest = hashlib.sha256(data).hexdigest()
    if digest != files[path]["sha256"]:
        raise ValueError(
            f"{src}/{path}: sha256 {digest[:12]}... is not the recorded "
            f"{files[path]['sha256'][:12]}... (check out commit {meta['commit'][:12]})"
        )
    return data


def _semicolon_table(data: bytes, label: str, columns: tuple[str, ...]) -> FloatArray:
    """The numeric rows of a Nav Sensor Recorder CSV (``;``-separated, ``Name [unit]`` header
    after free text lines), only the named columns (matched by the text before " ["), in that
    order. Rows that are not all numbers are skipped."""
    names: list[str] | None = None
    rows = []
    for line in data.decode("utf-8", errors="replace").splitlines():
        parts = [p.strip() for p in line.strip().rstrip(";").split(";")]
        if names is None:
            if any(p.startswith(columns[0] + " [") for p in parts):
                names = [p.split(" [")[0] for p in parts]
                missing = [c for c in columns if c not in names]
                if missing:
                    raise ValueError(f"{label}: no column {', '.join(missing)}")
                idx = [names.index(c) for c in columns]
            continue
        if len(parts) != len(names):
            continue
        try:
            rows.append([float(parts[i]) for i in idx])
        except ValueError:
            continue
    if names is None or len(rows) < 2:
        raise ValueError(f"{label}: no header with {columns[0]!r} or fewer than 2 rows")
    return np.asarray(rows, dtype=np.float64)


def _increasing(t: FloatArray) -> np.ndarray:
    """Mask keeping the rows whose time is above every earlier row's (strictly increasing t)."""
    prev = np.concatenate(([-np.inf], np.maximum.accumulate(t)[:-1]))
    return np.asarray(t > prev)


def _unit(v: FloatArray) -> FloatArray:
    return np.asarray(v / np.linalg.norm(v), dtype=np.float64)


def _after_handling(gyro: FloatArray, fix: FloatArray, margin_s: float = 2.0) -> np.ndarray:
    """Rows of a phone's gyro table (ns, rad/s) from the end of the last handling of the phone
    in the standing start: a 1 s mean rate above 20 deg/s while every fix so far reads
    standstill (a hand, not the car) ends ``margin_s`` before the rows kept, which start the
    drive there, so that its lead-in (the bias, the vertical) is measured as the phone then
    sits. All rows when the phone was not handled."""
    t = gyro[:, 0] * 1e-9
    moving = np.flatnonzero(fix[:, 2] > 0.3)
    t_move = fix[moving[0], 0] * 1e-9 if moving.shape[0] else t[-1]
    rate = _moving_mean(t, np.degrees(np.linalg.norm(gyro[:, 1:4], axis=1)), 1.0)
    handled = np.flatnonzero((rate > 20.0) & (t < t_move))
    if handled.shape[0] == 0:
        return np.ones(t.shape[0], dtype=bool)
    return np.asarray(t > t[handled[-1]] + margin_s)


def oan_to_drives(src: Path | None = None) -> list[DriveLog]:
    """The Open Aided Navigation car drives as drive logs (see the module docstring)."""
    src = _clone("oan", src)
    meta = public_source("oan")
    logs = []
    for name, folder in meta["drives"].items():
        folder = str(folder)
        stem = f"data/nsr/drive/{folder}/{folder[:15]}"

        def table(kind: str, cols: tuple[str, ...], stem: str = stem) -> FloatArray:
            path = f"{stem}_{kind}.csv"
            return _semicolon_table(read_source_file(src, "oan", path), path, cols)

        gyro = table("Gyro", ("TimestampGyro", "GyroX", "GyroY", "GyroZ"))
        acc = table("Acc", ("TimestampAcc", "AccX", "AccY", "AccZ"))
        fix = table("GNSS", ("TimestampGNSS", "UTC time", "Speed", "Heading"))
        gyro, fix = gyro[_increasing(gyro[:, 0])], fix[_increasing(fix[:, 0])]
        gyro = gyro[_after_handling(gyro, fix)]
        tg, ta, tf = gyro[:, 0] * 1e-9, acc[:, 0] * 1e-9, fix[:, 0] * 1e-9
        t = tg - tg[0]
        # The lead-in: the first fix reads standstill and the car stands until a fix says it
        # moves; rows before the first fix take its speed (checked by the gyro's 1 s mean, about
        # the whole drive's mean specific force: the phone's rough vertical).
        speed = np.interp(tg, tf, fix[:, 2], left=np.nan, right=np.nan)
        lead_speed = np.where(tg < tf[0], fix[0, 2], speed)
        omega0 = np.degrees(gyro[:, 1:4] @ _unit(acc[:, 1:4].mean(axis=0)))
        lead = lead_in_seconds(t, lead_speed, omega0, margin_s=2.0)
        still = (ta - tg[0]) < lead if lead is not None else np.ones(ta.shape, dtype=bool)
        up = _unit(acc[still, 1:4].mean(axis=0))
        omega = np.degrees(gyro[:, 1:4] @ up)
        course = fix[:, 3]
        ok = (fix[:, 2] > MIN_COURSE_SPEED_MPS) & (course >= 0.0) & (course < 360.0)
        heading = np.full(t.shape[0], np.nan)
        rows, near = _nearest_rows(tg, tf, 0.02)
        heading[rows] = np.where(ok[near], course[near], np.nan)
        speed[rows] = fix[near, 2]  # a fix's own speed at its row (also past the last fix)
        m = {
            "source": f"Open Aided Navigation {stem} (github.com/{meta['repo']} "
            f"{meta['commit'][:12]}), MIT",
            "omega": "phone gyro (LSM6DSL) vector projected on the static vertical, deg/s, CCW positive, 50 Hz, raw",
            "heading_truth": f"phone GNSS course (Android bearing) at 1 Hz, speed > {MIN_COURSE_SPEED_MPS:g} m/s, at the row nearest each fix",
            "speed": "phone GNSS speed, interpolated",
            "t0_s": f"{tg[0]:.6f} (phone elapsed-realtime clock); first fix UTC ms {fix[0, 1]:.0f}",
            "phone_tilt_deg": f"{math.degrees(math.acos(min(1.0, abs(float(up[2]))))):.1f} (vertical from the phone's z axis)",
        }
        if lead is not None:
            m["lead_in_s"] = f"{lead:g}"
        logs.append(
            DriveLog(t=t, omega=omega, heading_truth=heading, speed=speed, name=name, meta=m)
        )
    return logs


def psins_to_drive(src: Path | None = None) -> DriveLog:
    """PSINS's MEMS-vs-FOG-INS car run as a drive log (see the module docstring)."""
    import io

    from scipy.io import loadmat

    src = _clone("psins", src)
    meta = public_source("psins")
    path = meta["drives"]["psins_fog_mems"]
    mat = loadmat(io.BytesIO(read_source_file(src, "psins", path)))
    imu = np.asarray(mat["mimu"], dtype=np.float64)  # dtheta xyz (rad), dv xyz (m/s), t (s)
    avp = np.asarray(
        mat["fogavp"], dtype=np.float64
    )  # pitch roll yaw (rad), vE vN vU, lat lon h, t
    if imu.ndim != 2 or imu.shape[1] != 7 or avp.ndim != 2 or avp.shape[1] != 10:
        raise ValueError(f"{path}: mimu is not (n, 7) or fogavp not (n, 10)")
    imu = imu[_increasing(imu[:, 6])]
    avp = avp[_increasing(avp[:, 9]) & (avp[:, 6] > 0.1)]  # the INS is valid (as PSINS's demo)
    t_imu = imu[:, 6]
    dt = float(np.median(np.diff(t_imu)))
    up = _unit(imu[:, 3:6].mean(axis=0))  # no standstill: the run's mean specific force
    omega = np.degrees(imu[:, 0:3] @ up) / dt
    t_avp = avp[:, 9]
    yaw = np.degrees(np.unwrap(avp[:, 2]))  # PSINS: yaw counter-clockwise from north
    heading = np.full(t_imu.shape[0], np.nan)
    rows, near = _nearest_rows(t_imu, t_avp, dt / 2)
    heading[rows] = np.mod(-yaw[near], 360.0)
    omega_truth = np.interp(t_imu, t_avp, np.gradient(yaw, t_avp), left=np.nan, right=np.nan)
    speed = np.interp(t_imu, t_avp, np.hypot(avp[:, 3], avp[:, 4]), left=np.nan, right=np.nan)
    return DriveLog(
        t=t_imu - t_imu[0],
        omega=omega,
        heading_truth=heading,
        omega_truth=omega_truth,
        speed=speed,
        name="psins_fog_mems",
        meta={
            "source": f"PSINS {path} (github.com/{meta['repo']} {meta['commit'][:12]}), BSD-2-Clause",
            "omega": f"MEMS gyro increments / {dt:g} s projected on the run's mean specific force, deg/s, CCW positive, raw",
            "heading_truth": "FOG INS heading (minus PSINS's counter-clockwise yaw), at the row nearest each 10 Hz epoch",
            "omega_truth": "d/dt of the FOG INS yaw, interpolated",
            "speed": "FOG INS horizontal speed, interpolated",
            "imu_tilt_deg": f"{math.degrees(math.acos(min(1.0, abs(float(up[2]))))):.2f}",
        },
    )


BOREAS_COLUMNS = (
    "GPSTime", "easting", "northing", "altitude", "vel_east", "vel_north", "vel_up",
    "roll", "pitch", "heading", "angvel_z", "angvel_y", "angvel_x",
)  # fmt: skip
"""The columns of a Boreas ``applanix/<sensor>_poses.csv``, in order (DATA_REFERENCE.md)."""
BOREAS_HEADING_OFFSET_DEG = 43.2
"""Compass course of the car minus the Applanix ``heading`` of the lidar frame (taken as
clockwise, deg) on straight road: 43.21 deg on the tuning drive, 43.17 on the judging drive
(sd 0.5; the module docstring)."""


def _boreas_table(data: bytes, label: str) -> FloatArray:
    """The rows of a Boreas pose CSV (header :data:`BOREAS_COLUMNS`), strictly increasing in
    time; ValueError naming the file otherwise."""
    import io

    text = data.decode("utf-8", errors="replace")
    head = tuple(c.strip() for c in text.split("\n", 1)[0].split(","))
    if head != BOREAS_COLUMNS:
        raise ValueError(f"{label}: header is not {','.join(BOREAS_COLUMNS)}")
    rows = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1, ndmin=2)
    if rows.shape[0] < 2 or rows.shape[1] != len(BOREAS_COLUMNS):
        raise ValueError(f"{label}: fewer than 2 rows of {len(BOREAS_COLUMNS)} numbers")
    if not np.all(np.isfinite(rows)) or not np.all(np.diff(rows[:, 0]) > 0):
        raise ValueError(f"{label}: a value is not finite or the time does not increase")
    return np.asarray(rows, dtype=np.float64)


def boreas_to_drives(src: Path | None = None) -> list[DriveLog]:
    """The two Boreas drives as *routes*: drive logs whose ``omega`` is the true rate (a
    perfect gyro) for :mod:`hdrd.sim.roads` to carry simulated gyros (see the module
    docstring)."""
    src = _clone("boreas", src)
    meta = public_source("boreas")
    logs = []
    for name, folder in meta["drives"].items():
        path = f"pyboreas/test/demo/gt/{folder}/applanix/lidar_poses.csv"
        a = _boreas_table(read_source_file(src, "boreas", path), path)
        t = (a[:, 0] - a[0, 0]) * 1e-6
        rate = np.degrees(a[:, 10])  # about the lidar's z axis (up): CCW positive
        heading = np.mod(np.degrees(a[:, 9]) + BOREAS_HEADING_OFFSET_DEG, 360.0)
        speed = np.hypot(a[:, 4], a[:, 5])
        lead = lead_in_seconds(t, speed, rate, margin_s=1.0)
        m = {
            "source": f"Boreas {folder} {path} (github.com/{meta['repo']} "
            f"{meta['commit'][:12]}; Burnett et al., IJRR 2023), data CC BY 4.0",
            "route": "true rate: omega is omega_truth, a perfect gyro (hdrd.sim.roads puts a "
            "simulated gyro on this route)",
            "omega": "Applanix POS LV angvel_z (post-processed, bias-free) of the lidar frame, "
            "z up, deg/s, CCW positive, ~9.6 Hz",
            "omega_truth": "the same",
            "heading_truth": f"Applanix heading (clockwise, of the lidar frame) + "
            f"{BOREAS_HEADING_OFFSET_DEG:g} deg: the car's course on straight road, compass",
            "speed": "Applanix horizontal speed hypot(vel_east, vel_north)",
            "t0_s": f"{a[0, 0] * 1e-6:.6f} (UTC, s since 1970)",
        }
        if lead is not None:
            m["lead_in_s"] = f"{lead:g}"
        logs.append(DriveLog(t, rate, None, heading, rate.copy(), speed, name=name, meta=m))
    return logs


def _one(fn: Callable[[Path], DriveLog]) -> Callable[[Path], list[DriveLog]]:
    return lambda folder: [fn(folder)]


CONVERTERS: dict[str, tuple[Callable[[Path], list[DriveLog]], str]] = {
    "smartloc": (_one(smartloc_to_drive), "smartloc_berlin"),
    "comma2k19": (_one(comma2k19_to_drive), "comma2k19_example"),
    "rtklib": (_one(rtklib_to_drive), "rtklib_drive0708"),
    "driveplotr": (driveplotr_to_drives, "driveplotr_nds"),
}
"""Recording of ../shared/data -> (converter to drive logs, its folder there); ``all`` converts
these."""
PUBLIC: dict[str, tuple[Callable[[Path], list[DriveLog]], str]] = {
    "oan": (oan_to_drives, "oan"),
    "psins": (_one(psins_to_drive), "psins"),
    "boreas": (boreas_to_drives, "boreas"),
}
"""Recording of a public repository -> (converter, its key in tools/real_sources.yaml); read from
a clone (--data) or the fetched snapshot. Not part of ``all``."""
MULTI = {"driveplotr", "oan", "boreas"}
"""Recordings that become several logs (written with --out-dir)."""


def _absent_hint(name: str) -> str:
    """What to do when a recording's default location is absent."""
    if name in PUBLIC:
        return "; " + clone_hint(PUBLIC[name][1])
    return (
        "; the default is ../shared/data beside the repository (or $HDRD_REAL_DATA): pass the "
        "recording's folder with --data ('all': the folder holding every recording's folder)"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("which", choices=(*CONVERTERS, *PUBLIC, "all"))
    p.add_argument(
        "--data",
        "--src",
        dest="data",
        type=Path,
        help="the recording's folder, or for oan/psins/boreas a clone of its repository (default: "
        "../shared/data/<folder>; for those $HDRD_MIRRORS/<owner>+<name>/repo, no default "
        "without it); with 'all', the folder holding the "
        "recordings' folders (default ../shared/data)",
    )
    p.add_argument("--out", type=Path, help="drive log CSV to write (one single-log recording)")
    p.add_argument(
        "--out-dir", type=Path, help="directory for <name>.csv (with 'all', driveplotr and oan)"
    )
    args = p.parse_args(argv)
    multi = args.which == "all" or args.which in MULTI
    if multi and (args.out_dir is None or args.out is not None):
        p.error(f"{args.which} writes several logs: give --out-dir (not --out)")
    if not multi and args.out is None:
        p.error("--out is required")
    jobs: list[tuple[str, Callable[[Path], list[DriveLog]], Path]] = []
    if args.which == "all":
        root = args.data if args.data is not None else DATA
        jobs = [(name, fn, root / folder) for name, (fn, folder) in CONVERTERS.items()]
    elif args.which in PUBLIC:
        fn, key = PUBLIC[args.which]
        clone = args.data if args.data is not None else default_clone(key)
        if clone is None:
            print(f"convert_real: {args.which}: {no_clone(key)}", file=sys.stderr)
            return 1
        jobs = [(args.which, fn, clone)]
    else:
        fn, folder = CONVERTERS[args.which]
        jobs = [(args.which, fn, args.data if args.data is not None else DATA / folder)]
    for name, convert, src in jobs:
        if not src.exists():
            hint = _absent_hint(name) if args.data is None else ""
            print(f"convert_real: {name}: {src} is absent{hint}", file=sys.stderr)
            return 1
        try:
            logs = convert(src)
        except (OSError, ValueError, KeyError) as e:
            print(f"convert_real: {name}: {e}", file=sys.stderr)
            return 1
        for log in logs:
            out = args.out_dir / f"{log.name}.csv" if multi else args.out
            out.parent.mkdir(parents=True, exist_ok=True)
            write_drive(out, log)
            fixes = (
                int(np.isfinite(log.heading_truth).sum()) if log.heading_truth is not None else 0
            )
            lead = log.meta.get("lead_in_s")
            print(
                f"{out}: {len(log)} rows, {log.duration_s:.1f} s at {log.rate_hz:.1f} Hz, "
                f"{fixes} heading fixes" + (f", lead-in {lead} s" if lead else "")
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
