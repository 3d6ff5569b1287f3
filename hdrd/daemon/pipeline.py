"""The daemon's pipeline, pure: frames -> deg/s -> blocks of T -> HDR -> messages.

One :class:`Pipeline` serves ``hdrd run`` (a frame at a time, :meth:`Pipeline.feed`) and
``hdrd replay`` (a whole decoded capture, :meth:`Pipeline.feed_array`). Both give
bit-identical messages for the same bytes: the array path uses the same formulas elementwise
(:meth:`hdrd.core.sensor.SensorModel.to_dps_array`) and sums each block in the same order
(:meth:`hdrd.core.resample.BlockAverager.feed_many`).

Stages: counts -> deg/s, + = CCW (:mod:`hdrd.core.sensor`); block means over T by device time
(Eq. 11, :mod:`hdrd.core.resample`); then the :class:`Stepper`, one call per closed block: static
bias eps0 removed (Eq. 2; given, or measured over the first ``startup_s`` at standstill, paper
Sec. 6, in :class:`hdrd.core.calibrate.StartupWindow`), one step of the configured drift reducer
(:mod:`hdrd.core.methods`), the message's fields. ``hdrd evaluate`` runs a drive log's samples
through the same :class:`hdrd.core.resample.BlockAverager` and :class:`Stepper`, so a drive is
evaluated exactly as the daemon would have run it. The caller owns the clock: the UNIX ``time``
of a message is passed in, and ``None`` leaves it out (as replay does, having no wall clock for
recorded bytes).

Message fields are documented in docs/protocol.md ("Published messages"); their names, order
and schema version are in :mod:`hdrd.io.protocol`. An unknown value
is left out, never sent as null or 0.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import numpy as np
import numpy.typing as npt

from hdrd.core import methods
from hdrd.core.calibrate import BiasRecord, MotionDetected, StandstillLimits, StartupWindow
from hdrd.core.hdr import HdrParams
from hdrd.core.resample import Block, BlockAverager, Missing
from hdrd.core.sensor import SensorModel
from hdrd.core.steps import StepInput
from hdrd.core.selfcheck import FROZEN, OutageRecord, SelfCheck, frozen_params
from hdrd.daemon.aiding import DEAD_RECKONING, Aid, GpsAiding, HeadingFix, StepView
from hdrd.io.clocks import DeviceClock
from hdrd.io.protocol import MESSAGE_CLASS, SCHEMA_VERSION, TEMP_NOT_FITTED, Message

if TYPE_CHECKING:
    from hdrd.config import Config

__all__ = [
    "Pipeline",
    "PipelineConfig",
    "Stepper",
    "heading_from_yaw",
    "pipeline_config",
    "standstill_limits",
]


HELD_KEYS = (
    "yaw",
    "heading",
    "bias",
    "model",
    "bias_sd",
    "motion_offset",
    "heading_sd",
    "outage_policy",
    "outage_trials",
)
"""What a step published of the heading and the bias that a report which is not a step
(stale, a sensor fault) repeats: yaw (deg CCW since start), heading (compass deg, the
method's, before the aiding aligns it), bias (deg/s, the static bias and the method's
correction), and the method's own account of them (HDR+: its error model, the bias's and the
heading's sd, the motion offset, the outage policy)."""


class FrameLike(Protocol):
    """What the pipeline reads of a frame (hdrd.io.frames.Frame, or a capture row)."""

    @property
    def t_us(self) -> int: ...
    @property
    def rate(self) -> int: ...
    @property
    def ref(self) -> int: ...
    @property
    def temp_c(self) -> float | None: ...


def heading_from_yaw(heading0_deg: float, yaw_deg: float) -> float:
    """Compass heading (deg clockwise from north, [0, 360)) from yaw (deg CCW since start)."""
    h = (heading0_deg - yaw_deg) % 360.0
    return 0.0 if h >= 360.0 else h


