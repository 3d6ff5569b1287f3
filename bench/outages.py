#!/usr/bin/env python3
"""GNSS outages: each method through the daemon's GPS-aiding path against a course-aided
Kalman filter of heading and bias, on real and simulated drives.

    python bench/outages.py [--spec 120s/10min] [--workdir /tmp/hdrd-outages] [--set tune|judge|sim]
                            [--no-write]

What runs (``hdrd evaluate --outages``, :mod:`hdrd.analysis.outages`): each drive after its
start-up calibration; a GPS fix at each of the log's course samples (its ``gps_course``, else
``heading_truth``) fed to :class:`hdrd.daemon.aiding.GpsAiding` except inside the outages (one
of D s at the end of every P s); each method (``none`` = aiding with the bias frozen at the
outage's start, paper HDR, HDR+) through the aiding path; the heading error at each outage's
end. Beside them the *peer* (:func:`kalman_peer`): the loosely coupled course-aided filter of
Groves (Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems, 2nd ed.,
ch. 14), on one axis: states heading psi (compass deg) and gyro bias b (deg/s), propagated by
the gyro (psi <- psi - (omega_raw - b) T), updated by each course fix (outside the outages, at
the aiding's speed threshold, innovations beyond 3 sigma skipped); during an outage it
predicts only, its bias frozen at its estimate. Like the daemon's aiding it takes a course only
at or above the aiding's speed threshold and while the rate is below its alignment limit (in a
turn a fix's latency is an error).

Sets (docs/real-data.md, "The split"): ``tune`` (the real tuning drives, converted by
``tools/convert_real.py``), ``judge`` (the real judging drives: run once, to report), ``sim``
(simulated drives of every grade, seeds 7001-7003, temperature logged). Rewrites its own
section of bench/RESULTS.md (with ``--set judge`` and ``--set sim``; ``--no-write`` prints).
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from _common import machine_line, replace_section

from hdrd.analysis.outages import (
    FROZEN,
    OutageResult,
    OutageSpec,
    drive_fixes,
    outage_windows,
    run_outages,
)
from hdrd.analysis.prepare import EvaluationError, PreparedDrive, prepare_drive
from hdrd.daemon.aiding import AidingConfig, wrap180
from hdrd.io.drivelog import DriveLog, read_drive

SECTION = "## GNSS outages: through the daemon's aiding, against a course-aided Kalman filter"
METHODS = (FROZEN, "hdr", "hdr+")
PEER = "kalman peer"
MIN_SPEED_MPS = AidingConfig().min_speed_mps
MAX_RATE_DPS = AidingConfig().align_max_rate_dps


def kalman_peer(
    prep: PreparedDrive,
    log: DriveLog,
    spec: OutageSpec,
    course_sd_deg: float = 3.0,
    bias_q: float = 1e-6,
) -> np.ndarray:
    """The peer's heading error (deg, wrapped) at the end of each outage (NaN where the truth
    is unknown). course_sd_deg: a fix's course noise, deg (1 sigma; the daemon's gate assumes
    5 deg at 95 %); bias_q: the bias's random walk, (deg/s)^2/s."""
    s = prep.steps
    fix_t, fixes = drive_fixes(log)
    windows = outage_windows(spec, prep.start_s, float(s.t_end[-1]))
    raw = s.u + s.bias_dps  # block means, deg/s CCW
    n = s.u.shape[0]
    white = s.omega_std if s.omega_std is not None else np.full(n, 0.1)
    per = max(1.0, float(prep.samples_per_step or 1.0))
    psi = math.nan
    b = s.bias_dps
    P = np.diag(
        [
            course_sd_deg**2,
            (prep.bias_std_dps if math.isfinite(prep.bias_std_dps) else 0.05) ** 2 / per + 1e-4,
        ]
    )
    R = course_sd_deg**2
    heading = np.full(n, math.nan)
    j = 0
    for i in range(n):
        T = s.T
        if math.isfinite(psi):
            psi = (psi - (raw[i] - b) * T) % 360.0
            F = np.array([[1.0, T], [0.0, 1.0]])
            q_psi = (float(white[i]) ** 2 / per + 1e-6) * T * T
            P = F @ P @ F.T + np.diag([q_psi, bias_q * T])
        t = float(s.t_end[i])
        while j < len(fixes) and fix_t[j] <= t:
            f, tf = fixes[j], float(fix_t[j])
            j += 1
            if any(a <= tf < c for a, c in windows) or f.track_deg is None:
                continue
            if f.speed_mps is None or f.speed_mps < MIN_SPEED_MPS:
                continue
            if abs(raw[i] - b) > MAX_RATE_DPS:  # in a turn a fix's latency is an error
                continue
            if not math.isfinite(psi):
                psi = f.track_deg
                continue
            nu = wrap180(f.track_deg - psi)
            S = P[0, 0] + R
            if nu * nu > 9.0 * S:
                continue
            K = P[:, 0] / S
            psi = (psi + K[0] * nu) % 360.0
            b = b + K[1] * nu
            P = P - np.outer(K, P[0, :])
        heading[i] = psi
    ends = [int(np.searchsorted(s.t_end, c, side="right")) - 1 for _, c in windows]
    out = np.full(len(windows), math.nan)
    for k, i in enumerate(ends):
        if i >= 0 and math.isfinite(prep.truth[i]) and math.isfinite(heading[i]):
            out[k] = wrap180(float(heading[i]) - float(prep.truth[i]))
    return out


