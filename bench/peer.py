"""The course-aided Kalman filter of heading and bias that bench/outages.py and bench/holds.py
set beside hdrd's methods through GNSS outages: the peer (Groves, Principles of GNSS, Inertial,
and Multisensor Integrated Navigation Systems, 2nd ed., ch. 14: loosely coupled, one axis).
bench/outages.py's docstring says how it is tuned and on which data."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hdrd.analysis.outages import OutageSpec, drive_fixes, outage_windows
from hdrd.analysis.prepare import PreparedDrive
from hdrd.daemon.aiding import wrap180
from hdrd.io.drivelog import DriveLog


@dataclass(frozen=True)
class PeerParams:
    """The Kalman peer's settings (units in the names); the defaults are the tuned ones (the
    module docstring says which data tuned which)."""

    course_sd_deg: float = 1.0
    """A fix's course noise, 1 sigma, deg (R = its square)."""
    psi_q_deg2_per_s: float = 0.1
    """White heading process noise, deg^2/s (the gyro's angle random walk, aliasing)."""
    scale_sd: float = 0.05
    """The gyro's scale-factor uncertainty: heading process noise (scale_sd x the step's turn)^2."""
    bias_q: float = 3e-5
    """The bias's random walk, (deg/s)^2/s."""
    bias0_sd_dps: float = 0.05
    """The start-up calibration's bias uncertainty, deg/s (at least that of its mean)."""
    gate_sigma: float = 3.0
    """Innovations beyond this many sigma are not used ..."""
    gate_floor_deg: float = 5.0
    """... nor is the gate ever narrower than this, deg ..."""
    realign_after: int = 5
    """... and after this many rejected fixes in a row the heading is reset to the course
    (its variance to R; the bias kept): the filter, not the GPS, has lost the heading."""
    latency_s: float = 0.5
    """A fix's latency the filter does not model, s: in a turn its course is off by up to
    the rate times this, so R grows by (latency_s x rate)^2 (the daemon's aiding's)."""
    min_speed_mps: float = 5.0
    """A course is used at or above this speed, m/s (the daemon's aiding's threshold)."""
    max_rate_dps: float = 10.0
    """... and while the gyro turns by at most this, deg/s."""


SWEEP: dict[str, tuple[float, ...]] = {
    "course_sd_deg": (0.5, 2.0, 3.0),
    "psi_q_deg2_per_s": (0.03, 0.3),
    "scale_sd": (0.0, 0.02, 0.1),
    "bias_q": (1e-6, 1e-5, 5e-5, 1e-4),
    "bias0_sd_dps": (0.01, 0.2),
    "gate_sigma": (2.0, 5.0),
    "gate_floor_deg": (2.0, 20.0),
    "realign_after": (2, 20, 10**9),
    "latency_s": (0.0, 1.0),
    "min_speed_mps": (2.0, 8.0),
    "max_rate_dps": (3.0, 5.0, 100.0),
}
"""What ``--tune-peer`` tries, one setting at a time, around :class:`PeerParams`."""


def _fix_of_step(fix_t: np.ndarray, t0: float, t1: float, j: int) -> tuple[int, int]:
    """(index of the last fix with t0 < time <= t1, or -1; the index of the first fix after
    t1): one course per step, the newest; older ones are stale by the step's end."""
    last = -1
    while j < fix_t.shape[0] and fix_t[j] <= t1:
        if fix_t[j] > t0:
            last = j
        j += 1
    return last, j


def kalman_peer(
    prep: PreparedDrive, log: DriveLog, spec: OutageSpec, p: PeerParams = PeerParams()
) -> np.ndarray:
    """The peer's heading error (deg, wrapped) at the end of each outage (NaN where the truth
    is unknown): a Kalman filter of heading psi (compass deg) and gyro bias b (deg/s) on the
    drive's steps (module docstring), with the settings ``p``. Complex because it is the
    filter's loop: predict, take the step's fix, gate it, update or reset."""
    s = prep.steps
    fix_t, fixes = drive_fixes(log)
    windows = outage_windows(spec, prep.start_s, float(s.t_end[-1]))
    raw = s.u + s.bias_dps  # block means, deg/s CCW
    n, T, R = s.u.shape[0], s.T, p.course_sd_deg**2
    sd0 = prep.bias_std_dps / math.sqrt(max(1.0, float(prep.samples_per_step or 1.0)))
    b0_var = max(p.bias0_sd_dps, sd0 if math.isfinite(sd0) else 0.0) ** 2
    psi, b, P = math.nan, s.bias_dps, np.diag([R, b0_var])
    heading = np.full(n, math.nan)
    j, rejected = 0, 0
    for i in range(n):
        t = float(s.t_end[i])
        rate = raw[i] - b
        if math.isfinite(psi):
            psi = (psi - rate * T) % 360.0
            F = np.array([[1.0, T], [0.0, 1.0]])
            q_psi = p.psi_q_deg2_per_s * T + (p.scale_sd * rate * T) ** 2
            P = F @ P @ F.T + np.diag([q_psi, p.bias_q * T])
        k, j = _fix_of_step(fix_t, t - T, t, j)
        f = fixes[k] if k >= 0 else None
        usable = (
            f is not None
            and f.track_deg is not None
            and not any(a <= fix_t[k] <= c for a, c in windows)  # none at the end either
            and f.speed_mps is not None
            and f.speed_mps >= p.min_speed_mps
            and abs(rate) <= p.max_rate_dps
        )
        if usable and f is not None and f.track_deg is not None:
            if not math.isfinite(psi):
                psi, P = f.track_deg, np.diag([R, b0_var])
            else:
                nu = wrap180(f.track_deg - psi)
                S = P[0, 0] + R + (p.latency_s * rate) ** 2
                if abs(nu) > max(p.gate_sigma * math.sqrt(S), p.gate_floor_deg):
                    rejected += 1
                    if rejected >= p.realign_after:
                        psi, P[0, 0], P[0, 1], P[1, 0], rejected = f.track_deg, R, 0.0, 0.0, 0
                else:
                    rejected = 0
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
