"""In-process fuzz targets of tools/fuzz for the files the daemon reads (tools/fuzz/targets.py
says what a target is and what every one promises): config, ``config_from_args`` (what
start-up and SIGHUP read), a :class:`hdrd.daemon.run.Daemon` built from the result and a
running one reloaded with it (the SIGHUP handler's body), then the daemon's pipeline stepped;
bias, :func:`hdrd.io.files.biasfile.load_bias` and the daemon's
:func:`hdrd.daemon.run.choose_bias` (both ``on_bad_bias_file`` settings), an accepted record
replayed; capture, ``hdrd replay``'s and ``hdrd convert``'s own entry points (file checks,
decode, replay pipeline, output).
"""

from __future__ import annotations

import argparse
import io
import os
import random
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .contract import Target, check, one_line
from .inputs import stress_frames
from .targets import check_messages, quiet_logging

__all__ = ["BiasTarget", "CaptureTarget", "ConfigTarget", "stress_capture"]


# -- config: the loader, the daemon built from it, SIGHUP ---------------------------------------


def stress_capture(seed: int) -> bytes:
    """A short hdr-bin capture that drives the pipeline's corners (rails, clock jumps)."""
    from hdrd.io.wire.capture import encode_array

    arr = stress_frames(random.Random(f"{seed}:capture"), 600)
    arr["t_us"] = (np.arange(600) * 10_000 + 2**32 - 2_000_000) % 2**32
    arr["t_us"][300] = (int(arr["t_us"][299]) + 2**31) % 2**32
    return encode_array(arr, "hdr-bin")


class ConfigTarget(Target):
    """``config_from_args`` on the file, as ``hdrd run`` starts; an accepted configuration
    builds a :class:`hdrd.daemon.run.Daemon` (its pipeline, GPS link) and replays a stress
    capture; a long-lived daemon is reloaded with every input (the SIGHUP handler's body:
    a refused file must leave the running configuration in place) and stepped."""

    surface = "config"

    def __init__(self, seed: int, workdir: Path) -> None:
        from hdrd.cliconfig import config_from_args
        from hdrd.daemon.listeners import Outputs
        from hdrd.daemon.run import BiasChoice, Daemon

        self.events = quiet_logging()  # its events: did a reload fail?
        self.path = workdir / "hdrd.yaml"
        self.args = argparse.Namespace(config=str(self.path))
        self.path.write_text("hdr: {}\n")
        from hdrd.config import Config

        self.bias = BiasChoice(None, "startup")
        self.reload = lambda: config_from_args(self.args)
        self.daemon = Daemon(Config(), "built-in defaults", self.reload, self.bias)
        self.daemon.outputs = Outputs.from_config(self.daemon.cfg)
        self.capture = stress_capture(seed)
        self.t_us = 0
        self.count = 0

    def run(self, data: bytes) -> str:
        from hdrd.cliconfig import config_from_args
        from hdrd.config import ConfigError
        from hdrd.daemon.replay import replay_capture
        from hdrd.daemon.run import Daemon

        self.count += 1
        _write(self.path, data)
        try:
            cfg, where = config_from_args(self.args)
        except ConfigError as e:
            one_line(str(e), "config error")
            outcome = "rejected"
        else:
            outcome = "accepted"
            d = Daemon(cfg, where, self.reload, self.bias)
            if d.gps is not None:
                d.gps.close()
            if self.count % 4 == 0:
                check_messages(
                    replay_capture(self.capture, cfg, 0.1),
                    talker=cfg.output.nmea_talker,
                )
        self._reload()
        return outcome

    def _reload(self) -> None:
        d = self.daemon
        old = d.cfg
        self.events.events.clear()
        d.reload_config()  # what SIGHUP does (the process-level run sends real ones)
        names = [e.get("event") for e in self.events.events]
        if "config_reload_failed" in names:
            check(d.cfg is old, "a refused reload changed the running configuration")
            err = next(e for e in self.events.events if e.get("event") == "config_reload_failed")
            one_line(str(err.get("error")), "config_reload_failed")
        else:
            check("config_reloaded" in names, f"reload logged {names}")
        if d.gps is not None:
            d.gps.poll(d.pipeline)  # connects (or fails to) as the loop would
        msgs: list[dict[str, Any]] = []
        for _ in range(12):
            self.t_us = (self.t_us + 100_000) % 2**32
            from hdrd.io.wire.codec import Frame

            msgs += d.pipeline.feed(Frame(0, self.t_us, 32900, 0, None), 0, 1.7e9)
        if d.gps is not None:
            d.gps.log_mode(msgs)
        check_messages(msgs, talker=d.cfg.output.nmea_talker, ths=d.cfg.output.nmea_ths)

    def close(self) -> None:
        self.daemon.outputs.stop()
        if self.daemon.gps is not None:
            self.daemon.gps.close()


