"""Heading-error metrics of the paper's Sec. 5.2: Eψ (Eq. 12) and NEψ (Eq. 13).

Pure. Conventions (``shared/paper/HDR-NOTES.md``):

- gyro yaw ψ: degrees counter-clockwise since the start of the drive (HDR's output, Eq. 3);
- truth heading: compass degrees, clockwise from north, NaN where unknown;
- the gyro has no absolute reference, so its yaw is turned into a compass heading by aligning
  it to the truth at a step k (by default the first step where both exist)::

      heading_gyro_i = truth_k - (yaw_i - yaw_k)        (CCW yaw -> CW heading: minus sign)

  or, over n steps from k (``n`` > 1: a noisy truth such as a GPS course, aligned where it is
  trustworthy; :func:`hdrd.analysis.prepare.alignment` chooses k and n), to the circular mean
  A of truth_j + (yaw_j - yaw_k) over those steps with a truth: heading_gyro_i = A - (yaw_i -
  yaw_k);

- the momentary error is wrapped to [-180, 180) before the absolute value, so 359° vs 1° is
  a 2° error, not 358°;
- Eψ is the mean of |error| over the steps where truth exists (Eq. 12); NEψ = Eψ / Td with Td
  the drive's duration in minutes (Eq. 13), in deg/min.

Truth usually comes at 1 Hz (GPS) in a 10 Hz log, with empty cells between fixes and at low
speed. :func:`truth_at` samples it at the HDR step ends by linear interpolation of the
unwrapped heading between neighbouring fixes no further apart than ``max_gap_s``.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from hdrd.core.angles import wrap180

__all__ = [
    "abs_wrap180",
    "align_index",
    "e_psi",
    "e_psi_continuous",
    "gyro_heading",
    "heading_error",
    "improvement",
    "reference",
    "ne_psi",
    "truth_at",
    "wrap360",
]

FloatArray = npt.NDArray[np.float64]


def wrap360(h: npt.ArrayLike) -> FloatArray:
    """Heading(s) in degrees wrapped to [0, 360)."""
    return np.mod(np.asarray(h, dtype=np.float64), 360.0)


def align_index(yaw_deg_ccw: npt.ArrayLike, heading_truth_deg_cw: npt.ArrayLike) -> int | None:
    """Index of the first step where both the gyro yaw (first column if 2-D) and the truth are
    finite, or None if there is no such step."""
    yaw = np.asarray(yaw_deg_ccw, dtype=np.float64)
    truth = np.asarray(heading_truth_deg_cw, dtype=np.float64)
    y0 = yaw.reshape(yaw.shape[0], -1)[:, 0] if yaw.ndim > 1 else yaw
    ok = np.flatnonzero(np.isfinite(truth) & np.isfinite(y0))
    return int(ok[0]) if ok.shape[0] else None


def reference(yaw: FloatArray, truth: FloatArray, k: int, n: int = 1) -> float | FloatArray:
    """The compass heading (deg) the gyro's yaw at step k is aligned to: truth_k (n <= 1), or
    the circular mean over steps k .. k+n-1 with a truth of truth_j + (yaw_j - yaw_k) (per
    column of a 2-D yaw). yaw deg CCW, truth compass deg CW."""
    if n <= 1:
        return float(truth[k])
    t = truth[k : k + n]
    ok = np.isfinite(t)
    y = yaw[k : k + n][ok] - yaw[k]
    a = np.radians(t[ok].reshape((-1,) + (1,) * (yaw.ndim - 1)) + y)
    ref = np.degrees(np.arctan2(np.sin(a).mean(axis=0), np.cos(a).mean(axis=0)))
    return float(ref) if np.ndim(ref) == 0 else ref


def _aligned(
    yaw_deg_ccw: npt.ArrayLike, heading_truth_deg_cw: npt.ArrayLike, k: int | None
) -> tuple[FloatArray, FloatArray, int | None]:
    """yaw and truth as float arrays of the same length (else ValueError), and the step the
    gyro is aligned at: k, or by default :func:`align_index`."""
    yaw = np.asarray(yaw_deg_ccw, dtype=np.float64)
    truth = np.asarray(heading_truth_deg_cw, dtype=np.float64)
    if yaw.shape[0] != truth.shape[0]:
        raise ValueError(f"yaw has {yaw.shape[0]} steps, truth {truth.shape[0]}")
    return yaw, truth, align_index(yaw, truth) if k is None else k


def gyro_heading(
    yaw_deg_ccw: npt.ArrayLike,
    heading_truth_deg_cw: npt.ArrayLike,
    k: int | None = None,
    n: int = 1,
) -> FloatArray:
    """The gyro's compass heading (deg CW, NOT wrapped: continuous for plots), aligned to the
    truth at step k (default: the first step where both exist), over n steps
    (:func:`reference`). All NaN if never aligned.

    yaw has shape (n,) or (n, P) (P candidate runs); truth has shape (n,).
    """
    yaw, truth, k = _aligned(yaw_deg_ccw, heading_truth_deg_cw, k)
    if k is None:
        return np.full(yaw.shape, np.nan)
    return reference(yaw, truth, k, n) - (yaw - yaw[k])


def heading_error(
    yaw_deg_ccw: npt.ArrayLike,
    heading_truth_deg_cw: npt.ArrayLike,
    k: int | None = None,
    n: int = 1,
) -> FloatArray:
    """Signed momentary heading error gyro - truth, deg, wrapped to [-180, 180); NaN where the
    truth is unknown. The gyro's yaw is aligned to the truth at step k (default: the first
    step where both exist; the error there is 0), over n steps (:func:`reference`).

    yaw: deg CCW since start, shape (n,) or (n, P). truth: compass deg CW, shape (n,).
    """
    truth = np.asarray(heading_truth_deg_cw, dtype=np.float64)
    h = gyro_heading(yaw_deg_ccw, truth, k, n)
    t = truth.reshape((-1,) + (1,) * (h.ndim - 1))
    return wrap180(h - t)


def abs_wrap180(d: npt.ArrayLike) -> FloatArray:
    """|wrap180(d)|, deg in [0, 180]: the size of an angle difference, equal to
    ``abs(wrap180(d))`` but folding only the elements beyond 180 deg (tuning speed)."""
    x = np.asarray(d, dtype=np.float64)
    a = np.abs(np.atleast_1d(x))
    big = a > 180.0
    if big.any():  # rare for useful candidates: fold only those elements
        b = a[big]
        b -= 360.0 * np.floor(b / 360.0 + 0.5)
        a[big] = np.abs(b)
    return a.reshape(x.shape)


def e_psi(
    yaw_deg_ccw: npt.ArrayLike,
    heading_truth_deg_cw: npt.ArrayLike,
    k: int | None = None,
    n: int = 1,
) -> float | FloatArray:
    """Average heading error Eψ, deg (paper Eq. 12): mean |gyro - truth| over the steps where
    truth exists, the gyro aligned as in :func:`heading_error` (at step k, over n steps). A
    float for yaw of shape (n,), an array (P,) for (n, P). NaN if no truth (or no step to
    align at)."""
    yaw, truth, k = _aligned(yaw_deg_ccw, heading_truth_deg_cw, k)
    valid = np.isfinite(truth)
    if k is None or not valid.any():
        out = np.full(yaw.shape[1:], np.nan)
        return float(out) if out.ndim == 0 else out
    # gyro - truth = truth_k - (yaw_i - yaw_k) - truth_i = -((yaw_i - yaw_k) + (truth_i - truth_k));
    # the sign does not matter under |.|. Only the rows with truth are computed (tuning speed).
    d = yaw[valid]
    d -= yaw[k]
    if n <= 1:
        d += (truth[valid] - truth[k]).reshape((-1,) + (1,) * (yaw.ndim - 1))
    else:
        d += truth[valid].reshape((-1,) + (1,) * (yaw.ndim - 1))
        d -= reference(yaw, truth, k, n)
    m = np.mean(abs_wrap180(d), axis=0)
    return float(m) if np.ndim(m) == 0 else m


def e_psi_continuous(
    yaw_deg_ccw: npt.ArrayLike, heading_truth_deg_cw: npt.ArrayLike, k: int | None = None
) -> float:
    """Eψ with continuous headings, deg: the truth unwrapped along its fixes and the gyro's
    heading never wrapped, so a gyro that has drifted by a whole turn scores 360, not 0.

    Not hdrd's Eq. 12 (which wraps each momentary error to [-180, 180)), but what the paper's
    own Table II must have used: its Highway 1 drive averages 184 deg without HDR, impossible
    with wrapped errors. For comparisons with the paper only. yaw of shape (n,).
    """
    yaw = np.asarray(yaw_deg_ccw, dtype=np.float64)
    truth = np.asarray(heading_truth_deg_cw, dtype=np.float64)
    if k is None:
        k = align_index(yaw, truth)
    valid = np.flatnonzero(np.isfinite(truth))
    if k is None or valid.shape[0] == 0:
        return math.nan
    tu = np.unwrap(truth[valid], period=360.0)
    tu += truth[k] - tu[np.searchsorted(valid, k)]  # the same turn as the gyro at step k
    h = truth[k] - (yaw[valid] - yaw[k])
    return float(np.mean(np.abs(h - tu)))


def ne_psi(e_psi_deg: float | FloatArray, duration_min: float) -> float | FloatArray:
    """Normalized average heading error NEψ = Eψ / Td, deg/min (paper Eq. 13); Td in minutes."""
    if not duration_min > 0:
        raise ValueError(f"drive duration must be > 0 min, got {duration_min!r}")
    return e_psi_deg / duration_min


def improvement(e_without: float, e_with: float) -> float:
    """Relative HDR improvement Eψ(without) / Eψ(with) (paper Table II); inf if e_with is 0."""
    if e_with == 0.0:
        return float("inf") if e_without > 0.0 else float("nan")
    return float(e_without / e_with)


def truth_at(
    t_truth_s: npt.ArrayLike,
    heading_truth_deg_cw: npt.ArrayLike,
    t_query_s: npt.ArrayLike,
    max_gap_s: float = 2.0,
) -> FloatArray:
    """Truth heading (compass deg, [0, 360)) at the query times, NaN where unknown.

    Rows with NaN heading are not fixes. A query is answered by linear interpolation of the
    unwrapped heading between the fixes just before and just after it, if they are at most
    ``max_gap_s`` apart (or by a fix exactly at the query time); otherwise NaN, so a GPS
    outage or the low-speed blanking is never bridged by a guess.
    """
    t = np.asarray(t_truth_s, dtype=np.float64)
    h = np.asarray(heading_truth_deg_cw, dtype=np.float64)
    q = np.asarray(t_query_s, dtype=np.float64)
    ok = np.isfinite(h) & np.isfinite(t)
    tt, hh = t[ok], h[ok]
    out = np.full(q.shape, np.nan)
    if tt.shape[0] == 0:
        return out
    # Unwrapping between neighbouring fixes takes the short way round (< 180° per gap).
    hu = np.unwrap(hh, period=360.0)
    j = np.searchsorted(tt, q, side="right")  # tt[j-1] <= q < tt[j]
    exact = (j >= 1) & (tt[np.clip(j - 1, 0, None)] == q)
    inside = (j >= 1) & (j < tt.shape[0])
    lo = np.clip(j - 1, 0, tt.shape[0] - 1)
    hi = np.clip(j, 0, tt.shape[0] - 1)
    gap = tt[hi] - tt[lo]
    interp = inside & (gap <= max_gap_s) & (gap > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(interp, (q - tt[lo]) / np.where(gap > 0, gap, 1.0), 0.0)
    val = hu[lo] + frac * (hu[hi] - hu[lo])
    out[interp] = val[interp]
    out[exact] = hu[lo][exact]
    return wrap360(out)
