"""``hdrd replay`` and ``hdrd convert``: a recorded capture through the daemon's pipeline.

Replay decodes the whole capture at once (:func:`hdrd.frames.decode_capture`) and feeds it
to the same :class:`hdrd.pipeline.Pipeline` the daemon uses, as fast as possible; its JSON
lines are bit-identical to what ``hdrd run`` publishes for the same bytes, except ``time``
(the UNIX time of publication), which a recording does not have and replay leaves out.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from hdrd.calibrate import BiasFileError, BiasRecord, load_bias
from hdrd.config import EX_CONFIG, Config, ConfigError

__all__ = ["convert_main", "main", "replay_capture"]


def replay_capture(
    data: bytes,
    cfg: Config,
    bias_dps: float | None,
    startup_s: float | None = None,
    bias_record: BiasRecord | None = None,
) -> list[dict[str, Any]]:
    """Every message the daemon would publish for these bytes (without ``time``). Pure.
    bias_record: the bias file's record behind bias_dps (HDR+'s prior), as the daemon has it."""
    from dataclasses import replace

    from hdrd.daemon import _pipeline_config
    from hdrd.frames import decode_capture
    from hdrd.pipeline import Pipeline

    frames, stats = decode_capture(data, cfg.device.protocol)
    pc = _pipeline_config(cfg, None)
    pc = replace(pc, bias_dps=bias_dps, bias_record=bias_record)
    if startup_s is not None:
        pc = replace(pc, startup_s=startup_s)
    p = Pipeline(pc)
    msgs = p.feed_array(frames, stats.bad_before)
    msgs.extend(p.finish(int(stats.bad_frames)))
    return msgs


def _config_and_capture(args: argparse.Namespace, command: str) -> tuple[Config, bytes] | int:
    """The configuration and the capture's bytes, or the exit status after saying why."""
    from hdrd.daemon import config_from_args

    try:
        cfg, _ = config_from_args(args)
    except ConfigError as e:
        print(f"hdrd: {e}", file=sys.stderr)
        return EX_CONFIG
    try:
        return cfg, Path(args.capture).read_bytes()
    except OSError as e:
        print(f"hdrd {command}: cannot read {args.capture}: {e.strerror or e}", file=sys.stderr)
        return 1


def main(args: argparse.Namespace) -> int:
    """``hdrd replay FILE``: one JSON line per step on stdout."""
    from hdrd.publish import format_json

    loaded = _config_and_capture(args, "replay")
    if isinstance(loaded, int):
        return loaded
    cfg, data = loaded
    startup_s: float | None = None
    bias: float | None = None
    record: BiasRecord | None = None
    try:
        if args.bias is not None:
            bias = args.bias
        elif args.bias_file:
            record = load_bias(args.bias_file)
        elif args.calibrate_seconds is not None:
            if not args.calibrate_seconds > 0:
                print("hdrd replay: --calibrate-seconds must be > 0", file=sys.stderr)
                return 2
            startup_s = args.calibrate_seconds
        elif cfg.calibration.bias_file:
            record = load_bias(cfg.calibration.bias_file)
    except BiasFileError as e:
        print(f"hdrd replay: {e}", file=sys.stderr)
        return 1
    if record is not None:
        bias = record.bias_dps
    msgs = replay_capture(data, cfg, bias, startup_s, record)
    out = sys.stdout.buffer
    out.write(b"".join(format_json(m) for m in msgs))
    out.flush()
    return 0


def convert_main(args: argparse.Namespace) -> int:
    """``hdrd convert CAPTURE --out DRIVE.csv``: every frame as a drive-log row (raw deg/s)."""
    import numpy as np

    from hdrd.drivelog import DriveLog, write_drive
    from hdrd.frames import decode_capture
    from hdrd.resample import DeviceClock

    loaded = _config_and_capture(args, "convert")
    if isinstance(loaded, int):
        return loaded
    cfg, data = loaded
    frames, stats = decode_capture(data, cfg.device.protocol)
    t_us, ok = DeviceClock().unwrap_many(frames["t_us"])
    frames, t_us = frames[ok], t_us[ok]
    if frames.shape[0] == 0:
        print(
            f"hdrd convert: no valid frames in {args.capture} ({stats.bad_frames} bad)",
            file=sys.stderr,
        )
        return 1
    omega = cfg.sensor.to_dps_array(frames["rate"], frames["ref"])
    temp = frames["temp"].astype(np.float64)
    has_temp = frames["temp"] != -32768
    log = DriveLog(
        t=(t_us - t_us[0]) / 1e6,
        omega=omega,
        temp_c=np.where(has_temp, temp / 100, np.nan) if has_temp.any() else None,
        name=Path(args.capture).stem,
        meta={
            "source": f"hdrd convert {Path(args.capture).name}",
            "bad_frames": str(stats.bad_frames),
        },
    )
    write_drive(args.out, log)
    print(
        f"{frames.shape[0]} samples, {log.duration_s:.1f} s, {stats.bad_frames} bad frames -> {args.out}",
        file=sys.stderr,
    )
    return 0