@dataclass(frozen=True)
class PipelineConfig:
    """Everything the pipeline needs; :func:`pipeline_config` builds it from a
    :class:`hdrd.config.Config`."""

    sensor: SensorModel = SensorModel()
    setup: methods.MethodSetup = methods.MethodSetup()
    """The drift reducer's setup (:class:`hdrd.core.methods.MethodSetup`): the method, its
    HDR parameters, the static bias and its record (None: measured over the first
    ``startup_s`` at standstill), the gyro's error model; the stepper adds the gyro's samples
    per step, the bias measured at start-up and the ADC's step (unless the setup knows the
    gyro's output step otherwise, as a recorded log's lattice), and the method derives its
    settings from it (HDR+: :func:`hdrd.core.methods.plus_settings`)."""
    startup_s: float = 1.0
    """Start-up calibration window, s, rounded down to whole steps (at least one; paper
    Sec. 6: 1 s)."""
    limits: StandstillLimits = StandstillLimits()
    heading0_deg: float = 0.0
    """Compass heading at start, deg."""
    outage_record: OutageRecord = OutageRecord()
    """The outage policies' record the unit starts with (its state file's;
    :mod:`hdrd.core.selfcheck`)."""

    @property
    def params(self) -> HdrParams:
        """The HDR parameters (the setup's; T is the step period, s)."""
        return self.setup.hdr

    @property
    def method(self) -> str:
        """The drift reducer's name (the setup's)."""
        return self.setup.method


def _calibrated_at(rec: BiasRecord | None) -> float | None:
    """When a record was measured, UNIX s (a bias file's); None: unknown (``--bias``)."""
    return rec.time if rec is not None and rec.time > 0 else None


def add_aid(msg: Message, aid: Aid) -> None:
    """The aiding's keys of a message (docs/protocol.md): the aligned ``heading``,
    ``heading_offset``, ``mode``, ``gps_course``, ``gps_age_s``, ``gps_speed``."""
    if aid.heading_deg is not None:
        msg["heading"] = aid.heading_deg
        msg["heading_offset"] = aid.offset_deg
    msg["mode"] = aid.mode
    if aid.course_deg is not None:
        msg["gps_course"] = aid.course_deg
    if aid.course_age_s is not None:
        msg["gps_age_s"] = aid.course_age_s
    if aid.speed_mps is not None:
        msg["gps_speed"] = aid.speed_mps


# -- from a configuration ---------------------------------------------------------------------


def standstill_limits(cfg: Config) -> StandstillLimits:
    """The standstill test's thresholds from the calibration section (deg/s)."""
    c = cfg.calibration
    return StandstillLimits(c.max_std_dps, c.max_trend_dps, c.max_excursion_dps, c.max_bias_dps)


def pipeline_config(cfg: Config, bias: BiasRecord | None = None) -> PipelineConfig:
    """The pipeline a configuration asks for (``hdrd run``, ``hdrd replay``): sensor, the
    method's setup (:func:`hdrd.config.method_setup`) with the static bias of ``bias`` (None:
    measured at start-up), start-up window and standstill test, heading0."""
    from hdrd.config import method_setup

    return PipelineConfig(
        sensor=cfg.sensor,
        setup=method_setup(cfg, bias),
        startup_s=cfg.calibration.startup_s,
        limits=standstill_limits(cfg),
        heading0_deg=cfg.output.heading0_deg,
    )


OUTAGE_CHECK_S = 120.0
"""A virtual outage's length, and how often one starts while aided, s: the outage a car in a
tunnel or a multi-storey car park meets (``hdrd evaluate --outages 120s/10min``'s)."""


# -- stepping ----------------------------------------------------------------------------------


