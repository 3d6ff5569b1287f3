"""The daemon's pipeline, pure: frames -> deg/s -> blocks of T -> HDR -> messages.

One :class:`Pipeline` serves ``hdrd run`` (a frame at a time, :meth:`Pipeline.feed`) and
``hdrd replay`` (a whole decoded capture, :meth:`Pipeline.feed_array`). Both give
bit-identical messages for the same bytes: the array path uses the same formulas elementwise
(:meth:`hdrd.sensor.SensorModel.to_dps_array`) and sums each block in the same order
(:meth:`hdrd.resample.BlockAverager.feed_many`).

Stages: counts -> deg/s, + = CCW (:mod:`hdrd.sensor`); block means over T by device time
(Eq. 11, :mod:`hdrd.resample`); static bias eps0 removed (Eq. 2; given, or measured over the
first ``startup_s`` at standstill, paper Sec. 6); one HDR step per block (Eqs. 3-10,
:mod:`hdrd.hdr`). The caller owns the clock: the UNIX ``time`` of a message is passed in, and
``None`` leaves it out (as replay does, having no wall clock for recorded bytes).

Message fields are documented in docs/protocol.md ("Published messages"). An unknown value
is left out, never sent as null or 0.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from hdrd import hdr, hdrplus
from hdrd.calibrate import BiasRecord, MotionDetected, StandstillLimits, estimate_bias
from hdrd.hdr import HdrParams, HdrState
from hdrd.hdrplus import INITIAL_PLUS_STATE, HdrPlusParams, PlusState
from hdrd.resample import Block, BlockAverager, DeviceClock, Missing
from hdrd.sensor import SensorModel

__all__ = [
    "SCHEMA_VERSION",
    "Message",
    "Pipeline",
    "PipelineConfig",
    "heading_from_yaw",
    "method_params",
]

SCHEMA_VERSION = 1
Message = dict[str, Any]
TEMP_NOT_FITTED = -32768


class FrameLike(Protocol):
    """What the pipeline reads of a frame (hdrd.frames.Frame, or a capture row)."""

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


METHODS = ("none", "hdr", "hdr+")


def method_params(method: str, params: HdrParams) -> HdrParams:
    """The paper-HDR parameters a drift-reduction method runs with ("none" freezes I at 0;
    "hdr+" runs its own core, :data:`hdrd.hdrplus.PLUS_CORE`, and ignores these)."""
    if method == "none":
        return replace(params, enabled=False)
    if method in ("hdr", "hdr+"):
        return params
    raise ValueError(f"unknown method {method!r} (allowed: {', '.join(METHODS)})")


@dataclass(frozen=True)
class PipelineConfig:
    """Everything the pipeline needs; the edges build it from :class:`hdrd.config.Config`."""

    sensor: SensorModel = SensorModel()
    params: HdrParams = HdrParams()
    method: str = "hdr"
    bias_dps: float | None = None
    """Static bias eps0, deg/s; None = measure it over the first startup_s at standstill."""
    startup_s: float = 1.0
    """Start-up calibration window, s, rounded up to whole steps (paper Sec. 6: 1 s)."""
    limits: StandstillLimits = StandstillLimits()
    heading0_deg: float = 0.0
    """Compass heading at start, deg."""
    plus: HdrPlusParams = HdrPlusParams()
    """HDR+'s parameters (method "hdr+"); its core is its own, not ``params``."""


