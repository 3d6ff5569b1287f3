"""Configuration's shape: its sections as frozen dataclasses, their defaults, and the drift
reducer's setup a configuration asks for.

Defaults are the paper's (Table III, Tbias = 30 s, T = 1 s; see :mod:`hdrd.core.hdr` and
:mod:`hdrd.core.calibrate`) and the CRS03-04's (:mod:`hdrd.core.sensor`); ``config/hdrd.yaml``
ships them with comments, and a test keeps that file and these defaults equal. Reading and
checking a file is :mod:`hdrd.configload`'s; an invalid value raises :class:`ConfigError`,
whose one-line message names the key, the value and what is allowed; the CLI turns it into exit
status 78 (:data:`hdrd.errors.EX_CONFIG`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hdrd.core import methods
from hdrd.core.calibrate import T_BIAS_S, BiasRecord
from hdrd.core.gyronoise import GyroNoise
from hdrd.core.hdr import HdrParams
from hdrd.core.sensor import SensorModel
from hdrd.errors import HdrdError, clipped
from hdrd.io.net.gpsd import DEFAULT_HOST, DEFAULT_PORT
from hdrd.io.wire.protocol import NMEA_TALKER

__all__ = [
    "CalibrationConfig",
    "Config",
    "ConfigError",
    "DeviceConfig",
    "GpsdConfig",
    "LogConfig",
    "OutputConfig",
    "SimulateConfig",
    "StandstillConfig",
    "method_setup",
]


FILE_KEYS = ("(file)", "(yaml)")
"""A :class:`ConfigError`'s key for the file as a whole: ``(file)`` (missing, unreadable, empty,
not a mapping; ``allowed`` says so in words), ``(yaml)`` (its YAML; the value is "line L,
column C")."""


class ConfigError(HdrdError, ValueError):
    """An invalid configuration. ``str()`` is the one line shown to the user."""

    def __init__(self, key: str, value: Any, allowed: str, source: str | None = None) -> None:
        self.key, self.value, self.allowed, self.source = key, value, allowed, source
        where = f" in {source}" if source else ""
        if key in FILE_KEYS:  # the file as a whole, not a key of it: no "key = value"
            at = f", {value}" if key == "(yaml)" and value else ""
            super().__init__(f"config error{where}{at}: {allowed}")
            return
        shown = shown_value(value)
        # One line always: a key or a value read from YAML may hold line breaks.
        name = key if key.isprintable() else repr(key)
        name = clipped(name, 80)  # a key of any length: one line
        super().__init__(f"config error{where}: {name} = {shown}: {allowed}")

    def with_source(self, source: str) -> ConfigError:
        return ConfigError(self.key, self.value, self.allowed, source)


def shown_value(value: Any) -> str:
    """A value as an error message shows it: one printable line of at most 60 characters."""
    if isinstance(value, (str, float)):
        text = repr(value)
    else:
        import yaml

        try:
            text = yaml.safe_dump(value, default_flow_style=True, width=1 << 30).strip()
            text = text.removesuffix("...").strip()
        except yaml.YAMLError:
            text = repr(value)
        if not text.isprintable():  # a quoted scalar folded over lines
            text = repr(value)
    return clipped(text, 60)


# -- sections ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class DeviceConfig:
    """Where the gyro's ADC is and how it talks."""

    port: str = "/dev/hdrd-gyro"
    """pyserial URL or device path (the udev rule in systemd/ makes /dev/hdrd-gyro)."""
    protocol: str = "hdr-bin"
    baud: int = 115200
    reconnect_min_s: float = 0.5
    """First wait before reopening a lost device, s; doubles up to reconnect_max_s."""
    reconnect_max_s: float = 10.0
    stale_after_s: float = 3.0
    """No sample kept (or no step) for this long (wall clock) -> status "stale", s."""
    clock_rate: float = 1.0
    """Device seconds per wall-clock second the device's clock keeps: 1 for the gyro; N for a
    feed N times real time (``hdrd fakegyro --speedup N``); 0: the device clock is not checked
    against the wall clock (a feed as fast as it is read). A frame whose clock disagrees is
    dropped (docs/protocol.md, "Sequence and clock")."""


@dataclass(frozen=True, slots=True)
class HdrConfig:
    """Drift reduction: the method and the HDR parameters (paper Table III defaults)."""

    method: str = "hdr"
    """none: static bias only; hdr: the paper's HDR; hdr+: hdrd's improved reducer."""
    i_c_auto: bool = True
    """``hdr.i_c: auto`` (the default): Table III's increment, or with the gyro's error model
    known (``gyro.*``, a recorded bias file) what its bias drifts in I_C_WINDOW_S if that is
    less (a good gyro's I moves less); ``hdr.i_c: NUMBER``: that increment whatever the gyro
    (then ``params.i_c``)."""
    params: HdrParams = HdrParams()


@dataclass(frozen=True, slots=True)
class CalibrationConfig:
    """Static bias eps0 (paper Sec. 2)."""

    bias_file: str = ""
    """Bias file from `hdrd calibrate`; empty = $STATE_DIRECTORY/bias.yaml or
    /var/lib/hdrd/bias.yaml."""
    t_bias_s: float = T_BIAS_S
    """`hdrd calibrate` averaging time, s (paper: Tbias = 30 s)."""
    startup_s: float = 1.0
    """With no bias file, the daemon averages this long at start, s (paper Sec. 6: 1 s)."""
    on_bad_bias_file: str = "error"
    """error: refuse to start on a corrupt bias file; calibrate: measure at start instead."""
    max_std_dps: float = 0.5
    max_trend_dps: float = 0.2
    max_excursion_dps: float = 3.0
    max_bias_dps: float = 3.0
    """Largest |bias| believed, deg/s: a measurement (`hdrd calibrate`, start-up), a bias
    file or --bias beyond it is refused. The CRS03-04's bias stays within +/-3 deg/s over
    -40..85 degC (docs/gyro-model.md); the paper measured 1.432 deg/s on its unit."""
    no_data_timeout_s: float = 10.0
    """`hdrd calibrate` gives up when no frame has arrived for this long, s (wall clock)."""


@dataclass(frozen=True, slots=True)
class OutputConfig:
    """Publishers."""

    heading0_deg: float = 0.0
    """Compass heading at start, deg; heading = (heading0 - yaw) mod 360."""
    stdout: bool = False
    udp: tuple[str, ...] = ()
    """HOST:PORT destinations of JSON lines."""
    nmea_udp: tuple[str, ...] = ()
    """HOST:PORT destinations of NMEA 0183 ($HNHDT, $HNROT)."""
    nmea_ths: bool = False
    """Also send $HNTHS."""
    nmea_talker: str = NMEA_TALKER
    """NMEA talker ID, two capital letters: HN (heading, non-north-seeking gyro: what hdrd
    is, and what chart plotters are told); gpsd drops HN, so for gpsd use II (integrated
    instrumentation; docs/protocol.md, "NMEA 0183 and gpsd")."""


@dataclass(frozen=True, slots=True)
class LogConfig:
    level: str = "info"
    format: str = "auto"
    """auto: JSON when stderr is not a terminal, console otherwise."""
    bad_frame_interval_s: float = 10.0
    """At most one bad-frames log event per this many seconds."""


@dataclass(frozen=True, slots=True)
class SimulateConfig:
    """The built-in simulated gyro (`hdrd run --simulate`)."""

    drive: str = "mixed"
    seed: int = 1
    rate_hz: float = 10.0
    """Sample rate of the simulated ADC, Hz (paper: 10 Hz)."""
    speedup: float = 1.0
    """1 = real time; larger plays the drive faster."""
    grade: str = "crs03"
    """The simulated gyro's grade preset (:mod:`hdrd.core.grades`, docs/gyro-model.md)."""


@dataclass(frozen=True, slots=True)
class GpsdConfig:
    """Optional GPS aiding through gpsd's JSON protocol."""

    enabled: bool = False
    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    min_speed_mps: float = 5.0
    """Course from GPS is trusted above this speed, m/s."""
    max_fix_age_s: float = 2.5
    """A fix older than this, s since it arrived, is stale (two missed 1 Hz fixes); at most
    :data:`hdrd.configload.MAX_FIX_AGE_S`."""
    max_epd_deg: float = 15.0
    """Course error estimate (gpsd's epd, 95 %) above which the course is not used, deg."""
    align_gain: float = 0.2
    """Share of the heading error (hdrd - GPS course) removed per step while aided, 0 .. 1."""
    bias_window_s: float = 20.0
    """Straight-driving window over which GPS makes one bias estimate, s."""
    bias_gain: float = 0.3
    """Share of a window's bias estimate applied, 0 .. 1."""
    device: str = ""
    """The GPS receiver to follow, as gpsd names it (TPV ``device``, e.g. /dev/ttyUSB0);
    empty: the first that reports a fix."""


@dataclass(frozen=True, slots=True)
class StandstillConfig:
    """HDR+'s standstill re-calibration (zero-rate updates, :mod:`hdrd.core.standstill`)."""

    enabled: bool = True
    """Use stops: publish omega 0 and re-measure the bias while the vehicle stands still."""
    from_gyro: bool = False
    """With no speed source (gpsd), detect a stop from the gyro's own statistics; off by
    default: a gyro alone cannot tell a stop from a smooth straight road (bench/RESULTS.md)."""


@dataclass(frozen=True, slots=True)
class GyroConfig:
    """The gyro's error model, when it is known (docs/gyro-model.md): a grade preset, and/or
    measured parameters (0 = not given). HDR+ is fitted to it (docs/hdrplus.md) and paper
    HDR's ``hdr.i_c: auto`` follows its drift (docs/hdr.md). Noise parameters that ``hdrd
    calibrate`` recorded in the bias file take precedence when they say how the bias moves."""

    grade: str = "none"
    """A grade preset (:mod:`hdrd.core.grades`), or ``none``."""
    white_dps_per_rthz: float = 0.0
    """White rate noise N, deg/s/sqrt(Hz)."""
    bias_instability_dps: float = 0.0
    """Bias instability B (the Allan floor), deg/s."""
    bias_tau_s: float = 100.0
    """Its correlation time, s."""
    rrw_dps_per_sqrt_s: float = 0.0
    """Rate random walk K, deg/s/sqrt(s)."""
    temp_coeff_dps_per_c: float = 0.0
    """Bias temperature coefficient, deg/s/degC."""
    quant_step_dps: float = 0.0
    """Output step, deg/s."""
    motion_offset_dps: float = 0.0
    """The unit's motion offset: its driving bias minus its bias at rest, deg/s (signed); used
    only with ``motion_offset_sd_dps`` > 0 (``hdrd gap --gyro-out`` writes both)."""
    motion_offset_sd_dps: float = 0.0
    """How well the motion offset is known, deg/s (1 sigma); 0: no offset given."""
    stop_scatter_dps: float = 0.0
    """How far one stop reads from another, deg/s (1 sigma); 0: not given."""


@dataclass(frozen=True, slots=True)
class Config:
    device: DeviceConfig = DeviceConfig()
    sensor: SensorModel = SensorModel()
    hdr: HdrConfig = HdrConfig()
    calibration: CalibrationConfig = CalibrationConfig()
    output: OutputConfig = OutputConfig()
    log: LogConfig = LogConfig()
    simulate: SimulateConfig = SimulateConfig()
    gpsd: GpsdConfig = GpsdConfig()
    standstill: StandstillConfig = StandstillConfig()
    gyro: GyroConfig = GyroConfig()


def method_setup(
    cfg: Config, bias: BiasRecord | None = None, learned: GyroNoise | None = None
) -> methods.MethodSetup:
    """The drift reducer's setup a configuration asks for (:class:`hdrd.core.methods.
    MethodSetup`): ``hdr.method`` and ``hdr.*``, the gyro's error model (``gyro.grade`` and
    the ``gyro.*`` noise parameters), ``standstill.*``, and the static bias of ``bias`` (a
    bias file's record, a given one's: :meth:`hdrd.core.calibrate.BiasRecord.given`; None:
    measured at start-up), and what the unit's trips taught (``learned``: the daemon's unit
    state file, :mod:`hdrd.io.files.unitstate`). The daemon, replay and evaluate add what the gyro
    and the drive show (:meth:`hdrd.core.methods.MethodSetup.for_drive`)."""
    from dataclasses import asdict

    given = tuple((k, float(v)) for k, v in asdict(cfg.gyro).items() if k != "grade")
    return methods.MethodSetup(
        hdr=cfg.hdr.params,
        bias=bias,
        i_c_auto=cfg.hdr.i_c_auto,
        grade=cfg.gyro.grade,
        given_noise=given,
        standstill=cfg.standstill.enabled,
        standstill_from_gyro=cfg.standstill.from_gyro,
        method=cfg.hdr.method,
        learned=learned,
    )
