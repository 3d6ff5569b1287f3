"""The recordings of ../shared/data as hdrd drive logs (smartLoc, comma2k19, rtklib,
driveplotr: the converters ``python tools/convert_real.py`` runs), and what every converter
shares: geodesy, the course from positions, the start-up standstill, the row nearest an event.

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

Each log that starts at standstill says so in ``lead_in_s`` (docs/drive-format.md): the seconds
from the first sample during which the vehicle stood still, so that the static bias can be
measured there. From the speed: the initial run of rows with speed <= 0.3 m/s (RTK) or
<= 0.3 m/s and |omega - median| <= 0.5 deg/s (driveplotr: its GPS speed lags and reads ~0.1 m/s
while the car already turns out of a parking space), ended a margin before the first row that
fails (1 s for rtklib, 3 s for driveplotr's lagging speed); a lead-in under 3 s is not written.
smartLoc, comma2k19, psins and the 100 s oan drive start moving: they carry no ``lead_in_s``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import numpy.typing as npt

from hdrd.io.files.drivelog import DriveLog

FloatArray = npt.NDArray[np.float64]

DATA = Path(
    os.environ.get("HDRD_REAL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")
)
"""../shared/data beside the repository (or $HDRD_REAL_DATA): the recordings' folders."""
MIN_COURSE_SPEED_MPS = 2.0

# WGS84
WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3


def geodetic_lat_lon(x: float, y: float, z: float) -> tuple[float, float]:
    """Geodetic latitude and longitude (rad) of an ECEF point (m), WGS84."""
    lon = math.atan2(y, x)
    p = math.hypot(x, y)
    lat = math.atan2(z, p * (1 - WGS84_E2))
    for _ in range(5):
        n = WGS84_A / math.sqrt(1 - WGS84_E2 * math.sin(lat) ** 2)
        h = p / math.cos(lat) - n
        lat = math.atan2(z, p * (1 - WGS84_E2 * n / (n + h)))
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
        w = moving_mean(t, omega, 1.0)
        med = float(np.median(w[:end]))
        bad = np.flatnonzero(np.abs(w[:end] - med) > max_rate_dev_dps)
        if bad.shape[0]:
            end = int(bad[0])
    if end == 0:
        return None
    t_fail = float(t[end]) if end < t.shape[0] else float(t[-1])
    lead = math.floor(t_fail - float(t[0]) - margin_s)
    return float(lead) if lead >= min_s else None


def moving_mean(t: FloatArray, x: FloatArray, window_s: float) -> FloatArray:
    """Mean of x over the rows within +-window_s/2 of each row (x itself at <= 1 row per window)."""
    c = np.concatenate(([0.0], np.cumsum(x)))
    lo = np.searchsorted(t, t - window_s / 2, side="left")
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    return (c[hi] - c[lo]) / np.maximum(hi - lo, 1)


def nearest_rows(
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
    rows, ok = nearest_rows(t_gps, t_pos, 0.02)
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
