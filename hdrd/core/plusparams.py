"""HDR+'s settings: the hypotheses of its bank, the road and the stops it measures by, and
what one unit's error model and start-up calibration set. The estimator is
:mod:`hdrd.core.hdrplus`; :meth:`PlusParams.fitted` is the one place settings follow from what
is known of the unit. Pure.

Units: rates deg/s, + = counter-clockwise seen from above; variances (deg/s)^2; random walks
(deg/s)^2/s; heading deg; temperature degC; time s. A *motion offset* is the driving bias
minus the bias at rest (what a stop reads), deg/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Any

from hdrd.core.gyronoise import GyroNoise
from hdrd.core.standstill import CalibrationNoise, StopDetection

__all__ = [
    "DEFAULTS",
    "FRESH_BANK",
    "Hypothesis",
    "PlusParams",
    "ROAD_MODEL",
    "Road",
    "unit_bank",
]


@dataclass(frozen=True, slots=True)
class Hypothesis:
    """One member of the bank: a kind of unit. ``drift_q``: its driving bias's random walk,
    (deg/s)^2/s; ``offset_dps`` and ``offset_sd_dps``: the prior mean and sd of its motion
    offset (driving minus rest), deg/s. Two probabilities at start, each in (0, 1]:
    ``prior``, the weight the correction in force starts from (a unit is taken for steady
    until the evidence shows otherwise: a correction that harms a good unit is worse than
    one that misses an offset), and ``share``, how common such units are, which the published
    uncertainty starts from (the heading's sd must hold for the units there are)."""

    name: str
    prior: float
    drift_q: float = 1e-9
    offset_dps: float = 0.0
    offset_sd_dps: float = 0.0015
    share: float = math.nan
    """NaN: the same as ``prior``."""
    drift_tau_s: float = math.inf
    """The driving bias's wander is mean-reverting with this correlation time, s (a Gauss-Markov
    process of variance drift_q x drift_tau_s / 2 about the member's offset: a bias wanders
    within bounds); inf: a random walk."""

    def __post_init__(self) -> None:
        if not (0.0 < self.prior <= 1.0):
            raise ValueError(f"hypothesis {self.name}: prior must be in (0, 1], got {self.prior!r}")
        if math.isnan(self.share):
            object.__setattr__(self, "share", self.prior)
        if not (0.0 < self.share <= 1.0):
            raise ValueError(f"hypothesis {self.name}: share must be in (0, 1], got {self.share!r}")
        if not self.drift_tau_s > 0.0:
            raise ValueError(
                f"hypothesis {self.name}: drift_tau_s must be > 0, got {self.drift_tau_s!r}"
            )
        for name in ("drift_q", "offset_sd_dps"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"hypothesis {self.name}: {name} must be >= 0, got {v!r}")
        if not math.isfinite(self.offset_dps):
            raise ValueError(f"hypothesis {self.name}: offset_dps must be finite")


FRESH_BANK: tuple[Hypothesis, ...] = (
    Hypothesis("steady", 0.93, share=0.4),
    Hypothesis("offset", 0.02, offset_sd_dps=0.05, share=0.4),
    Hypothesis("drifting", 0.05, drift_q=1e-5, offset_sd_dps=0.02, share=0.2),
)
"""The bank of a unit nothing is known of: its driving bias is what a stop reads and stays
there (*steady*); or it differs from the rest bias by a constant motion offset of up to
~0.1 deg/s (*offset*: real MEMS units, -0.09 .. 0 deg/s); or it wanders (*drifting*: a
warm-up, a phone). Steady is the default; the others need the evidence of the road and the
stops. bench/RESULTS.md says which data chose these numbers."""


PROFILE_OFFSET_SD_DPS = 0.02
"""How far a unit's motion offset may differ from one drive to the next, deg/s (1 sigma,
beside the profile's own standard error): a profile is learned on an earlier drive, whose
warm-up and stops added to what it read. Chosen on the tuning units (bench/unit_profile.py)."""


def unit_bank(
    noise: GyroNoise, fresh: tuple[Hypothesis, ...] = FRESH_BANK
) -> tuple[Hypothesis, ...]:
    """The bank of a unit whose profile says something (a grade, the configuration's ``gyro.*``
    keys, a recorded or learned profile): the fresh bank with what is known put in. A known
    motion offset becomes every member's mean, and the steady member's sd is the profile's;
    a known random walk becomes the steady and offset members' (the drifting member stays:
    a profile from one drive does not rule a warm-up out). The offset member keeps its wide
    sd, and its prior, so that an offset the profile got wrong can still show."""
    q = noise.tracked_q_no_temp()
    m = noise.motion_offset_dps
    sd = noise.motion_offset_sd_dps
    out = []
    for h in fresh:
        kw: dict[str, Any] = {}
        if math.isfinite(m):
            kw["offset_dps"] = m
            if h is fresh[0]:
                own = sd if math.isfinite(sd) else 0.01
                kw["offset_sd_dps"] = math.hypot(own, PROFILE_OFFSET_SD_DPS)
        if math.isfinite(q) and h.drift_q <= fresh[0].drift_q * 10.0:
            kw["drift_q"] = q
        out.append(replace(h, **kw) if kw else h)
    return tuple(out)


@dataclass(frozen=True, slots=True)
class Road:
    """What a step of driving that is not a stop says of the driving bias: the road's yaw rate
    is a Gauss-Markov process of ``sd_dps`` and ``tau_s`` (gentle curves), plus ``sway_var``
    of white noise per step, (deg/s)^2 (steering, the body's sway), on a step that is straight
    (probability ``p_straight``); a curve adds ``curve_var``, (deg/s)^2. The heading roads
    curve is thus never forced to zero: a step whose rate is far from the bias counts for
    little."""

    sd_dps: float = 0.01
    tau_s: float = 60.0
    sway_var: float = 0.04
    p_straight: float = 0.6
    curve_var: float = 4.0

    def __post_init__(self) -> None:
        _check(self)
        if not 0.0 < self.p_straight <= 1.0:
            raise ValueError(f"p_straight must be in (0, 1], got {self.p_straight!r}")


def _check(obj: object, nan_ok: tuple[str, ...] = ()) -> None:
    """Every number of a frozen record finite and >= 0 (those in nan_ok may be NaN)."""
    for f in fields(obj):  # type: ignore[arg-type]
        v = getattr(obj, f.name)
        if not isinstance(v, float | int) or isinstance(v, bool):
            continue
        v = float(v)
        if f.name in nan_ok and math.isnan(v):
            continue
        if not (math.isfinite(v) and v >= 0.0):
            raise ValueError(f"{f.name} must be a number >= 0, got {getattr(obj, f.name)!r}")
        object.__setattr__(obj, f.name, v)


EVIDENCE_WEIGHT = 0.6
"""How much one step's measurements count as evidence between the members (a tempered
likelihood): the road's sway and a stop's noise are correlated over several steps, which a
filter that takes each step as independent would count many times over, in favour of
whichever member predicts most loosely. Tuned (bench/RESULTS.md)."""
SWITCH_P = 1e-6
"""Probability per step that the unit turns out to be of another kind: a Markov transition
between the members, so that no member's probability is ever stuck at 0."""
ROAD_MODEL = Road()
"""The road the straight-road measurement assumes. Tuned (bench/RESULTS.md)."""
STOP_FLOOR_DPS = 0.01
"""No step at a stop is trusted to better than this, deg/s (1 sigma): the samples of a
band-limited gyro, and a stop's vibration, are correlated within a step."""
TURN_ERR = 0.02
"""The heading error a turn adds, as a share of the angle turned (1 sigma: a scale factor's
error; a CRS03-04's is within 3 %). Tuned on the tuning sets' outages (bench/RESULTS.md)."""
STOP_GATE_SIGMA = 4.0
"""A stop's corrected level must be within this many sd of what the bank allows at rest: a
turn that a stale speed calls standstill is not taken for the bias."""
GATE_FLOOR_DPS = 0.03
"""The stop gate allows at least this much bias error, deg/s."""


@dataclass(frozen=True, slots=True)
class PlusParams:
    """HDR+'s settings (module docstring). The defaults are a CRS03-04's before any fit."""

    T: float = 1.0
    """Step period, s."""
    bank: tuple[Hypothesis, ...] = FRESH_BANK
    """The hypotheses."""
    standstill: StopDetection = field(default_factory=StopDetection)
    """Standstill detection; a stop is a zero-rate update."""
    stop_scatter_dps: float = 0.01
    """How far a later stop may read from the calibration's rest bias, deg/s (1 sigma, each
    stop its own: idling, a slope, the engine's vibration)."""
    bias_p0: float = 4e-4
    """Variance of the start-up bias eps0, (deg/s)^2: the calibration's sample variance /
    samples; without a calibration (a bias given, ``--bias``), (0.02 deg/s)^2, a bias of
    unknown age."""
    block_var: float = math.nan
    """Variance of one step's mean at standstill, (deg/s)^2 (the calibration's; NaN unknown:
    each step's own spread stands for it)."""
    quant_var: float = 4.9e-6
    """Variance of what the rest readings miss of the bias by the output's rounding,
    (deg/s)^2: q^2/12 for a unit that sits on one code at rest (undithered), about 0 when its
    noise dithers it."""
    temp_coeff_sd: float = 0.002
    """Prior sd of the bias's temperature coefficient, deg/s/degC, while a temperature is
    logged (0: not estimated). Small: a cabin's warm-up is monotonic, and a wide prior lets the
    road's curvature pass for a temperature coefficient on a good gyro."""
    heading_q: float = 0.0
    """A wander of the bias too fast to follow (correlation time within a couple of minutes),
    as the heading's random walk, deg^2/s."""
    measure: bool = True
    """False: no stop or road measurement, the yaw integrates every step (the ``frozen``
    outage policy, :mod:`hdrd.core.selfcheck`: the driving bias the courses taught, held)."""
    model: str = "defaults"
    """Which error model the settings were fitted to (published as ``model``):
    ``defaults``, ``calibration``, or the known model's source (``grade NAME``, ``config``,
    ``recorded``, ``learned``)."""

    def __post_init__(self) -> None:
        if not self.bank:
            raise ValueError("the bank needs at least one hypothesis")
        object.__setattr__(self, "bank", tuple(self.bank))
        _check(self, nan_ok=("block_var",))
        if not self.T > 0.0:
            raise ValueError(f"T must be > 0, got {self.T!r}")

    def with_(self, **kw: object) -> PlusParams:
        """A copy with some fields replaced."""
        return replace(self, **kw)  # type: ignore[arg-type]

    def fitted(
        self,
        calibration: CalibrationNoise | None = None,
        noise: GyroNoise | None = None,
        quant_step_dps: float | None = None,
    ) -> PlusParams:
        """These settings fitted to one unit and its start-up calibration.

        calibration (:func:`hdrd.core.standstill.calibration_noise`, or a record's): samples
        per step, a step's variance at rest, var(eps0), and whether the window sat on one or
        two codes (undithered: the rest bias is then known to the output step only). noise:
        the unit's error model when known (a grade, ``gyro.*``, a recorded or learned
        profile): the bank of :func:`unit_bank`, the fast wander as heading noise, the prior on
        the temperature coefficient, the stop scatter. quant_step_dps: the output step when
        known otherwise (the ADC's LSB; a log's lattice)."""
        p = self
        q = _output_step(quant_step_dps, calibration, noise)
        if calibration is not None:
            p = p._with_calibration(calibration, q)
        elif math.isfinite(q):
            p = p.with_(quant_var=q * q / 12.0)
        if noise is not None:
            p = p._with_noise(noise)
        return p

    def _with_calibration(self, cal: CalibrationNoise, q: float) -> PlusParams:
        ss = replace(self.standstill, samples_per_step=max(1.0, cal.samples_per_step))
        p = self.with_(standstill=ss, model="calibration")
        if math.isfinite(cal.block_var) and cal.block_var >= 0.0:
            p = p.with_(block_var=cal.block_var)
        if math.isfinite(cal.bias_var) and cal.bias_var >= 0.0:
            p = p.with_(bias_p0=cal.bias_var)
        if math.isfinite(q):
            undithered = 0 < cal.codes <= 2 or cal.bias_var == 0.0
            p = p.with_(quant_var=q * q / 12.0 if undithered else 0.0)
        return p

    def _with_noise(self, noise: GyroNoise) -> PlusParams:
        p = self.with_(model=noise.source)
        if noise.known() or math.isfinite(noise.motion_offset_dps):
            p = p.with_(bank=unit_bank(noise))
        wander = noise.fast_wander_q()
        if math.isfinite(wander):
            p = p.with_(heading_q=wander)
        if math.isfinite(noise.temp_coeff_dps_per_c):
            p = p.with_(temp_coeff_sd=max(noise.temp_coeff_dps_per_c, 1e-5))
        if math.isfinite(noise.stop_scatter_dps):
            p = p.with_(stop_scatter_dps=noise.stop_scatter_dps)
        return p


def _output_step(
    given: float | None, calibration: CalibrationNoise | None, noise: GyroNoise | None
) -> float:
    """The output step q, deg/s: the one given, else the calibration's, else the noise
    model's; NaN when none is known."""
    for cand in (
        given,
        calibration.quant_step_dps if calibration is not None else None,
        noise.quant_step_dps if noise is not None else None,
    ):
        if cand is not None and math.isfinite(cand) and cand > 0:
            return float(cand)
    return math.nan


DEFAULTS = PlusParams()
"""HDR+'s settings before any fit."""