class Stepper:
    """One closed block in, one message out: the start-up calibration window, one step of the
    configured drift reducer, the message's fields. Pure; not thread-safe.

    The :class:`Pipeline` (``hdrd run``, ``hdrd replay``) and ``hdrd evaluate`` both step
    through it. While calibrating, the owner adds each sample's raw rate to :attr:`window`
    before the block that holds it closes. ``events`` collects state changes for the edge to
    log ("calibrated", "calibration_rejected", "bias_adjusted").
    """

    def __init__(
        self,
        config: PipelineConfig = PipelineConfig(),
        aiding: GpsAiding | None = None,
        aid_clock: Callable[[], float] | None = None,
    ) -> None:
        self.config = config
        self.aiding = aiding
        """The GPS aiding stage (None: none), :mod:`hdrd.daemon.aiding`."""
        self.aid_clock = aid_clock
        """The aiding's clock (the daemon's monotonic one); None: the step's device time."""
        self._fix: HeadingFix | None = None  # the aiding's measurement for the next step
        self._t_view = 0.0  # device time of the last step, s
        self.method = methods.get(config.method)
        self.state: Any = self.method.initial_state()
        self.bias: BiasRecord | None = config.setup.bias
        self.bias_source = "calibration"
        """What last changed the published bias (``bias_source``, docs/protocol.md)."""
        self.calibrated_at = _calibrated_at(self.bias)
        """When the static bias was measured, UNIX s (None: unknown)."""
        self._bias_corr = 0.0  # the method's last correction to eps0, deg/s
        self._just_calibrated = False  # the start-up window closed in this step
        self.window = StartupWindow.for_seconds(config.startup_s, config.params.T, config.limits)
        self.events: list[tuple[str, dict[str, Any]]] = []
        self.speed_mps: float | None = None
        self.samples_per_step: float | None = None
        """Samples per step the method's settings were derived with (the first block stepped:
        the gyro's sample rate times T)."""
        self._settings: Any = None  # derived at the first step (methods.Method.settings)
        self.held: dict[str, Any] | None = None
        """What the last step published of the heading and the bias (:data:`HELD_KEYS`; None
        before the first step with a heading): a report that is not a step holds these."""
        self.selfcheck: SelfCheck | None = None
        """The virtual outages of a method that owns the heading (HDR+), once it is aided
        (:mod:`hdrd.core.selfcheck`); None for the others."""
        self.outage_record = config.outage_record
        """The outage policies' record: the unit's, as given, then what this run adds."""
        self._mode: str | None = None  # the aiding's mode at the last step
        self.aided_stops = 0
        """Zero-rate updates while the heading was aligned to GPS: the steps that show the
        rest bias beside a driving bias the courses teach (the motion offset is observable)."""

    @property
    def calibrating(self) -> bool:
        """True until the static bias is known."""
        return self.bias is None

    def held_fields(self, msg: Message) -> None:
        """The held heading's keys of a report that is not a step (stale, a sensor fault):
        ``yaw``, ``heading`` (the method's, before the aiding aligns it) and ``bias``, as the
        last step published them; before the first step, as they stand (none while
        calibrating)."""
        if self.held is not None:
            msg.update(self.held)
        elif self.bias is not None:
            msg["yaw"] = self.yaw
            msg["heading"] = heading_from_yaw(self.config.heading0_deg, self.yaw)
            msg["bias"] = self.bias.bias_dps

    @property
    def settings(self) -> Any:
        """The method's settings in force (None until the first step after (re)configuring)."""
        return self._settings

    def reconfigure(self, config: PipelineConfig) -> None:
        """New parameters, method or bias; the state (heading, controller) is kept."""
        given = config.setup.bias
        if given is not None and (self.bias is None or given.bias_dps != self.bias.bias_dps):
            self.bias = given
            self.bias_source, self.calibrated_at = "calibration", _calibrated_at(self.bias)
        self.config = config
        method = methods.get(config.method)
        if method is not self.method:  # a new method continues the heading
            self.state = method.initial_state(self.method.yaw(self.state))
            self.method = method
        self.window.limits = config.limits
        self.samples_per_step = None
        self._settings = None  # derived again at the next step

    def adjust_bias(self, delta_dps: float, source: str) -> None:
        """Add delta_dps to the static bias eps0 (deg/s); no effect while calibrating."""
        if self.bias is None or delta_dps == 0.0:
            return
        self.bias = replace(self.bias, bias_dps=self.bias.bias_dps + delta_dps)
        self.bias_source = source
        self.events.append(
            (
                "bias_adjusted",
                {"delta_dps": delta_dps, "bias_dps": self.bias.bias_dps, "source": source},
            )
        )

    @property
    def yaw(self) -> float:
        """The yaw in force, deg CCW since start."""
        return self.method.yaw(self.state)

    def input_for(self, block: Block) -> StepInput:
        """The method's input for a block: u = block mean - eps0 (Eqs. 2, 11), the samples'
        spread, the speed set last (NaN = unknown), the block's temperature, T; and the GPS
        course's measurement of the heading error the aiding stage made at the step before,
        if any (a method that estimates the bias itself: HDR+)."""
        assert self.bias is not None
        temp = math.nan if block.temp_c is None else block.temp_c
        speed = math.nan if self.speed_mps is None else self.speed_mps
        fix, self._fix = self._fix, None
        T = self.config.params.T
        u = block.mean - self.bias.bias_dps
        if fix is None:
            return StepInput(u, block.std, speed, temp, T)
        return StepInput(u, block.std, speed, temp, T, fix.err_deg, fix.var_deg2, fix.reset)

    def prepare(self, block: Block) -> StepInput | None:
        """A block closed: None while calibrating (it was a step of the start-up window),
        else the method's input for it. The first block after (re)configuring also fixes the
        samples per step the method's settings are derived with: the gyro's sample rate
        times T, as this block holds it (a 1 Hz gyro: 1)."""
        if self.bias is None:
            if block.saturated or block.faults:
                self._calibration_broken(block)
            else:
                self._calibration_step()
            return None
        if self.samples_per_step is None:
            self.samples_per_step = float(block.n)
        return self.input_for(block)

    def derive_settings(self) -> Any:
        """The method's settings for this gyro and drive (:mod:`hdrd.core.methods`): the config,
        the samples per step, the bias record (HDR+: :func:`hdrd.core.methods.plus_settings`)."""
        if self._settings is None:
            setup = self.config.setup
            q = setup.quant_step_dps
            setup = setup.for_drive(
                self.samples_per_step,
                self.bias,
                self.config.sensor.lsb_dps if q is None else q,  # else the ADC's output step
            )
            self._settings = self.method.settings(setup)
        return self._settings

    def step(self, block: Block) -> methods.Published | None:
        """One block: None while calibrating (the window closes a step), else the method's
        output as message fields (:meth:`hdrd.core.methods.Method.publish`). A method that
        owns the heading runs, in an outage (aligned to GPS before, dead reckoning now), the
        outage policy its record favours, and its virtual outages while aided
        (:mod:`hdrd.core.selfcheck`)."""
        inp = self.prepare(block)
        if inp is None:
            return None
        settings = self.derive_settings()
        if not self.method.owns_heading:
            self.state, o = self.method.step(self.state, inp, settings)
            return self.method.publish(o, settings)
        before = self.state
        in_outage = before.aided and self._mode == DEAD_RECKONING
        policy = self.outage_record.policy()
        used = frozen_params(settings) if in_outage and policy == FROZEN else settings
        self.state, o = self.method.step(before, inp, used)
        course = inp.heading_err_deg == inp.heading_err_deg
        if self.selfcheck is None and self.state.aided:
            T = self.config.params.T
            n = max(1, round(OUTAGE_CHECK_S / T))
            self.selfcheck = SelfCheck(self.outage_record, n, n)
        if self.selfcheck is not None:
            self.selfcheck.on_step(before, inp, settings, o.yaw, course and not in_outage)
            self.outage_record = self.selfcheck.record
        if o.standstill and self.state.aided:
            self.aided_stops += 1
        pub = self.method.publish(o, settings)
        pub.extra["outage_policy"] = policy
        pub.extra["outage_trials"] = self.outage_record.trials
        return pub

    def message(
        self,
        block: Block,
        step: int,
        t: float,
        bad_frames: int,
        now: float | None,
        gap_s: float = 0.0,
    ) -> Message:
        """Step the block and publish it: step number and device time ``t`` (s) as the
        owner counts them, gap_s: seconds without samples before it (0 = none)."""
        msg: Message = {"class": MESSAGE_CLASS, "v": SCHEMA_VERSION}
        if now is not None:
            msg["time"] = now
        msg["t"] = t
        msg["step"] = step
        msg["omega_raw"] = block.mean
        self._t_view = t
        aided = self._fix is not None  # a GPS measurement goes into this step
        pub = self.step(block)
        if pub is None or self.bias is None:
            status = "calibrating"
            aid = None
        else:
            status = self._step_fields(msg, pub, aided)
            aid = self._aid(StepView(t, pub.core["omega"], block.mean, msg["bias"],
                                     msg["heading"], gap_s > 0))  # fmt: skip
        msg["samples"] = block.n
        msg["bad_frames"] = bad_frames
        msg["status"] = status
        if block.temp_c is not None:
            msg["temp"] = round(block.temp_c, 3)  # deg C; the sensor resolves 0.01
        if gap_s:
            msg["gap_s"] = gap_s
        self._add_faults(msg, block)
        self.add_bias_origin(msg, now)
        if aid is not None:
            add_aid(msg, aid)
        return msg

    def fault_message(
        self, block: Block, step: int, t: float, bad_frames: int, now: float | None
    ) -> Message:
        """A block of which no sample could be averaged (each faulty or saturated): not a
        step of the method; the heading held (:meth:`held_fields`), the status saying why
        (``supply_fault``, ``saturated``), the counts and the supply seen."""
        msg: Message = {"class": MESSAGE_CLASS, "v": SCHEMA_VERSION}
        if now is not None:
            msg["time"] = now
        msg["t"] = t
        msg["step"] = step
        self.held_fields(msg)
        msg["samples"] = 0
        msg["bad_frames"] = bad_frames
        msg["status"] = "supply_fault" if block.faults else "saturated"
        self._add_faults(msg, block)
        if self.bias is None:
            self._calibration_broken(block)
        self.add_bias_origin(msg, now)
        self.held_aid(msg)
        return msg

    def _add_faults(self, msg: Message, block: Block) -> None:
        """What a block held that was not averaged: ``saturated`` (samples at an ADC rail or
        beyond the gyro's range), ``supply_faults`` (samples whose supply reading was a fault)
        and ``supply_v`` (V, of those readings the one farthest from the nominal supply)."""
        if block.saturated:
            msg["saturated"] = block.saturated
        if block.faults:
            msg["supply_faults"] = block.faults
            nominal = self.config.sensor.supply_nominal_v
            lo, hi = block.fault_lo, block.fault_hi
            msg["supply_v"] = hi if hi - nominal > nominal - lo else lo

    def _calibration_broken(self, block: Block) -> None:
        """A calibration step held samples the gyro cannot have given: the window is not
        contiguous standstill any more; it starts again."""
        self.window.clear()
        why = (
            f"{block.faults} samples with a supply fault"
            if block.faults
            else f"{block.saturated} samples at an ADC rail or beyond sensor.range_dps"
        )
        self.events.append(
            ("calibration_rejected", {"reason": why, "attempt": self.window.attempts})
        )

    def _step_fields(self, msg: Message, pub: methods.Published, aided: bool) -> str:
        """A step's fields from the method's output (rate, yaw, heading, the controller, the
        bias in force and the method's own); its status."""
        assert self.bias is not None
        core = pub.core
        msg["omega"] = core["omega"]
        msg["yaw"] = core["yaw"]
        msg["heading"] = heading_from_yaw(self.config.heading0_deg, core["yaw"])
        for key in ("I", "W", "R", "r"):
            if key in core:
                msg[key] = core[key]
        msg["bias"] = self.bias.bias_dps + pub.bias_corr_dps
        if pub.bias_corr_dps != self._bias_corr:  # the method moved it (HDR+)
            self._bias_corr = pub.bias_corr_dps
            self.bias_source = "gps" if aided else "stops" if pub.standstill else "driving"
        msg.update(pub.extra)
        if math.isfinite(pub.heading_sd_deg):
            msg["heading_sd"] = pub.heading_sd_deg
        self.held = {k: msg[k] for k in HELD_KEYS if k in msg}
        return "standstill" if pub.standstill else ("ok" if core["W"] else "turning")

    def _aid(self, view: StepView) -> Aid | None:
        """The GPS aiding stage on a step (None without one): a method that estimates the bias
        itself takes the course as its next step's measurement; for the others a learned
        correction moves the static bias."""
        if self.aiding is None:
            return None
        now = self.aid_clock() if self.aid_clock is not None else view.t
        aid = self.aiding.on_step(view, now, owner=self.method.owns_heading)
        self._mode = aid.mode
        if aid.fix is not None:
            self._fix = aid.fix
        if aid.bias_delta_dps:
            self.adjust_bias(aid.bias_delta_dps, "gps")
        return aid

    def held_aid(self, msg: Message) -> None:
        """The aiding's view of a report of the held heading (no new step: nothing is learned
        or measured), added to ``msg``."""
        if self.aiding is None or "heading" not in msg or self.bias is None:
            return
        view = StepView(self._t_view, 0.0, math.nan, msg["bias"], msg["heading"], step=False)
        now = self.aid_clock() if self.aid_clock is not None else view.t
        add_aid(msg, self.aiding.on_step(view, now, owner=self.method.owns_heading))

    def add_bias_origin(self, msg: Message, now: float | None) -> None:
        """``bias_source`` and ``calib_age_s`` (s since the static bias was measured, by the
        host clock ``now``; absent when unknown) added to a message that has a ``bias``."""
        if self._just_calibrated:  # the start-up window closed in this message's step
            self._just_calibrated = False
            self.calibrated_at = now
        if "bias" not in msg:
            return
        msg["bias_source"] = self.bias_source
        if now is not None and self.calibrated_at is not None and now >= self.calibrated_at:
            msg["calib_age_s"] = round(now - self.calibrated_at, 3)

    def _calibration_step(self) -> None:
        """A calibration block closed (its samples are in the window): measure once the
        window is complete; on motion, log it and start again."""
        try:
            rec = self.window.close_block()
        except MotionDetected as e:
            self.events.append(
                ("calibration_rejected", {"reason": str(e), "attempt": self.window.attempts})
            )
            return
        if rec is None:
            return
        self.bias = rec
        self.bias_source, self._just_calibrated = "calibration", True
        self.events.append(
            (
                "calibrated",
                {
                    "bias_dps": rec.bias_dps,
                    "std_dps": rec.std_dps,
                    "samples": rec.n,
                    "source": "startup",
                },
            )
        )


