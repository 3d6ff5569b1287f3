"""The input surfaces of tools/fuzz and each one's generator: tools/fuzz/inputs.py holds the
daemon's surfaces, tools/fuzz/clockinputs.py the clock's, tools/fuzz/driveinputs.py the drive
logs'."""

from __future__ import annotations

import random
from collections.abc import Callable

from . import clockinputs, driveinputs, inputs

__all__ = ["SURFACES", "generate"]

SURFACES = (
    "serial",
    "clock",
    "gpsd",
    "tail",
    "config",
    "bias",
    "capture",
    "drivecsv",
    "driveparquet",
)

_GENERATORS: dict[str, Callable[[random.Random], bytes]] = {
    "serial": inputs.serial_input,
    "clock": clockinputs.clock_input,
    "gpsd": inputs.gpsd_input,
    "tail": inputs.tail_input,
    "config": inputs.config_input,
    "bias": inputs.bias_input,
    "capture": inputs.capture_input,
    "drivecsv": driveinputs.drivecsv_input,
    "driveparquet": driveinputs.driveparquet_input,
}


def generate(surface: str, seed: int, i: int) -> bytes:
    """Input *i* of *surface*'s sequence for *seed*."""
    return _GENERATORS[surface](inputs.rng_for(seed, surface, i))