def _write(path: Path, data: bytes) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


# -- bias ---------------------------------------------------------------------------------------


class BiasTarget(Target):
    """:func:`load_bias` as ``hdrd replay --bias-file`` reads it, and the daemon's
    :func:`choose_bias` with ``calibration.on_bad_bias_file`` error and calibrate; an accepted
    record becomes the pipeline's bias (and HDR+'s prior) for a stress capture."""

    surface = "bias"

    def __init__(self, seed: int, workdir: Path) -> None:
        from dataclasses import replace

        from hdrd.config import Config

        self.path = workdir / "bias.yaml"
        base = Config()
        cal = replace(base.calibration, bias_file=str(self.path))
        self.cfg_error = replace(base, calibration=replace(cal, on_bad_bias_file="error"))
        self.cfg_cal = replace(base, calibration=replace(cal, on_bad_bias_file="calibrate"))
        self.cfg_plus = replace(self.cfg_error, hdr=replace(base.hdr, method="hdr+"))
        self.capture = stress_capture(seed)
        self.count = 0

    def run(self, data: bytes) -> str:
        from hdrd.daemon.replay import replay_capture
        from hdrd.daemon.run import choose_bias
        from hdrd.io.files.biasfile import BiasFileError, load_bias

        self.count += 1
        _write(self.path, data)
        limit = self.cfg_error.calibration.max_bias_dps
        try:
            rec = load_bias(self.path, limit)
        except BiasFileError as e:
            one_line(str(e), "bias file error")
            rec = None
        try:
            choice = choose_bias(self.cfg_error, None)
            check(
                rec is not None and choice.record == rec,
                "choose_bias took a file load_bias refused",
            )
        except BiasFileError as e:
            check(rec is None, "choose_bias refused a file load_bias took")
            one_line(str(e), "bias file error")
        cal = choose_bias(self.cfg_cal, None)
        check((cal.record is None) == (rec is None), "on_bad_bias_file: calibrate disagrees")
        if rec is None:
            return "rejected"
        if self.count % 4 == 0:
            check_messages(
                replay_capture(self.capture, self.cfg_plus, rec.bias_dps, bias_record=rec)
            )
        return "accepted"


# -- capture: hdrd replay and hdrd convert --------------------------------------------------------


class _Sink(io.RawIOBase):
    """A binary stream that keeps only the byte count (replay's stdout)."""

    def __init__(self) -> None:
        self.n = 0
        self.lines = 0

    def writable(self) -> bool:
        return True

    def write(self, b: Any) -> int:
        n = len(b)
        self.n += n
        self.lines += bytes(b).count(b"\n")
        return n


class _Stdout:
    def __init__(self) -> None:
        self.buffer = _Sink()

    def write(self, s: str) -> int:
        return len(s)

    def flush(self) -> None:
        pass


class CaptureTarget(Target):
    """``hdrd replay FILE`` (``hdrd.commands.replay.main``) with stdout counted, not kept; every
    fourth input also ``hdrd convert FILE --out /dev/null``. Exit 0 with one JSON line per
    step, or 1 with one line on stderr."""

    surface = "capture"

    def __init__(self, seed: int, workdir: Path) -> None:
        self.path = workdir / "capture.bin"
        self.count = 0

    def _call(
        self, fn: Callable[[argparse.Namespace], int], args: argparse.Namespace
    ) -> tuple[int, str, _Stdout]:
        out, err = _Stdout(), io.StringIO()
        saved = sys.stdout, sys.stderr
        sys.stdout, sys.stderr = out, err
        try:
            rc = fn(args)
        finally:
            sys.stdout, sys.stderr = saved
        return rc, err.getvalue(), out

    def run(self, data: bytes) -> str:
        from hdrd.commands import replay

        self.count += 1
        protocol = "hdr-bin" if data[:1] == b"B" else "hdr-text"
        _write(self.path, data[1:])
        args = argparse.Namespace(
            capture=str(self.path),
            protocol=protocol,
            bias=None if self.count % 3 == 0 else 0.1,
            bias_file=None,
            calibrate_seconds=1.0 if self.count % 3 == 0 else None,
            method=("hdr", "hdr+", "none")[self.count % 3],
            out="/dev/null",
        )
        rc, err, out = self._call(replay.main, args)
        check(rc in (0, 1), f"replay exit {rc}")
        if rc == 1:
            one_line(err.rstrip("\n"), "replay's error")
        else:
            check(err == "", f"replay exit 0 wrote to stderr: {err[:200]!r}")
        if self.count % 4 == 0:
            rc2, err2, _ = self._call(replay.convert_main, args)
            check(rc2 == rc, f"convert exit {rc2}, replay {rc}")
            one_line(err2.rstrip("\n"), "convert's stderr")
        return "replayed" if rc == 0 else "no frames"
