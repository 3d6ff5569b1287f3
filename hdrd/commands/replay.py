"""``hdrd replay`` and ``hdrd convert``: a recorded capture through the daemon's pipeline.

Replay writes the messages of :func:`hdrd.daemon.replay.replay_steps` (the daemon's own
pipeline on the decoded capture) as JSON lines, bit-identical to what ``hdrd run`` publishes for
the same bytes, except ``time`` (the UNIX time of publication), which a recording does not
have and replay leaves out.

Memory follows the file: its bytes (read whole, a regular file of at most
:data:`hdrd.io.files.access.MAX_CAPTURE_BYTES`), 12 bytes per frame decoded, and the messages of
one chunk of frames at a time; never the device time the capture spans
(bench/replay_memory.py). A file with no valid frame is an error (exit 1), not an empty run.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path
from typing import Any

from hdrd.cliconfig import check_bias_arg, config_from_args, drive_log_outputs_ok
from hdrd.config import Config, ConfigError
from hdrd.core.calibrate import BiasRecord
from hdrd.daemon.replay import replay_steps
from hdrd.errors import EX_CONFIG, EX_USAGE
from hdrd.io.files.access import MAX_CAPTURE_BYTES, InputFileError, read_limited, shown_path
from hdrd.io.files.biasfile import BiasFileError, load_bias
from hdrd.io.files.drivecolumns import DriveLogError
from hdrd.io.files.drivefiles import log_format, write_log
from hdrd.io.files.drivelog import SNIFF_BYTES, DriveLog, converted_name, drive_log_kind
from hdrd.io.net.formats import format_json
from hdrd.io.wire.capture import decode_capture
from hdrd.io.wire.clocks import DeviceClock
from hdrd.io.wire.protocol import TEMP_NOT_FITTED

__all__ = ["convert_main", "main"]


def _config_and_capture(args: argparse.Namespace, command: str) -> tuple[Config, bytes] | int:
    """The configuration and the capture's bytes, or the exit status after saying why.

    The capture must be a regular file of at most MAX_CAPTURE_BYTES (a FIFO or a device
    would block or never end)."""

    try:
        cfg, _ = config_from_args(args)
        check_bias_arg(getattr(args, "bias", None), cfg)
    except ConfigError as e:
        print(f"hdrd: {e}", file=sys.stderr)
        return EX_CONFIG
    try:
        return cfg, read_limited(args.capture, MAX_CAPTURE_BYTES)
    except InputFileError as e:
        print(f"hdrd {command}: cannot read {args.capture}: {e}", file=sys.stderr)
    except OSError as e:
        print(f"hdrd {command}: cannot read {args.capture}: {e.strerror or e}", file=sys.stderr)
    return 1


def _no_frames(command: str, capture: str, protocol: str, stats: Any) -> int:
    """A file that holds no valid frame (a drive log; not a capture; another --protocol):
    exit 1."""
    try:
        with open(capture, "rb") as f:  # a regular file: read_limited took it whole
            kind = drive_log_kind(f.read(SNIFF_BYTES))
    except OSError:
        kind = None
    if kind is not None:
        shown = shown_path(capture)
        print(
            f"hdrd {command}: {shown} is a drive log ({kind}), not a capture of the gyro's "
            f"frames: `hdrd evaluate {shlex.quote(shown)}` runs a drive log through the drift "
            "reducers as the daemon would (docs/evaluation.md)",
            file=sys.stderr,
        )
        return 1
    other = "hdr-text" if protocol == "hdr-bin" else "hdr-bin"
    print(
        f"hdrd {command}: no valid frames in {capture} ({stats.bad_frames} bad frames, "
        f"{stats.garbage_bytes} bytes of garbage as {protocol}); is it a capture from "
        f"`hdrd record`, and is it {other} (--protocol {other})?",
        file=sys.stderr,
    )
    return 1


def main(args: argparse.Namespace) -> int:
    """``hdrd replay FILE``: one JSON line per step on stdout, written as the steps come."""
    loaded = _config_and_capture(args, "replay")
    if isinstance(loaded, int):
        return loaded
    cfg, data = loaded
    del loaded
    startup_s: float | None = None
    bias: float | None = None
    record: BiasRecord | None = None
    limit = cfg.calibration.max_bias_dps
    try:
        if args.bias is not None:
            bias = args.bias
        elif args.bias_file:
            record = load_bias(args.bias_file, limit)
        elif args.calibrate_seconds is not None:
            if not 0 < args.calibrate_seconds <= 600:  # calibration.startup_s's range
                print(
                    "hdrd replay: --calibrate-seconds must be a number > 0 and <= 600",
                    file=sys.stderr,
                )
                return 2
            startup_s = args.calibrate_seconds
        elif cfg.calibration.bias_file:
            record = load_bias(cfg.calibration.bias_file, limit)
    except BiasFileError as e:
        print(f"hdrd replay: {e}", file=sys.stderr)
        return 1
    if record is not None:
        bias = record.bias_dps
    frames, stats = decode_capture(data, cfg.device.protocol)
    del data  # the frames are all that is needed from here on
    if frames.shape[0] == 0:
        return _no_frames("replay", args.capture, cfg.device.protocol, stats)
    out = sys.stdout.buffer
    for msgs in replay_steps(
        frames, stats.bad_before, stats.bad_frames, cfg, bias, startup_s, bias_record=record
    ):
        if msgs:
            out.write(b"".join(format_json(m) for m in msgs))
    out.flush()
    return 0


def _is_the_capture(out: str, capture: str) -> bool:
    """Whether writing ``out`` would write over ``capture`` (the same file, under its name, a
    link or another hard link)."""
    try:
        return os.path.samefile(out, capture)
    except OSError:  # one of them does not exist (or cannot be looked at): not the same
        return False


def convert_main(args: argparse.Namespace) -> int:
    """``hdrd convert CAPTURE --out DRIVE.csv|DRIVE.parquet|DIR [--format F]``: every frame as a
    drive-log row (raw deg/s)."""
    import numpy as np

    if _is_the_capture(args.out, args.capture):
        print(
            f"hdrd convert: --out {shown_path(args.out)} is the capture itself; name another "
            f"file, e.g. --out {shlex.quote(converted_name(args.capture))}",
            file=sys.stderr,
        )
        return EX_USAGE
    fmt = log_format(args.out, getattr(args, "format", None))
    say = lambda msg: print(f"hdrd convert: {msg}", file=sys.stderr)  # noqa: E731
    if not drive_log_outputs_ok(args, say, fmt == "dataset"):  # said before the work
        return 1
    loaded = _config_and_capture(args, "convert")
    if isinstance(loaded, int):
        return loaded
    cfg, data = loaded
    frames, stats = decode_capture(data, cfg.device.protocol)
    t_us, ok = DeviceClock().unwrap_many(frames["t_us"])
    frames, t_us = frames[ok], t_us[ok]
    if frames.shape[0] == 0:
        return _no_frames("convert", args.capture, cfg.device.protocol, stats)
    omega = cfg.sensor.to_dps_array(frames["rate"], frames["ref"])
    temp = frames["temp"].astype(np.float64)
    has_temp = frames["temp"] != TEMP_NOT_FITTED
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
    try:
        written = write_log(args.out, log, fmt, log.name)
    except (OSError, DriveLogError) as e:
        print(
            f"hdrd convert: cannot write {args.out}: {(e.strerror if isinstance(e, OSError) else None) or e}",
            file=sys.stderr,
        )
        return 1
    print(
        f"{frames.shape[0]} samples, {log.duration_s:.1f} s, {stats.bad_frames} bad frames -> {written}",
        file=sys.stderr,
    )
    return 0
