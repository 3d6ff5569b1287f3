"""The stepper, pure: one closed block of T seconds in, one message out -- the start-up
calibration window, one step of the configured drift reducer, the message's fields.

The one path from a block to a heading: the daemon's :class:`hdrd.daemon.pipeline.Pipeline`
(``hdrd run``, ``hdrd replay``), ``hdrd evaluate`` (:mod:`hdrd.analysis.prepare`) and its GNSS
outages (:mod:`hdrd.analysis.outages`) all step through :class:`Stepper`. It reads one bias (the
static bias eps0 and the method's correction) and one heading (the method's yaw; with GPS, the
aiding's alignment), and builds every message, of a step or of a report that is not one (stale,
a sensor fault), in one place. Message fields: docs/protocol.md ("Published messages"); their
names and order: :mod:`hdrd.io.wire.protocol`. An unknown value is left out, never sent as null.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from hdrd.core import methods
from hdrd.core.angles import compass
from hdrd.core.calibrate import BiasRecord, CalibrationLimits, MotionDetected, StartupWindow
from hdrd.core.hdr import HdrParams
from hdrd.core.hdrplus import PlusOutput, motion_offset
from hdrd.core.resample import Block
from hdrd.core.selfcheck import FROZEN, OutageRecord, SelfCheck, frozen_params
from hdrd.core.sensor import SensorModel
from hdrd.core.steps import StepInput
from hdrd.daemon.aiding import DEAD_RECKONING, Aid, GpsAiding, HeadingFix, StepView
from hdrd.io.wire.protocol import MESSAGE_CLASS, SCHEMA_VERSION, Message

__all__ = [
    "HELD_KEYS",
    "OUTAGE_CHECK_S",
    "PipelineConfig",
    "Stepper",
    "add_aid",
    "heading_from_yaw",
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


def heading_from_yaw(heading0_deg: float, yaw_deg: float) -> float:
    """Compass heading (deg clockwise from north, [0, 360)) from yaw (deg CCW since start)."""
    return compass(heading0_deg - yaw_deg)


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
    limits: CalibrationLimits = CalibrationLimits()
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
        self._held_source = self.bias_source  # the last step's bias_source
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
        calibrating), ``bias_source`` with them."""
        if self.held is not None:
            msg.update(self.held)
            msg["bias_source"] = self._held_source
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

    LEARN_MIN_STOPS = 10
    """Zero-rate updates while aided before the motion offset counts as learned (a stop's
    reading beside a driving bias the courses taught)."""

    def learned_offset(self) -> tuple[float, float] | None:
        """(motion offset, its sd), deg/s, as this run has learned it: only from a method that
        owns the heading, once it has seen :data:`LEARN_MIN_STOPS` stops while aided (the
        offset is observable then); None otherwise."""
        if not self.method.owns_heading or self.aided_stops < self.LEARN_MIN_STOPS:
            return None

        m, sd = motion_offset(self.state)
        return (m, sd) if math.isfinite(m) and math.isfinite(sd) else None

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
        assert isinstance(o, PlusOutput)  # the method that owns the heading: HDR+
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
        self._held_source = self.bias_source
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
        msg["bias_source"] = msg.pop("bias_source", self.bias_source)  # held: the step's
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