class Pipeline:
    """Frames in, one message per closed step out. Pure; not thread-safe.

    ``events`` collects state changes for the edge to log ("calibrated",
    "calibration_rejected"); the edge drains it.
    """

    def __init__(self, config: PipelineConfig = PipelineConfig()) -> None:
        self.config = config
        self._params = method_params(config.method, config.params)
        self._clock = DeviceClock()
        self._avg = BlockAverager(config.params.T)
        # One state for every method: HDR+ carries the paper HDR state as its core, so a
        # method switched on SIGHUP continues the same heading.
        self._plus: PlusState = INITIAL_PLUS_STATE
        self._step_offset = 0  # step numbers continue across a device resync
        self._t_offset = 0.0  # device seconds continue across a device resync
        self._last_step: int | None = None
        self._t_last = 0.0
        self._pending_gap_s = 0.0
        self.bias: BiasRecord | None = None
        self._cal_blocks = max(1, math.ceil(config.startup_s / config.params.T - 1e-9))
        self._cal_omega: list[float] = []  # per-sample rates of the calibration window
        self._cal_temp: list[float] = []
        self._cal_done_blocks = 0
        self.calibration_attempts = 0
        if config.bias_dps is not None:
            self.bias = BiasRecord(config.bias_dps, 0.0, 0, 0.0)
        self.events: list[tuple[str, dict[str, Any]]] = []
        self.speed_mps: float | None = None
        self._plus_params: HdrPlusParams | None = None  # fitted at the first HDR+ step

    # -- state ---------------------------------------------------------------------------

    @property
    def calibrating(self) -> bool:
        """True until the static bias is known."""
        return self.bias is None

    @property
    def hdr_state(self) -> HdrState:
        """The HDR core's state (x, I, yaw, r, s, n)."""
        return self._plus.core

    @property
    def heading(self) -> float:
        """Current compass heading, deg."""
        return heading_from_yaw(self.config.heading0_deg, self._plus.core.yaw)

    @property
    def clock(self) -> DeviceClock:
        return self._clock

    def reconfigure(self, config: PipelineConfig) -> None:
        """New parameters, method, heading0 or bias (SIGHUP), keeping heading and controller
        state. T cannot change while running: it defines the block edges."""
        if config.params.T != self.config.params.T:
            raise ValueError("hdr.T cannot change while running; restart the daemon")
        if config.bias_dps is not None and (
            self.bias is None or config.bias_dps != self.bias.bias_dps
        ):
            self.bias = BiasRecord(config.bias_dps, 0.0, 0, 0.0)
        self.config = config
        self._params = method_params(config.method, config.params)
        self._plus_params = None  # refitted at the next HDR+ step

    def set_speed(self, speed_mps: float | None) -> None:
        """Vehicle speed (m/s, None = unknown) from an outside source (gpsd, CAN), used by
        the next closed step (standstill detection); the edge keeps it fresh."""
        self.speed_mps = speed_mps

    def adjust_bias(self, delta_dps: float, source: str) -> None:
        """Add delta_dps to the static bias eps0 (deg/s), e.g. learned from GPS course or a
        standstill; the controller state is kept. No effect while still calibrating."""
        if self.bias is None or delta_dps == 0.0:
            return
        self.bias = replace(self.bias, bias_dps=self.bias.bias_dps + delta_dps)
        self.events.append(
            (
                "bias_adjusted",
                {"delta_dps": delta_dps, "bias_dps": self.bias.bias_dps, "source": source},
            )
        )

    # -- input ---------------------------------------------------------------------------

    def feed(
        self, frame: FrameLike, bad_frames: int = 0, now: float | None = None
    ) -> list[Message]:
        """One frame; the messages of the steps it closed (usually none, at most a few).

        bad_frames: corrupt frames counted so far, published as is. now: UNIX time to stamp.
        """
        t = self._clock.unwrap(frame.t_us)
        if t is None:
            return []
        sensor = self.config.sensor
        omega = sensor.to_dps_scalar(frame.rate, frame.ref)
        sat = sensor.saturated_scalar(frame.rate, omega)
        temp = frame.temp_c
        closed = self._avg.feed(t, omega, temp, sat)
        out = self._on_blocks(closed, bad_frames, now) if closed else []
        if self.bias is None:
            self._cal_omega.append(omega)
            self._cal_temp.append(math.nan if temp is None else temp)
        return out

    def feed_array(
        self,
        frames: npt.NDArray[Any],
        bad_before: npt.ArrayLike | None = None,
        now: Callable[[], float] | None = None,
    ) -> list[Message]:
        """A whole capture: a structured array with fields t_us, rate, ref, temp (0.01 degC,
        -32768 = not fitted), as :func:`hdrd.frames.decode_capture` gives.

        Same messages as :meth:`feed` frame by frame. bad_before[i]: corrupt frames seen
        before frame i in the byte stream.
        """
        n = frames.shape[0]
        bad = np.zeros(n, np.int64) if bad_before is None else np.asarray(bad_before, np.int64)
        out: list[Message] = []
        i = 0
        # The start-up calibration gathers per-sample rates: take it a frame at a time.
        while self.bias is None and i < n:
            f = frames[i]
            temp = None if int(f["temp"]) == TEMP_NOT_FITTED else int(f["temp"]) / 100
            out.extend(
                self.feed(
                    _Row(int(f["t_us"]), int(f["rate"]), int(f["ref"]), temp),
                    int(bad[i]),
                    now() if now else None,
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
        sat = np.asarray(sensor.saturated(rate, omega), bool)
        raw_temp = rest["temp"].astype(np.int64)
        temps = np.where(raw_temp == TEMP_NOT_FITTED, np.nan, raw_temp / 100)
        for pos, item in self._avg.feed_many(t_us, omega, temps, sat):
            out.extend(self._on_blocks((item,), int(bad[keep[pos]]), now() if now else None))
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
        if self._last_step is not None:
            missed = int(gap_s // self.config.params.T) if gap_s and gap_s > 0 else 0
            self._step_offset = self._last_step + 1 + missed
            self._t_offset = self._t_last + missed * self.config.params.T
        self._clock = DeviceClock()
        self._avg = BlockAverager(self.config.params.T)
        if gap_s:
            self._pending_gap_s += gap_s
        if self.bias is None:  # a calibration window must be contiguous
            self._cal_omega.clear()
            self._cal_temp.clear()
            self._cal_done_blocks = 0
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
        msg: Message = {"class": "HDR", "v": SCHEMA_VERSION}
        if now is not None:
            msg["time"] = now
        msg["t"] = self._t_last
        msg["step"] = step
        msg["omega_raw"] = block.mean
        bias = self.bias
        if bias is None:
            status = "calibrating"
            self._calibration_step(block)
        else:
            o, published_bias, still = self._step(block, bias.bias_dps)
            msg["omega"] = o.omega
            msg["yaw"] = o.yaw
            msg["heading"] = heading_from_yaw(self.config.heading0_deg, o.yaw)
            msg["I"] = o.I
            msg["W"] = o.W
            msg["R"] = o.R
            msg["r"] = o.r
            msg["bias"] = published_bias
            status = "standstill" if still else ("ok" if o.W else "turning")
            if self.config.method == "hdr+":
                msg["zupt"] = int(still)
        msg["samples"] = block.n
        msg["bad_frames"] = bad_frames
        msg["status"] = status
        if block.temp_c is not None:
            msg["temp"] = round(block.temp_c, 3)  # deg C; the sensor resolves 0.01
        if self._pending_gap_s:
            msg["gap_s"] = self._pending_gap_s
            self._pending_gap_s = 0.0
        if block.saturated:
            msg["saturated"] = block.saturated
        return msg

    def _step(
        self, block: Block, eps0: float
    ) -> tuple[hdr.HdrOutput | hdrplus.PlusOutput, float, bool]:
        """One drift-reduction step on the block: (output, published bias deg/s, standstill)."""
        u = block.mean - eps0
        if self.config.method != "hdr+":
            core, o = hdr.step(self._plus.core, u, self._params)
            self._plus = self._plus._replace(core=core)
            return o, eps0, False
        temp = math.nan if block.temp_c is None else block.temp_c
        speed = math.nan if self.speed_mps is None else self.speed_mps
        inp = hdrplus.PlusInput(u, block.std, speed, temp, self.config.params.T)
        if self._plus_params is None:
            self._plus_params = self._fit_plus_params(block)
        self._plus, po = hdrplus.step(self._plus, inp, self._plus_params)
        return po, eps0 + po.bias_corr_dps, po.standstill

    def _fit_plus_params(self, block: Block) -> HdrPlusParams:
        """HDR+'s parameters for this gyro: samples per step from the first block stepped
        (the sample rate times T), and the start-up bias variance std^2/n of the eps0
        measurement when it is known (the default assumes a 30 s one)."""
        p = self.config.plus
        if block.n >= 2:
            p = replace(p, standstill=replace(p.standstill, samples_per_step=float(block.n)))
        rec = self.bias
        if rec is not None and rec.n > 1 and rec.std_dps > 0:
            p = replace(p, bias_p0=rec.std_dps * rec.std_dps / rec.n)
        return p

    def _calibration_step(self, block: Block) -> None:
        """A calibration block closed: its samples are in _cal_*, minus none (the closing
        sample is appended after this runs). Measure once the window is complete."""
        self._cal_done_blocks += 1
        if self._cal_done_blocks < self._cal_blocks:
            return
        self.calibration_attempts += 1
        w = np.asarray(self._cal_omega)
        temps = np.asarray(self._cal_temp)
        T = self.config.params.T
        try:
            rec = estimate_bias(w, temp_c=temps, limits=self.config.limits)
        except MotionDetected as e:
            self.events.append(
                ("calibration_rejected", {"reason": str(e), "attempt": self.calibration_attempts})
            )
            self._cal_omega.clear()
            self._cal_temp.clear()
            self._cal_done_blocks = 0
            return
        self.bias = replace(rec, duration_s=self._cal_blocks * T)
        self._cal_omega = []
        self._cal_temp = []
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
        daemon uses it to read the port in batches (:mod:`hdrd.pacing`).
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
        """What to publish while no sample arrives: no new step, the heading held."""
        msg: Message = {"class": "HDR", "v": SCHEMA_VERSION}
        if now is not None:
            msg["time"] = now
        if self._last_step is not None:
            msg["step"] = self._last_step
        if self.bias is not None and self._last_step is not None:
            msg["yaw"] = self._plus.core.yaw
            msg["heading"] = self.heading
            msg["bias"] = self.bias.bias_dps
        msg["bad_frames"] = bad_frames
        msg["status"] = status
        msg["stale_s"] = silent_s
        return msg


@dataclass(frozen=True, slots=True)
class _Row:
    """One row of a decoded capture, shaped like a frame for :meth:`Pipeline.feed`."""

    t_us: int
    rate: int
    ref: int
    temp_c: float | None
