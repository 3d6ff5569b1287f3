"""The daemon's input from a configuration: the serial device, or the built-in simulated
gyro (``hdrd run``, ``hdrd calibrate``)."""

from __future__ import annotations

from hdrd.config import Config
from hdrd.io.wire.sources import SerialSource, Source

__all__ = ["open_source"]


def open_source(cfg: Config, simulate: bool) -> Source:
    """The configured input (``hdrd run``, ``hdrd calibrate``): the serial device
    (``device.*``), or the built-in simulated gyro (``simulate.*``)."""
    if simulate:
        from hdrd.sim.source import SimulatedSource  # the simulator is loaded only for it

        s = cfg.simulate
        return SimulatedSource(
            drive=s.drive,
            seed=s.seed,
            hz=s.rate_hz,
            speedup=s.speedup,
            sensor=cfg.sensor,
            grade=s.grade,
        )
    d = cfg.device
    return SerialSource(
        d.port,
        protocol=d.protocol,
        baud=d.baud,
        reconnect_min_s=d.reconnect_min_s,
        reconnect_max_s=d.reconnect_max_s,
    )