def real_drives(workdir: Path, which: str) -> list[Path]:
    """The real drives of one set (bench/real.py's split), converted into ``workdir`` as
    bench/real.py converts them (the public sources' where their snapshots are)."""
    from real import JUDGING, TUNING, convert_all

    names = TUNING if which == "tune" else JUDGING
    out = workdir / "real"
    out.mkdir(parents=True, exist_ok=True)
    convert_all(out, [])
    return sorted(p for p in out.glob("*.csv") if p.stem in names)


def sim_drives(workdir: Path) -> list[Path]:
    """Simulated drives of every grade with their temperature logged (``hdrd simulate``)."""
    out = workdir / "sim"
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for grade in ("crs03", "phone", "automotive", "tactical"):
        for seed, drive in ((7001, "mixed"), (7002, "city"), (7003, "highway")):
            p = out / f"{grade}-{drive}-{seed}.csv"
            if not p.exists():
                cmd = [sys.executable, "-m", "hdrd", "simulate", "--drive", drive, "--seed",
                       str(seed), "--minutes", "40", "--grade", grade, "--out", str(p)]  # fmt: skip
                subprocess.run(cmd, check=True, capture_output=True)
            paths.append(p)
    return paths


def score(paths: Sequence[Path], spec: OutageSpec) -> list[tuple[OutageResult, np.ndarray]]:
    rows = []
    for p in paths:
        log = read_drive(p)
        try:
            prep = prepare_drive(log)
            r = run_outages(prep, log, spec, METHODS)
        except EvaluationError as e:
            print(f"skipped {e}", file=sys.stderr)
            continue
        rows.append((r, kalman_peer(prep, log, spec)))
    return rows


def table(rows: Sequence[tuple[OutageResult, np.ndarray]]) -> str:
    cols = [*METHODS, PEER]
    head = (
        "| drive | outages | "
        + " | ".join("frozen bias" if m == FROZEN else m for m in cols)
        + " |"
    )
    lines = [head, "|" + "---|" * (len(cols) + 2)]
    pooled: dict[str, list[float]] = {m: [] for m in cols}
    for r, peer in rows:
        errs = {**{m: r.errors[m] for m in METHODS}, PEER: peer}
        ok = np.isfinite(errs[FROZEN]) & np.isfinite(peer)
        cells = []
        for m in cols:
            e = np.abs(errs[m][ok])
            pooled[m].extend(e.tolist())
            cells.append(f"{np.mean(e):.2f}" if e.shape[0] else "–")
        lines.append(f"| {r.name} | {int(ok.sum())}/{len(r.windows)} | " + " | ".join(cells) + " |")
    n = len(pooled[FROZEN])
    means = [f"**{np.mean(pooled[m]):.2f}**" if n else "–" for m in cols]
    lines.append(f"| all outages | {n} | " + " | ".join(means) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--spec", default="120s/10min", help="outages, DURATION/PERIOD (default 120s/10min)"
    )
    ap.add_argument(
        "--workdir", default="/tmp/hdrd-outages", help="drive logs (default /tmp/hdrd-outages)"
    )
    ap.add_argument(
        "--set",
        choices=("tune", "judge", "sim"),
        default="tune",
        help="which drives (default tune)",
    )
    ap.add_argument("--no-write", action="store_true", help="print, leave RESULTS.md alone")
    a = ap.parse_args(argv)
    spec = OutageSpec.parse(a.spec)
    work = Path(a.workdir)
    paths = sim_drives(work) if a.set == "sim" else real_drives(work, a.set)
    rows = score(paths, spec)
    text = table(rows)
    print(text)
    if a.no_write or a.set == "tune":
        return 0
    body = (
        f"{SECTION} ({a.set})\n\nGenerated by `python bench/outages.py --set {a.set} --spec {a.spec}` "
        f"({machine_line()}). Mean |heading error| at the end of each outage, deg, over the "
        "outages whose end has a truth heading; *frozen bias*: the daemon's aiding with the "
        "static bias it learned frozen at the outage's start (``none``); the *kalman peer*: "
        "the course-aided filter of heading and bias (bench/outages.py, `kalman_peer`).\n\n"
        + text
        + "\n"
    )
    replace_section(f"{SECTION} ({a.set})", body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
