"""What a reload (SIGHUP) may not change: the settings that only a restart applies.

The device (its port is open), ``hdr.T`` (the steps' length) and ``output.heading0_deg`` (the
heading at start: a reload keeps the heading, docs/commands.md) stay as they were; each kept
is a ``config_reload_partial`` warning naming the key.
"""

from __future__ import annotations

from dataclasses import replace

from hdrd.config import Config
from hdrd.io.logs import log

__all__ = ["kept_until_restart"]


def kept_until_restart(old: Config, cfg: Config, simulate: bool) -> Config:
    """``cfg`` with what only a restart applies taken from ``old`` (a simulated gyro's
    device settings are the simulator's and may change)."""
    if cfg.device != old.device and not simulate:
        log.warning(
            "config_reload_partial",
            key="device",
            reason="device settings need a restart",
            kept=str(old.device.port),
        )
        cfg = replace(cfg, device=old.device)
    if cfg.hdr.params.T != old.hdr.params.T:
        log.warning(
            "config_reload_partial",
            key="hdr.T",
            reason="hdr.T needs a restart",
            kept=old.hdr.params.T,
        )
        cfg = replace(cfg, hdr=replace(cfg.hdr, params=replace(cfg.hdr.params, T=old.hdr.params.T)))
    if cfg.output.heading0_deg != old.output.heading0_deg:
        log.warning(
            "config_reload_partial",
            key="output.heading0_deg",
            reason="the heading at start: a reload keeps the heading (restart to set it)",
            kept=old.output.heading0_deg,
        )
        cfg = replace(cfg, output=replace(cfg.output, heading0_deg=old.output.heading0_deg))
    return cfg
