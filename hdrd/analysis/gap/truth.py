"""The true yaw rate of a drive log for the model-gap workflow: from ``omega_truth``, from a
heading truth's fixes, zero at rest (``--standstill``), and zero wherever the vehicle stands
(a stop from the speed with a guard at motion's edges, or the log's start-up standstill
``lead_in_s``): a car at rest does not turn, with or without a truth heading there.

Rates deg/s, + = CCW (left turn); heading compass deg, clockwise from north; time s since the
first sample (= power-on); speed m/s. Pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from hdrd.errors import HdrdError
from hdrd.io.files.drivelog import DriveLog

__all__ = [
    "STOP_MARGIN_S",
    "STOP_RATE_DEV_DPS",
    "STOP_SPEED_MPS",
    "GapError",
    "Truth",
    "fixes",
    "lead_in_s",
    "read_truth",
    "standing_rows",
    "truth_rate_from_heading",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

STOP_SPEED_MPS = 0.3
"""At or below this speed (m/s) the vehicle stands still: its true yaw rate is zero (the
standstill speed of ``hdrd evaluate``'s calibration and of tools/convert_real.py)."""
STOP_MARGIN_S = 3.0
"""Samples closer than this (s) to a stop's first or last row are not taken as standing: a
speed that lags (a GPS speed filtered over seconds) still reads zero while the car turns out
of its parking space (the converter's guard for such a speed)."""


class GapError(HdrdError, ValueError):
    """The log cannot be analysed (no truth, too short, ...); the message says why."""


def fixes(t: FloatArray, h: FloatArray) -> IntArray:
    """Row indices of the fixes in a heading column: finite values, a value held over several
    rows counted once (its first row)."""
    ok = np.flatnonzero(np.isfinite(h))
    if ok.shape[0] > 1:
        keep = np.concatenate(([True], h[ok[1:]] != h[ok[:-1]]))
        ok = ok[keep]
    return ok


def truth_rate_from_heading(
    t_s: npt.ArrayLike, heading_deg: npt.ArrayLike, max_gap_s: float = 2.5
) -> FloatArray:
    """True yaw rate (deg/s, + = CCW) per sample from a compass heading (deg, clockwise from
    north; NaN = unknown), e.g. a 1 Hz GPS course.

    Between two consecutive fixes at most ``max_gap_s`` apart the rate is -(heading change the
    short way round) / (time between them): CW -> CCW. It is given to the samples between the
    two fixes' rows; a fix's own row, shared by two intervals, gets the mean of both rates (the
    trapezoid rule: samples are instantaneous values, so a row between two intervals belongs
    half to each). NaN elsewhere (stops, outages, before the first fix).
    """
    t = np.asarray(t_s, dtype=np.float64)
    h = np.asarray(heading_deg, dtype=np.float64)
    out = np.full(t.shape[0], np.nan)
    ok = fixes(t, h)
    if ok.shape[0] < 2:
        return out
    tf, hf = t[ok], h[ok]
    dt = np.diff(tf)
    dh = (np.diff(hf) + 180.0) % 360.0 - 180.0  # shortest way round: 359 -> 1 is +2 deg
    rate = -dh / dt
    good = dt <= max_gap_s
    for j in np.flatnonzero(good):
        out[ok[j] : ok[j + 1]] = rate[j]
    both = np.flatnonzero(good[1:] & good[:-1]) + 1  # fixes with a good interval on each side
    out[ok[both]] = 0.5 * (rate[both - 1] + rate[both])
    return out


@dataclass(frozen=True)
class Truth:
    """The true rate of every sample (deg/s, + = CCW; NaN unknown), where it comes from and,
    with a heading truth, the heading (compass deg), its fixes' rows, the first fix's time and
    the median time between fixes (s)."""

    rate: FloatArray
    source: str
    heading: FloatArray | None = None
    fixes: IntArray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    origin: float = 0.0
    fix_dt: float = 1.0


def read_truth(log: DriveLog, t: FloatArray, standstill: bool) -> Truth:
    """The log's truth: ``omega_truth`` where it has values, else the derivative of
    ``heading_truth``, else zero when ``standstill``; GapError when there is none."""
    n = len(log)
    if log.omega_truth is not None and np.isfinite(log.omega_truth).any():
        truth = Truth(np.asarray(log.omega_truth, dtype=np.float64), "omega_truth")
    elif log.heading_truth is not None and np.isfinite(log.heading_truth).sum() > 2:
        heading = np.asarray(log.heading_truth, dtype=np.float64)
        fx = fixes(t, heading)
        truth = Truth(
            truth_rate_from_heading(t, heading),
            "heading_truth",
            heading,
            fx,
            float(t[fx[0]]),
            float(np.median(np.diff(t[fx]))) if fx.shape[0] > 1 else 1.0,
        )
    elif standstill:
        truth = Truth(np.zeros(n), "standstill")
    else:
        raise GapError(
            "the log has no truth: it needs an omega_truth or heading_truth column, "
            "or --standstill for a log taken at rest"
        )
    if standstill and truth.source != "standstill":
        truth = replace(truth, source=truth.source + " (--standstill ignored: the log has truth)")
    return truth


def lead_in_s(log: DriveLog) -> float:
    """The log's start-up standstill, s from its first sample (its ``lead_in_s`` metadata,
    docs/drive-format.md: written by ``hdrd simulate`` and tools/convert_real.py, which
    already end it a margin before the car moves); 0 when it has none."""
    try:
        v = float(log.meta.get("lead_in_s", ""))
    except ValueError:
        return 0.0
    return v if math.isfinite(v) and v > 0 else 0.0


STOP_RATE_DEV_DPS = 0.5
"""Within a stop, rows whose rate averaged over 1 s is further than this (deg/s; or 1.5 ADC
steps, if more) from the stop's median are not standing: a rotating car is not standing,
whatever a lagging speed says (the converter's guard; a GPS speed read once a second still
says 0.01 m/s while the car turns out of its parking space at 16 deg/s)."""


def _runs(st: BoolArray, time_gap: BoolArray) -> IntArray:
    """The run index of every row of ``st`` (consecutive rows without a time gap), -1 off it."""
    new_run = st & ~np.concatenate(([False], st[:-1] & ~time_gap[1:]))
    return np.where(st, np.cumsum(new_run) - 1, -1)


def _moving_mean(t: FloatArray, x: FloatArray, window_s: float) -> FloatArray:
    """Mean of x over the rows within +-window_s/2 of each row (x itself at 1 row a window)."""
    c = np.concatenate(([0.0], np.cumsum(x)))
    lo = np.searchsorted(t, t - window_s / 2, side="left")
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    return np.asarray((c[hi] - c[lo]) / np.maximum(hi - lo, 1))


def _not_turning(
    st: BoolArray, run: IntArray, t: FloatArray, omega: FloatArray, dev: float
) -> BoolArray:
    """``st`` without the rows whose 1-s mean rate is further than ``dev`` (deg/s) from their
    run's median."""
    w = _moving_mean(t, np.nan_to_num(omega), 1.0)
    med = np.zeros(int(run.max()) + 1)
    for r in np.unique(run[st]).tolist():
        med[r] = float(np.median(w[run == r]))
    return st & (np.abs(w - med[np.maximum(run, 0)]) <= dev)


def standing_rows(
    t: FloatArray,
    speed: FloatArray | None,
    excluded: BoolArray,
    time_gap: BoolArray,
    lead_in: float = 0.0,
    omega: FloatArray | None = None,
    step_dps: float = 0.0,
) -> BoolArray:
    """Rows at which the vehicle stands: inside a stop (the speed at most
    :data:`STOP_SPEED_MPS` and, given the rate ``omega`` (deg/s), its 1-s mean within
    :data:`STOP_RATE_DEV_DPS` (or 1.5 ADC steps ``step_dps``) of the stop's median, on a run
    of rows without a time gap, at least :data:`STOP_MARGIN_S` from the run's first and last
    row) or within the start-up standstill (t - t[0] < ``lead_in``, s); never an excluded row.
    There the true yaw rate is zero at every sample. ``t``: s; ``speed``: m/s (NaN unknown)
    or None."""
    out = np.zeros(t.shape[0], dtype=bool)
    if lead_in > 0:
        out |= (t - t[0]) < lead_in
    if speed is not None:
        st = np.isfinite(speed) & (speed <= STOP_SPEED_MPS) & ~excluded
        if st.any() and omega is not None:
            dev = max(STOP_RATE_DEV_DPS, 1.5 * step_dps)
            st = _not_turning(st, _runs(st, time_gap), t, omega, dev)
        if st.any():
            run = _runs(st, time_gap)
            idx = run[st]
            t_first = np.full(int(idx.max()) + 1, np.inf)
            t_last = np.full(int(idx.max()) + 1, -np.inf)
            np.minimum.at(t_first, idx, t[st])
            np.maximum.at(t_last, idx, t[st])
            ts = t[st]
            out[st] |= (ts - t_first[idx] >= STOP_MARGIN_S) & (t_last[idx] - ts >= STOP_MARGIN_S)
    return out & ~excluded
