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

- smartLoc Berlin, comma2k19, rtklib_drive0708, driveplotr_nds: tools/convert_shared.py,
  with the start-up standstill (``lead_in_s``) every converter measures.
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

from hdrd.io.files.drivelog import DriveLog, write_drive

# The repository on sys.path, for tools.convert_shared when this file runs as a script.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tools.convert_shared import (  # noqa: E402
    DATA,
    MIN_COURSE_SPEED_MPS,
    FloatArray,
    comma2k19_to_drive,
    driveplotr_to_drives,
    lead_in_seconds,
    moving_mean,
    nearest_rows,
    rtklib_to_drive,
    smartloc_to_drive,
)

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
    idx: list[int] | None = None
    width = 0
    rows = []
    for line in data.decode("utf-8", errors="replace").splitlines():
        parts = [p.strip() for p in line.strip().rstrip(";").split(";")]
        if idx is None:
            idx = _header_columns(parts, label, columns)
            width = len(parts)
            continue
        if len(parts) != width:
            continue
        try:
            rows.append([float(parts[i]) for i in idx])
        except ValueError:
            continue
    if idx is None or len(rows) < 2:
        raise ValueError(f"{label}: no header with {columns[0]!r} or fewer than 2 rows")
    return np.asarray(rows, dtype=np.float64)


def _header_columns(parts: list[str], label: str, columns: tuple[str, ...]) -> list[int] | None:
    """The named columns' places when ``parts`` is the header (it names the first column),
    else None; ValueError when the header lacks one."""
    if not any(p.startswith(columns[0] + " [") for p in parts):
        return None
    names = [p.split(" [")[0] for p in parts]
    missing = [c for c in columns if c not in names]
    if missing:
        raise ValueError(f"{label}: no column {', '.join(missing)}")
    return [names.index(c) for c in columns]


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
    rate = moving_mean(t, np.degrees(np.linalg.norm(gyro[:, 1:4], axis=1)), 1.0)
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
        rows, near = nearest_rows(tg, tf, 0.02)
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
    rows, near = nearest_rows(t_imu, t_avp, dt / 2)
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


def _parser() -> argparse.ArgumentParser:
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
    return p


Job = tuple[str, Callable[[Path], list[DriveLog]], Path]
"""A recording's name, its converter, where it is read."""


def _jobs(which: str, data: Path | None) -> list[Job] | str:
    """What ``which`` converts, from ``data`` or the defaults; a message when a public
    source has no clone."""
    if which == "all":
        root = data if data is not None else DATA
        return [(name, fn, root / folder) for name, (fn, folder) in CONVERTERS.items()]
    if which in PUBLIC:
        fn, key = PUBLIC[which]
        clone = data if data is not None else default_clone(key)
        if clone is None:
            return f"convert_real: {which}: {no_clone(key)}"
        return [(which, fn, clone)]
    fn, folder = CONVERTERS[which]
    return [(which, fn, data if data is not None else DATA / folder)]


def _convert(job: Job, args: argparse.Namespace, multi: bool) -> bool:
    """One recording converted and its logs written (each said on stdout); False, said on
    stderr, when it is absent or unreadable."""
    name, convert, src = job
    if not src.exists():
        hint = _absent_hint(name) if args.data is None else ""
        print(f"convert_real: {name}: {src} is absent{hint}", file=sys.stderr)
        return False
    try:
        logs = convert(src)
    except (OSError, ValueError, KeyError) as e:
        print(f"convert_real: {name}: {e}", file=sys.stderr)
        return False
    for log in logs:
        out = args.out_dir / f"{log.name}.csv" if multi else args.out
        out.parent.mkdir(parents=True, exist_ok=True)
        write_drive(out, log)
        fixes = int(np.isfinite(log.heading_truth).sum()) if log.heading_truth is not None else 0
        lead = log.meta.get("lead_in_s")
        print(
            f"{out}: {len(log)} rows, {log.duration_s:.1f} s at {log.rate_hz:.1f} Hz, "
            f"{fixes} heading fixes" + (f", lead-in {lead} s" if lead else "")
        )
    return True


def main(argv: list[str] | None = None) -> int:
    p = _parser()
    args = p.parse_args(argv)
    multi = args.which == "all" or args.which in MULTI
    if multi and (args.out_dir is None or args.out is not None):
        p.error(f"{args.which} writes several logs: give --out-dir (not --out)")
    if not multi and args.out is None:
        p.error("--out is required")
    jobs = _jobs(args.which, args.data)
    if isinstance(jobs, str):
        print(jobs, file=sys.stderr)
        return 1
    for job in jobs:
        if not _convert(job, args, multi):
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
