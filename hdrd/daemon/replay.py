"""A recorded capture through the daemon's pipeline, as fast as possible (``hdrd replay``,
:mod:`hdrd.commands.replay`, is its command line).

The capture is decoded whole (:func:`hdrd.io.wire.capture.decode_capture`) and fed to the same
:class:`hdrd.daemon.pipeline.Pipeline` the daemon uses; the messages are bit-identical to what
``hdrd run`` publishes for the same bytes, except ``time`` (the UNIX time of publication),
which a recording does not have and replay leaves out. Pure.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from hdrd.config import Config
from hdrd.core.calibrate import BiasRecord, given_bias
from hdrd.daemon.pipeline import Pipeline, pipeline_config
from hdrd.io.wire.capture import decode_capture

__all__ = ["STEP_CHUNK_FRAMES", "replay_capture", "replay_steps"]

STEP_CHUNK_FRAMES = 16384
"""Frames fed to the pipeline at once by ``hdrd replay``, whose messages are written out
before the next chunk: the messages of a long capture are never all held at once."""


def replay_steps(
    frames: Any,
    bad_before: Any,
    bad_frames: int,
    cfg: Config,
    bias_dps: float | None,
    startup_s: float | None = None,
    chunk: int = STEP_CHUNK_FRAMES,
    bias_record: BiasRecord | None = None,
) -> Iterator[list[dict[str, Any]]]:
    """The daemon's messages (without ``time``) for decoded frames, a list per chunk of
    frames: the same messages, in the same order, as one pass (the pipeline's state carries
    over, and its block sums run in sample order either way). Pure. bias_record: the bias
    file's record behind bias_dps (HDR+'s prior), as the daemon has it."""
    from dataclasses import replace

    # the record also brings the noise parameters it holds (HDR+'s error model); a bias
    # given without one is a bare given bias, None is measured at start-up
    rec = bias_record if bias_record is not None and bias_record.bias_dps == bias_dps else None
    bias = rec if rec is not None else given_bias(bias_dps)
    pc = pipeline_config(cfg, bias)
    if startup_s is not None:
        pc = replace(pc, startup_s=startup_s)
    p = Pipeline(pc)
    for lo in range(0, frames.shape[0], chunk):
        yield p.feed_array(frames[lo : lo + chunk], bad_before[lo : lo + chunk])
    yield p.finish(int(bad_frames))


def replay_capture(
    data: bytes,
    cfg: Config,
    bias_dps: float | None,
    startup_s: float | None = None,
    bias_record: BiasRecord | None = None,
) -> list[dict[str, Any]]:
    """Every message the daemon would publish for these bytes (without ``time``). Pure.
    bias_record: the bias file's record behind bias_dps (HDR+'s prior), as the daemon has it."""
    frames, stats = decode_capture(data, cfg.device.protocol)
    out: list[dict[str, Any]] = []
    for msgs in replay_steps(
        frames,
        stats.bad_before,
        stats.bad_frames,
        cfg,
        bias_dps,
        startup_s,
        bias_record=bias_record,
    ):
        out.extend(msgs)
    return out
