"""The Silicon Sensing CRS03-04 rate gyro read through an ADC: counts <-> deg/s.

Pure. The CRS03-04 (shared/paper/HDR-NOTES.md, "The sensor"; paper Table I) outputs a
voltage centred on half its supply (2.5 V at 5 V) with 10 mV per deg/s, ratiometric to the
supply, over +/-200 deg/s. Read by a unipolar ADC with reference ``vref_v``::

    volts = counts * vref_v / 2**adc_bits
    omega = polarity * (volts - null_v * k) / (scale_v_per_dps * k)      deg/s, + = CCW

where k = supply / supply_nominal_v when a supply-monitor channel is wired (ref counts > 0;
supply = ref_counts * vref_v / 2**adc_bits * ref_divider) and k = 1 otherwise. Polarity +1
means the gyro's positive output is counter-clockwise seen from above (a left turn); use -1
for a gyro mounted upside down.

What the gyro cannot have given is not a rate (:meth:`SensorModel.supply_faults`,
:meth:`SensorModel.saturated`): a supply reading outside the CRS03-04's specified 5 V +/- 5 %
(4.75 .. 5.25 V, docs/firmware.md, "Supply") makes k, and so the
rate, wrong by 250 deg/s per unit of ratio (a divider that opens reads the ADC's rail, "10 V":
-125 deg/s for a still gyro); so does a reading that jumps by more than ``supply_max_step_v``
from one sample to the next, which a supply with its decoupling does not do (the reading's
own noise is about 1.4 mV, docs/firmware.md); and a rate beyond ``range_dps`` or at an ADC
rail is outside what the gyro measures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["SensorModel"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True, slots=True)
class SensorModel:
    """ADC and gyro constants; defaults are the CRS03-04 on a 16-bit, 5 V unipolar ADC."""

    adc_bits: int = 16
    """ADC resolution, bits (counts 0 .. 2**adc_bits - 1)."""
    vref_v: float = 5.0
    """ADC full-scale reference, V."""
    null_v: float = 2.5
    """Gyro output at zero rate at the nominal supply, V (CRS03-04: half of 5 V)."""
    scale_v_per_dps: float = 0.010
    """Scale factor at the nominal supply, V per deg/s (CRS03-04: 10 mV/(deg/s))."""
    polarity: int = 1
    """+1: positive output = counter-clockwise (left turn); -1: mounted upside down."""
    range_dps: float = 200.0
    """Specified measurement range, +/- deg/s; beyond it a sample is flagged saturated (and is
    not a rate)."""
    ref_divider: float = 2.0
    """Divider ratio in front of the supply-monitor ADC channel (supply = ref volts * this)."""
    supply_nominal_v: float = 5.0
    """Supply voltage at which null_v and scale_v_per_dps hold, V."""
    supply_tolerance: float = 0.05
    """The supply the gyro is specified for, as a share of supply_nominal_v either side
    (CRS03-04: 5 V +/- 5 %, 4.75 .. 5.25 V); a supply-monitor reading outside it is a fault,
    not a supply."""
    supply_max_step_v: float = 0.1
    """Largest change of the supply-monitor reading from one sample to the next, V; a larger
    jump is a fault (a loose divider), not a supply (70 times the reading's noise)."""

    @property
    def full_scale(self) -> int:
        """Largest ADC count."""
        return (1 << self.adc_bits) - 1

    @property
    def supply_min_v(self) -> float:
        """Lowest supply the gyro is specified for, V."""
        return self.supply_nominal_v * (1.0 - self.supply_tolerance)

    @property
    def supply_max_v(self) -> float:
        """Highest supply the gyro is specified for, V."""
        return self.supply_nominal_v * (1.0 + self.supply_tolerance)

    @property
    def lsb_dps(self) -> float:
        """One ADC count in deg/s at the nominal supply (quantisation step)."""
        return self.vref_v / (1 << self.adc_bits) / self.scale_v_per_dps

    def supply_v(self, ref_counts: npt.ArrayLike) -> FloatArray | float:
        """Supply voltage from the supply-monitor counts, V (nominal where not wired, ref = 0)."""
        ref = np.asarray(ref_counts, dtype=np.float64)
        v = np.where(
            ref > 0,
            ref * self.vref_v / (1 << self.adc_bits) * self.ref_divider,
            self.supply_nominal_v,
        )
        return float(v) if v.ndim == 0 else v

    def supply_reading_scalar(self, ref_counts: int) -> float:
        """The supply the monitor reads, V; NaN when it is not wired (ref 0). Same operations
        in the same order as :meth:`supply_readings`, so bit-identical to it."""
        if ref_counts > 0:
            return ref_counts * self.vref_v / (1 << self.adc_bits) * self.ref_divider
        return math.nan

    def supply_readings(self, ref_counts: npt.ArrayLike) -> FloatArray:
        """:meth:`supply_reading_scalar` over an array."""
        ref = np.asarray(ref_counts, dtype=np.float64)
        v = ref * self.vref_v / (1 << self.adc_bits) * self.ref_divider
        return np.where(ref > 0, v, math.nan)

    def supply_fault_scalar(self, reading_v: float, before_v: float) -> bool:
        """A sample's supply reading (V, NaN: not wired) is a fault: outside
        [supply_min_v, supply_max_v], or more than supply_max_step_v from the reading of the
        sample before (``before_v``; NaN: none, or not wired)."""
        if reading_v != reading_v:
            return False
        return (
            not self.supply_min_v <= reading_v <= self.supply_max_v
            or abs(reading_v - before_v) > self.supply_max_step_v
        )

    def supply_faults(self, readings_v: FloatArray, before_v: float = math.nan) -> BoolArray:
        """:meth:`supply_fault_scalar` of consecutive samples' readings (``before_v``: the
        reading of the sample before the first)."""
        v = np.asarray(readings_v, dtype=np.float64)
        prev = np.empty_like(v)
        prev[:1] = before_v
        prev[1:] = v[:-1]
        wired = ~np.isnan(v)
        with np.errstate(invalid="ignore"):
            out_of_range = (v < self.supply_min_v) | (v > self.supply_max_v)
            jump = np.abs(v - prev) > self.supply_max_step_v
        return wired & (out_of_range | jump)

    def to_dps_scalar(self, rate_counts: int, ref_counts: int = 0) -> float:
        """Yaw rate in deg/s (+ = CCW) of one sample, from ADC counts (ref_counts 0: the supply
        is not monitored), in plain floats (the live daemon's hot path).

        Same operations in the same order as :meth:`to_dps_array`, so bit-identical to it.
        """
        scale = 1 << self.adc_bits
        volts = rate_counts * self.vref_v / scale
        if ref_counts > 0:
            k = ref_counts * self.vref_v / scale * self.ref_divider / self.supply_nominal_v
        else:
            k = self.supply_nominal_v / self.supply_nominal_v
        return self.polarity * (volts - self.null_v * k) / (self.scale_v_per_dps * k)

    def to_dps_array(self, rate_counts: npt.ArrayLike, ref_counts: npt.ArrayLike) -> FloatArray:
        """:meth:`to_dps_scalar` over arrays (whole captures), bit-identical to it."""
        scale = 1 << self.adc_bits
        rate = np.asarray(rate_counts, dtype=np.float64)
        ref = np.asarray(ref_counts, dtype=np.float64)
        volts = rate * self.vref_v / scale
        k = np.where(
            ref > 0,
            ref * self.vref_v / scale * self.ref_divider / self.supply_nominal_v,
            self.supply_nominal_v / self.supply_nominal_v,
        )
        return self.polarity * (volts - self.null_v * k) / (self.scale_v_per_dps * k)

    def saturated_scalar(self, rate_counts: int, omega_dps: float) -> bool:
        """:meth:`saturated` for one sample."""
        return (
            rate_counts <= 0 or rate_counts >= self.full_scale or abs(omega_dps) >= self.range_dps
        )

    def to_counts(
        self, omega_dps: npt.ArrayLike, supply_v: float | None = None
    ) -> npt.NDArray[np.int64]:
        """ADC counts a yaw rate produces (rounded, clipped to the ADC's rails): the inverse of
        :meth:`to_dps_scalar`."""
        k = (self.supply_nominal_v if supply_v is None else supply_v) / self.supply_nominal_v
        omega = np.asarray(omega_dps, dtype=np.float64)
        volts = self.null_v * k + self.polarity * omega * self.scale_v_per_dps * k
        counts = np.rint(volts * (1 << self.adc_bits) / self.vref_v)
        return np.clip(counts, 0, self.full_scale).astype(np.int64)

    def ref_counts_for(self, supply_v: float) -> int:
        """Supply-monitor counts that a given supply voltage produces (for encoders and fakes)."""
        counts = round(supply_v / self.ref_divider * (1 << self.adc_bits) / self.vref_v)
        return int(min(max(counts, 1), self.full_scale))

    def saturated(
        self, rate_counts: npt.ArrayLike, omega_dps: npt.ArrayLike
    ) -> npt.NDArray[np.bool_] | bool:
        """True where a sample is at an ADC rail or beyond the gyro's specified range."""
        c = np.asarray(rate_counts)
        w = np.asarray(omega_dps, dtype=np.float64)
        sat = (c <= 0) | (c >= self.full_scale) | (np.abs(w) >= self.range_dps)
        return bool(sat) if sat.ndim == 0 else sat
