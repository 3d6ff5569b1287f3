"""hdrd.daemon.inputs: the input a configuration names for ``hdrd run`` and ``hdrd
calibrate``: the serial device with its ``device.*`` settings (a real pty here), or the
built-in simulated gyro with its ``simulate.*`` settings.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from hdrd.config import Config
from hdrd.configload import apply_overrides
from hdrd.daemon.inputs import open_source
from hdrd.io.wire.codec import Frame, encode_text
from hdrd.io.wire.sources import SerialSource
from hdrd.sim.source import SimulatedSource


def test_the_device_with_its_settings(tmp_path: Path) -> None:
    master, slave = os.openpty()
    link = tmp_path / "gyro"
    link.symlink_to(os.ttyname(slave))
    os.close(slave)
    cfg = apply_overrides(
        Config(),
        {
            "device.port": str(link),
            "device.protocol": "hdr-text",
            "device.baud": 230400,
            "device.reconnect_min_s": 0.25,
            "device.reconnect_max_s": 4.0,
        },
    )
    try:
        with open_source(cfg, simulate=False) as src:
            assert isinstance(src, SerialSource) and src.url == str(link)
            r = src.reader
            assert (r.baud, r.reconnect_min_s, r.reconnect_max_s) == (230400, 0.25, 4.0)
            assert src.port.baudrate == 230400
            f = Frame(7, 700_000, 33000, 0, 2150)
            os.write(master, encode_text(f))  # the text protocol, as configured
            got = None
            deadline = time.monotonic() + 20.0
            while got is None and time.monotonic() < deadline:
                got = src.recv(0.1)
            assert got == f
    finally:
        os.close(master)


def test_the_simulated_gyro_with_its_settings() -> None:
    cfg = apply_overrides(
        Config(),
        {
            "simulate.drive": "highway",
            "simulate.seed": 4,
            "simulate.rate_hz": 2.0,
            "simulate.speedup": 1000.0,
            "simulate.grade": "phone",
        },
    )
    with open_source(cfg, simulate=True) as src:
        assert isinstance(src, SimulatedSource) and src.speedup == 1000.0
        want = SimulatedSource(
            "highway", seed=4, hz=2.0, speedup=0.0, sensor=cfg.sensor, grade="phone"
        )
        assert np.array_equal(src.frames, want.frames)
        want.close()
        other = SimulatedSource("highway", seed=4, hz=2.0, speedup=0.0, grade="crs03")
        assert not np.array_equal(src.frames, other.frames)  # the grade was passed on
        other.close()
        dt = np.diff(src.profile.t)
        assert np.allclose(dt, 1 / 2.0)  # at the configured rate
