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
and schema version are in :mod:`hdrd.io.wire.protocol`. An unknown value
is left out, never sent as null or 0.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt

from hdrd.config import method_setup
from hdrd.core.calibrate import BiasRecord, CalibrationLimits
from hdrd.core.resample import Block, BlockAverager, Missing
from hdrd.core.selfcheck import OutageRecord
from hdrd.daemon.aiding import GpsAiding
from hdrd.daemon.stepper import PipelineConfig, Stepper
from hdrd.io.wire.clocks import DeviceClock
from hdrd.io.wire.protocol import MESSAGE_CLASS, SCHEMA_VERSION, TEMP_NOT_FITTED, Message

if TYPE_CHECKING:
    from hdrd.config import Config
    from hdrd.io.files.unitstate import UnitState

__all__ = [
    "Pipeline",
    "pipeline_config",
    "standstill_limits",
]


class FrameLike(Protocol):
    """What the pipeline reads of a frame (hdrd.io.wire.codec.Frame, or a capture row)."""

    @property
    def t_us(self) -> int: ...
    @property
    def rate(self) -> int: ...
    @property
    def ref(self) -> int: ...
    @property
    def temp_c(self) -> float | None: ...


# -- from a configuration ---------------------------------------------------------------------


def standstill_limits(cfg: Config) -> CalibrationLimits:
    """The standstill test's thresholds from the calibration section (deg/s)."""
    c = cfg.calibration
    return CalibrationLimits(c.max_std_dps, c.max_trend_dps, c.max_excursion_dps, c.max_bias_dps)


def pipeline_config(
    cfg: Config, bias: BiasRecord | None = None, unit: UnitState | None = None
) -> PipelineConfig:
    """The pipeline a configuration asks for (``hdrd run``, ``hdrd replay``): sensor, the
    method's setup (:func:`hdrd.config.method_setup`) with the static bias of ``bias`` (None:
    measured at start-up) and what the unit's trips taught (``unit``, its state file), start-up
    window and standstill test, heading0."""
    return PipelineConfig(
        sensor=cfg.sensor,
        setup=method_setup(cfg, bias, unit.profile() if unit is not None else None),
        startup_s=cfg.calibration.startup_s,
        limits=standstill_limits(cfg),
        heading0_deg=cfg.output.heading0_deg,
        outage_record=unit.outage_record if unit is not None else OutageRecord(),
    )


DEFAULT_CONFIG = PipelineConfig()
"""The pipeline a default configuration asks for (a CRS03-04 on the shipped ADC, paper HDR)."""


class Pipeline:
    """Frames in, one message per closed step out. Pure; not thread-safe.

    ``events`` collects state changes for the edge to log ("calibrated",
    "calibration_rejected"); the edge drains it.
    """

    def __init__(
        self,
        config: PipelineConfig = DEFAULT_CONFIG,
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
        -32768 = not fitted), as :func:`hdrd.io.wire.capture.decode_capture` gives.

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