class Pipeline:
    """Frames in, one message per closed step out. Pure; not thread-safe.

    ``events`` collects state changes for the edge to log ("calibrated",
    "calibration_rejected"); the edge drains it.
    """

    def __init__(
        self,
        config: PipelineConfig = PipelineConfig(),
        aiding: GpsAiding | None = None,
        aid_clock: Callable[[], float] | None = None,
    ) -> None:
        self.config = config
        self._clock = DeviceClock()
        self._avg = BlockAverager(config.params.T)
        self.stepper = Stepper(config, aiding, aid_clock)
        self._step_offset = 0  # step numbers continue across a device resync
        self._t_offset = 0.0  # device seconds continue across a device resync
        self._last_step: int | None = None
        self._t_last = 0.0
        self._pending_gap_s = 0.0
        self._supply_before = math.nan  # the supply monitor's last reading, V (NaN: none)
        self.frames = 0
        """Frames fed since start (the link's good frames), published as ``frames``."""
        self.reconnects = 0
        """Times the device came back (:meth:`resync`), published as ``reconnects``."""

    # -- state ---------------------------------------------------------------------------

    @property
    def bias(self) -> BiasRecord | None:
        """The static bias in force (None while calibrating)."""
        return self.stepper.bias

    @property
    def events(self) -> list[tuple[str, dict[str, Any]]]:
        return self.stepper.events

    @property
    def speed_mps(self) -> float | None:
        return self.stepper.speed_mps

    @property
    def calibration_attempts(self) -> int:
        return self.stepper.window.attempts

    @property
    def calibrating(self) -> bool:
        """True until the static bias is known."""
        return self.stepper.bias is None

    @property
    def method_state(self) -> Any:
        """The drift reducer's state (its method's own type)."""
        return self.stepper.state

    @property
    def heading(self) -> float:
        """Current compass heading, deg."""
        return heading_from_yaw(self.config.heading0_deg, self.stepper.yaw)

    @property
    def clock(self) -> DeviceClock:
        return self._clock

    def reconfigure(self, config: PipelineConfig) -> None:
        """New parameters, method or bias (SIGHUP), keeping heading and controller state.
        ``heading0_deg`` is the heading at start: a new one is not taken (the heading would
        jump by the difference). T cannot change while running: it defines the block edges."""
        if config.params.T != self.config.params.T:
            raise ValueError("hdr.T cannot change while running; restart the daemon")
        config = replace(config, heading0_deg=self.config.heading0_deg)
        self.config = config
        self.stepper.reconfigure(config)

    def set_aiding(
        self, aiding: GpsAiding | None, aid_clock: Callable[[], float] | None = None
    ) -> None:
        """A GPS aiding stage (None: none) and its clock, from the next step on (a new gpsd
        connection after SIGHUP)."""
        self.stepper.aiding, self.stepper.aid_clock = aiding, aid_clock

    @property
    def aiding(self) -> GpsAiding | None:
        """The GPS aiding stage, if any."""
        return self.stepper.aiding

    def set_speed(self, speed_mps: float | None) -> None:
        """Vehicle speed (m/s, None = unknown) from an outside source (gpsd, CAN), used by
        the next closed step (standstill detection); the edge keeps it fresh."""
        self.stepper.speed_mps = speed_mps

    def adjust_bias(self, delta_dps: float, source: str) -> None:
        """Add delta_dps to the static bias eps0 (deg/s), e.g. learned from GPS course or a
        standstill; the controller state is kept. No effect while still calibrating."""
        self.stepper.adjust_bias(delta_dps, source)

    # -- input ---------------------------------------------------------------------------

    def feed(
        self, frame: FrameLike, bad_frames: int = 0, now: float | None = None
    ) -> list[Message]:
        """One frame; the messages of the steps it closed (usually none, at most a few).

        bad_frames: corrupt frames counted so far, published as is. now: UNIX time to stamp.
        """
        self.frames += 1
        t = self._clock.unwrap(frame.t_us)
        if t is None:
            return []
        sensor = self.config.sensor
        omega = sensor.to_dps_scalar(frame.rate, frame.ref)
        supply = sensor.supply_reading_scalar(frame.ref)
        fault = sensor.supply_fault_scalar(supply, self._supply_before)
        self._supply_before = supply
        sat = not fault and sensor.saturated_scalar(frame.rate, omega)
        temp = frame.temp_c
        closed = self._avg.feed(t, omega, temp, sat, supply if fault else None)
        out = self._on_blocks(closed, bad_frames, now) if closed else []
        if self.stepper.bias is None and not (fault or sat):
            self.stepper.window.add(omega, temp)
        return out

    def feed_array(
        self,
        frames: npt.NDArray[Any],
        bad_before: npt.ArrayLike | None = None,
    ) -> list[Message]:
        """A whole capture: a structured array with fields t_us, rate, ref, temp (0.01 degC,
        -32768 = not fitted), as :func:`hdrd.io.capture.decode_capture` gives.

        Same messages as :meth:`feed` frame by frame. bad_before[i]: corrupt frames seen
        before frame i in the byte stream.
        """
        n = frames.shape[0]
        start = self.frames  # frames fed before these
        bad = np.zeros(n, np.int64) if bad_before is None else np.asarray(bad_before, np.int64)
        out: list[Message] = []
        i = 0
        # The start-up calibration gathers per-sample rates: take it a frame at a time.
        while self.stepper.bias is None and i < n:
            f = frames[i]
            temp = None if int(f["temp"]) == TEMP_NOT_FITTED else int(f["temp"]) / 100
            out.extend(
                self.feed(
                    _Row(int(f["t_us"]), int(f["rate"]), int(f["ref"]), temp),
                    int(bad[i]),
                )
            )
            i += 1
        if i >= n:
            return out
        rest = frames[i:]
        t_us, ok = self._clock.unwrap_many(rest["t_us"])
        keep = np.flatnonzero(ok) + i
        if keep.shape[0] < rest.shape[0]:  # samples the clock rejected (else: no copy)
            rest = frames[keep]
            t_us = t_us[ok]
        rate = rest["rate"].astype(np.int64)
        ref = rest["ref"].astype(np.int64)
        sensor = self.config.sensor
        omega = sensor.to_dps_array(rate, ref)
        supply = sensor.supply_readings(ref)
        fault = sensor.supply_faults(supply, self._supply_before)
        if supply.shape[0]:
            self._supply_before = float(supply[-1])
        sat = ~fault & np.asarray(sensor.saturated(rate, omega), bool)
        raw_temp = rest["temp"].astype(np.int64)
        temps = np.where(raw_temp == TEMP_NOT_FITTED, np.nan, raw_temp / 100)
        faults = np.where(fault, supply, np.nan)
        for pos, item in self._avg.feed_many(t_us, omega, temps, sat, faults):
            self.frames = start + int(keep[pos]) + 1  # as feed() counts at the closing frame
            out.extend(self._on_blocks((item,), int(bad[keep[pos]]), None))
        self.frames = start + n
        return out

    def finish(self, bad_frames: int = 0, now: float | None = None) -> list[Message]:
        """End of input: close the open, partial block."""
        return self._on_blocks(self._avg.flush(), bad_frames, now)

    def resync(
        self, gap_s: float | None = None, bad_frames: int = 0, now: float | None = None
    ) -> list[Message]:
        """The device went away and is back (its clock may have restarted from zero).

        Closes the open block, then cuts new block edges from the next sample; heading and
        the controller carry on. ``gap_s`` (wall-clock seconds without data) is reported in
        the next step's message, and step numbers and ``t`` move on by it, as they do across
        a gap within a connection: the steps missed are skipped, not invented.
        """
        out = self.finish(bad_frames, now)
        self.reconnects += 1
        if self._last_step is not None:
            missed = int(gap_s // self.config.params.T) if gap_s and gap_s > 0 else 0
            self._step_offset = self._last_step + 1 + missed
            self._t_offset = self._t_last + missed * self.config.params.T
        self._clock = DeviceClock()
        self._avg = BlockAverager(self.config.params.T)
        self._supply_before = math.nan  # a new connection: no reading to jump from
        if gap_s:
            self._pending_gap_s += gap_s
        if self.stepper.bias is None:  # a calibration window must be contiguous
            self.stepper.window.clear()
        return out

    # -- steps ---------------------------------------------------------------------------

    def _on_blocks(
        self,
        items: tuple[Block | Missing, ...] | list[Block | Missing],
        bad_frames: int,
        now: float | None,
    ) -> list[Message]:
        out: list[Message] = []
        for item in items:
            if isinstance(item, Missing):
                self._pending_gap_s += item.t_end - item.t_start
            else:
                out.append(self._on_block(item, bad_frames, now))
        return out

    def _on_block(self, block: Block, bad_frames: int, now: float | None) -> Message:
        step = block.index + self._step_offset
        self._last_step = step
        self._t_last = self._t_offset + block.t_end
        if block.n:
            gap = self._pending_gap_s
            self._pending_gap_s = 0.0
            msg = self.stepper.message(block, step, self._t_last, bad_frames, now, gap)
        else:  # nothing usable: as a gap, the heading held and the reason said
            self._pending_gap_s += block.t_end - block.t_start
            msg = self.stepper.fault_message(block, step, self._t_last, bad_frames, now)
        msg["frames"] = self.frames
        msg["reconnects"] = self.reconnects
        return msg

    def sample_interval_s(self) -> float | None:
        """Sample interval of the open block, device s: (last - block start) / (n - 1), never
        less than the mean interval (the first sample is at or after the start). None until
        the open block holds two samples."""
        block = self._avg.open_block
        last = self._clock.last_us
        if block is None or last is None or block[2] < 2:
            return None
        return max(last - block[0], 0) / (block[2] - 1) / 1e6

    def until_step_s(self) -> float | None:
        """Device seconds from the last sample to one sample interval before the open block
        ends: how long the port may go unread without delaying the next step, if the device
        clock runs at the host's rate (the sample that closes the step arrives at the block's
        end at the earliest). None until the open block holds two samples.

        The interval (:meth:`sample_interval_s`) errs long, so the answer errs early. The
        daemon uses it to read the port in batches (:mod:`hdrd.daemon.pacing`).
        """
        interval = self.sample_interval_s()
        block = self._avg.open_block
        last = self._clock.last_us
        if interval is None or block is None or last is None:
            return None
        return (block[1] - last) / 1e6 - interval

    # -- while no data arrives -------------------------------------------------------------

    def stale_message(
        self, now: float | None, silent_s: float, bad_frames: int = 0, status: str = "stale"
    ) -> Message:
        """What to publish while no sample arrives: no new step; the heading and the bias
        held as the last step published them (:meth:`Stepper.held_fields`)."""
        msg: Message = {"class": MESSAGE_CLASS, "v": SCHEMA_VERSION}
        if now is not None:
            msg["time"] = now
        if self._last_step is not None:
            msg["step"] = self._last_step
            self.stepper.held_fields(msg)
        msg["bad_frames"] = bad_frames
        msg["status"] = status
        msg["stale_s"] = silent_s
        self.stepper.add_bias_origin(msg, now)
        self.stepper.held_aid(msg)
        msg["frames"] = self.frames
        msg["reconnects"] = self.reconnects
        return msg


@dataclass(frozen=True, slots=True)
class _Row:
    """One row of a decoded capture, shaped like a frame for :meth:`Pipeline.feed`."""

    t_us: int
    rate: int
    ref: int
    temp_c: float | None
