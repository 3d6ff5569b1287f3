"""Static bias eps0: the mean gyro rate at standstill over Tbias (paper Sec. 2, Eq. 2).

Pure estimation (:func:`estimate_bias`, :class:`StartupWindow`); the bias file that keeps a
record is :mod:`hdrd.io.files.biasfile`. The paper averages Tbias = 30 s "with the gyro held
completely motionless" (20 s in its drives) and notes that "just one second ... is
sufficient" for usable results (Sec. 6).

The standstill test rejects a window whose samples say the vehicle moved:
- spread: the sample standard deviation exceeds ``max_std_dps`` (a turn, or rough motion);
- trend: the means of the window's first and last thirds differ by more than
  ``max_trend_dps`` (a slow turn or a creeping drift that the mean would absorb);
- excursion: any sample is further than ``max_excursion_dps`` from the median (a bump);
- size: the mean is beyond ``max_bias_dps`` (a constant rotation looks steady, but no
  CRS03-04 has a bias that large: +/-3 deg/s over -40..85 degC, docs/gyro-model.md).

Those limits are absolute, set for a CRS03-04-class gyro at 10 Hz. Two more scale with the
gyro's own noise and the number of samples, so that a quiet gyro sampled slowly (a phone at
1 Hz, where one sample is a whole second) cannot pass the start of a turn as standstill:
- shift: the samples far from the median (beyond ``SHIFT_INNER_SIGMAS`` noise sigmas) move
  the window's mean by more than ``max_shift_se`` standard errors of that mean;
- scaled trend: the first-vs-last-third trend exceeds ``max_trend_se`` standard errors of a
  difference of two third-means (never less than ``trend_floor_dps``).
The noise sigma is the larger of 1.4826 x the median absolute deviation and the standard
deviation without the sample farthest from the median (the MAD alone is 0 when a coarse ADC
reads one code in most samples), never below ``noise_floor_dps``. They need at least
``NOISE_TEST_MIN_SAMPLES`` samples. See docs/evaluation.md.

:class:`StartupWindow` is the one start-up calibration window: the daemon's pipeline, ``hdrd
calibrate`` and ``hdrd evaluate`` gather their standstill samples in it and measure through it.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.core.gyronoise import GyroNoise
from hdrd.errors import HdrdError

__all__ = [
    "T_BIAS_S",
    "BiasRecord",
    "MotionDetected",
    "CalibrationLimits",
    "StartupWindow",
    "estimate_bias",
    "given_bias",
    "noise_sigma",
]

T_BIAS_S = 30.0
"""Static bias averaging time Tbias, s (paper Sec. 2: "Tbias = 30 seconds")."""
SHIFT_INNER_SIGMAS = 4.0
"""Samples within this many noise sigmas of the median are the undisturbed core of a window
(the shift test compares their mean with the mean of all)."""
NOISE_TEST_MIN_SAMPLES = 6
"""The noise-scaled tests need this many samples: a window's own noise is too uncertain in
fewer (Gaussian noise alone would fail them 1 time in 100 with 5 samples, 1 in 4 with 3)."""


class MotionDetected(HdrdError, ValueError):
    """The calibration window does not look like standstill; the message says why."""


@dataclass(frozen=True, slots=True)
class CalibrationLimits:
    """Thresholds of the start-up calibration's standstill test, deg/s. A parked car with its
    engine running shows vibration well below these; any turn or a drive through a bend
    exceeds them."""

    max_std_dps: float = 0.5
    max_trend_dps: float = 0.2
    max_excursion_dps: float = 3.0
    max_bias_dps: float = 3.0
    max_shift_se: float = 4.0
    """Largest pull of the far samples on the mean, in standard errors of the mean (noise
    sigma / sqrt(samples)); 0 switches the noise-scaled tests off."""
    max_trend_se: float = 6.0
    """Largest first-vs-last-third trend, in standard errors of that difference."""
    noise_floor_dps: float = 0.01
    """Smallest noise sigma the noise-scaled tests assume, deg/s (a gyro quieter than this,
    or quantised to one code, is not held to a finer limit)."""
    trend_floor_dps: float = 0.02
    """The noise-scaled trend test never rejects a trend below this, deg/s (slow warm-up
    drift over a long window)."""


@dataclass(frozen=True, slots=True)
class BiasRecord:
    """A static bias measurement.

    bias_dps: eps0, mean raw rate at standstill, deg/s (+ = CCW). std_dps: sample standard
    deviation, deg/s. n: samples averaged. duration_s: device time spanned, s. temp_c: mean
    board temperature, deg C, or None if not fitted. time: when it was measured, UNIX s.
    noise: the gyro's error model the standstill showed (``hdrd calibrate`` records it;
    :func:`hdrd.core.gyronoise.measure_noise`), or None (not measured; older bias files).
    """

    bias_dps: float
    std_dps: float
    n: int
    duration_s: float
    temp_c: float | None = None
    time: float = 0.0
    noise: GyroNoise | None = None

    @classmethod
    def given(cls, bias_dps: float) -> BiasRecord:
        """The record of a bias given, not measured (``--bias``): n = 0, no spread known."""
        return cls(bias_dps, 0.0, 0, 0.0)

    def to_dict(self) -> dict[str, Any]:
        """The record as a bias file holds it (``noise``: its known parameters by name)."""
        d: dict[str, Any] = {f.name: getattr(self, f.name) for f in fields(self)}
        d.pop("noise")
        if self.noise is not None:
            d["noise"] = self.noise.to_dict()
        return d


def given_bias(bias_dps: float | None) -> BiasRecord | None:
    """The record of a bias given (:meth:`BiasRecord.given`), None for none (measure it)."""
    return None if bias_dps is None else BiasRecord.given(bias_dps)


def estimate_bias(
    omega_dps: npt.ArrayLike,
    t_s: npt.ArrayLike | None = None,
    *,
    temp_c: npt.ArrayLike | None = None,
    limits: CalibrationLimits = CalibrationLimits(),
    when: float = 0.0,
) -> BiasRecord:
    """Static bias eps0 from raw standstill samples (deg/s); raises MotionDetected on motion.

    t_s: sample times in seconds (for the duration); when absent, the duration is unknown
    and reported as 0. temp_c: board temperatures, deg C (NaN = unknown). when: the UNIX time
    to stamp the record with (the caller owns the clock).
    """
    w = np.asarray(omega_dps, dtype=np.float64)
    n = int(w.shape[0])
    if n < 2:
        raise MotionDetected(f"only {n} sample(s): at least 2 are needed to measure the bias")
    if not np.all(np.isfinite(w)):
        raise MotionDetected("non-finite samples in the calibration window")
    mean = float(np.mean(w))
    std = float(np.std(w, ddof=1))
    if std > limits.max_std_dps:
        raise MotionDetected(
            f"vehicle moved: rate spread {std:.3f} deg/s > {limits.max_std_dps} deg/s allowed"
        )
    third = max(n // 3, 1)
    trend = float(np.mean(w[-third:]) - np.mean(w[:third]))
    if abs(trend) > limits.max_trend_dps:
        raise MotionDetected(
            f"vehicle moved: rate trend {trend:+.3f} deg/s between the window's first and last "
            f"thirds > {limits.max_trend_dps} deg/s allowed"
        )
    excursion = float(np.max(np.abs(w - np.median(w))))
    if excursion > limits.max_excursion_dps:
        raise MotionDetected(
            f"vehicle moved: a sample {excursion:.2f} deg/s from the median "
            f"> {limits.max_excursion_dps} deg/s allowed"
        )
    if not abs(mean) <= limits.max_bias_dps:
        raise MotionDetected(
            f"mean rate {mean:+.3f} deg/s is beyond the +/-{limits.max_bias_dps:g} deg/s a "
            "bias can be (calibration.max_bias_dps): the vehicle is turning, or the sensor "
            "settings are wrong"
        )
    _check_noise_scaled(w, limits)
    duration = 0.0
    if t_s is not None:
        t = np.asarray(t_s, dtype=np.float64)
        duration = float(t[-1] - t[0]) if t.shape[0] else 0.0
    temp: float | None = None
    if temp_c is not None:
        tc = np.asarray(temp_c, dtype=np.float64)
        tc = tc[np.isfinite(tc)]
        temp = float(np.mean(tc)) if tc.shape[0] else None
    return BiasRecord(mean, std, n, duration, temp, when)


def noise_sigma(w: npt.NDArray[np.float64], floor_dps: float = 0.0) -> float:
    """Robust noise sigma of standstill samples (deg/s): the larger of 1.4826 x the median
    absolute deviation and the sample standard deviation without the sample farthest from the
    median, never below floor_dps. One bump (the first second of a turn at 1 Hz) does not
    inflate it, and, unlike the MAD alone, it is not 0 when most samples read one ADC code."""
    n = int(w.shape[0])
    dev = np.abs(w - np.median(w))
    mad_sigma = 1.4826 * float(np.median(dev))
    loo = 0.0
    if n > 2:
        loo = float(np.std(np.delete(w, int(np.argmax(dev))), ddof=1))
    return max(mad_sigma, loo, floor_dps)


def _check_noise_scaled(w: npt.NDArray[np.float64], limits: CalibrationLimits) -> None:
    """The shift and scaled-trend tests (module docstring); raises MotionDetected."""
    n = int(w.shape[0])
    if not limits.max_shift_se > 0 or n < NOISE_TEST_MIN_SAMPLES:
        return
    sigma = noise_sigma(w, limits.noise_floor_dps)
    med = float(np.median(w))
    core = w[np.abs(w - med) <= SHIFT_INNER_SIGMAS * sigma]
    mean = float(np.mean(w))
    shift = mean - float(np.mean(core)) if core.shape[0] else mean - med
    se = sigma / math.sqrt(n)
    if abs(shift) > limits.max_shift_se * se:
        raise MotionDetected(
            f"vehicle moved: {n - core.shape[0]} of {n} samples pull the mean by {shift:+.4f} "
            f"deg/s, {abs(shift) / se:.1f} standard errors (noise {sigma:.4f} deg/s) > "
            f"{limits.max_shift_se:g} allowed"
        )
    third = max(n // 3, 1)
    trend = float(np.mean(w[-third:]) - np.mean(w[:third]))
    se_trend = sigma * math.sqrt(2.0 / third)
    if abs(trend) > max(limits.max_trend_se * se_trend, limits.trend_floor_dps):
        raise MotionDetected(
            f"vehicle moved: rate trend {trend:+.4f} deg/s between the window's first and last "
            f"thirds, {abs(trend) / se_trend:.1f} standard errors (noise {sigma:.4f} deg/s) > "
            f"{limits.max_trend_se:g} allowed"
        )


class StartupWindow:
    """The start-up calibration window, one implementation for the daemon's pipeline,
    ``hdrd calibrate`` and ``hdrd evaluate``. Pure.

    It gathers the raw rates (deg/s, + = CCW) and temperatures (deg C, NaN = unknown) of
    consecutive samples while the vehicle should stand still, and measures them as one static
    bias (:func:`estimate_bias`). The owner says when a step of the window closed
    (:meth:`close_block`): after ``blocks`` closed steps the window is measured; samples that
    show motion empty it, and the samples that follow start a new attempt (the daemon keeps
    trying until the vehicle stands still). ``hdrd calibrate`` ends its window by device time
    instead and calls :meth:`measure` itself.

    Samples are kept as C doubles (``array('d')``: 8 bytes each, not a Python float's 32), so
    an hour of a fast gyro fits in ``hdrd calibrate``; :meth:`measure` hands them to numpy
    without a copy.
    """

    __slots__ = ("_omega", "_temp", "attempts", "block_s", "blocks", "closed", "limits")

    def __init__(
        self, blocks: int = 1, limits: CalibrationLimits = CalibrationLimits(), block_s: float = 0.0
    ) -> None:
        if blocks < 1:
            raise ValueError(f"a calibration window needs at least 1 step, got {blocks}")
        self.blocks = blocks
        self.block_s = block_s
        """Length of one step, s (the measured record's duration is blocks x block_s)."""
        self.limits = limits
        self.closed = 0
        """Steps of the current attempt closed so far."""
        self.attempts = 0
        """Measurements tried (accepted or rejected)."""
        self._omega: array[float] = array("d")
        self._temp: array[float] = array("d")

    @classmethod
    def for_seconds(
        cls, seconds: float, T: float, limits: CalibrationLimits = CalibrationLimits()
    ) -> StartupWindow:
        """A window of the whole steps of T s within ``seconds`` (rounded down: no sample past
        ``seconds`` is taken in), and at least one (a window shorter than a step is one
        step: the configured ``calibration.startup_s`` of 1 s with hdr.T = 2 s)."""
        return cls(max(1, math.floor(seconds / T + 1e-9)), limits, T)

    @property
    def n(self) -> int:
        """Samples gathered in the current attempt."""
        return len(self._omega)

    @property
    def omega_dps(self) -> npt.NDArray[np.float64]:
        """The raw rates gathered in the current attempt, deg/s: a numpy view of the window's
        storage, no copy (drop it before adding more: a lent buffer cannot grow)."""
        return np.frombuffer(self._omega, dtype=np.float64)

    @property
    def mean_dps(self) -> float:
        """Mean of the samples gathered so far, deg/s (NaN before the first): their sum in
        order over their count (``hdrd calibrate``'s progress lines)."""
        return sum(self._omega) / len(self._omega) if self._omega else math.nan

    def add(self, omega_dps: float, temp_c: float | None = None) -> None:
        """One sample of the window."""
        self._omega.append(omega_dps)
        self._temp.append(math.nan if temp_c is None else temp_c)

    def add_many(self, omega_dps: npt.ArrayLike, temp_c: npt.ArrayLike | None = None) -> None:
        """Samples in order, as :meth:`add` one by one (temp_c NaN = unknown)."""
        w = np.ascontiguousarray(omega_dps, dtype=np.float64)
        self._omega.frombytes(w.tobytes())
        if temp_c is None:
            self._temp.frombytes(np.full(w.shape[0], math.nan).tobytes())
        else:
            self._temp.frombytes(np.ascontiguousarray(temp_c, dtype=np.float64).tobytes())

    def clear(self) -> None:
        """Start again: no samples, no closed steps (a contiguous window was broken)."""
        # New arrays, not emptied ones: a failed measure's exception may still hold a numpy
        # view of the old ones (an array lending its buffer cannot be resized).
        self._omega = array("d")
        self._temp = array("d")
        self.closed = 0

    def measure(self, when: float = 0.0) -> BiasRecord:
        """The bias of the samples gathered (duration: the closed steps times block_s).
        Raises MotionDetected (the window is left as it is)."""
        self.attempts += 1
        rec = estimate_bias(
            self.omega_dps,
            temp_c=np.frombuffer(self._temp, dtype=np.float64),
            limits=self.limits,
            when=when,
        )
        return replace(rec, duration_s=self.blocks * self.block_s)

    def close_block(self) -> BiasRecord | None:
        """A step of the window closed (its samples were added). None until ``blocks`` steps
        closed; then the measured bias, the window emptied. MotionDetected if the samples
        show motion, the window emptied for a new attempt."""
        self.closed += 1
        if self.closed < self.blocks:
            return None
        try:
            rec = self.measure()
        except MotionDetected:
            self.clear()
            raise
        self.clear()
        return rec
