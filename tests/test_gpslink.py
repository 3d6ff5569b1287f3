# ruff: noqa: F811 - the fixture peer comes from test_gpsd by import
"""hdrd.daemon.gpslink: ``hdrd run --gpsd``'s link: gpsd's fixes (from a real TCP peer
speaking as gpsd does) stamped and fed to the aiding, the GPS speed to the pipeline, messages
aided before they are published, and state changes logged, the noisy ones at most every 10 s
(structlog's own capture).

The gpsd client and parser: test_gpsd.py; the aiding (pure): test_aiding.py; with the real
gpsd and a daemon process: test_gpsd_nmea.py.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import pytest
from structlog.testing import capture_logs

from hdrd.core.calibrate import given_bias
from hdrd.core.methods import MethodSetup
from hdrd.core.sensor import SensorModel
from hdrd.daemon.aiding import AIDED, GpsAiding
from hdrd.daemon.gpslink import GpsdLink
from hdrd.daemon.pipeline import Pipeline
from hdrd.daemon.stepper import PipelineConfig
from hdrd.io.net.gpsd import GpsdClient
from hdrd.io.wire.protocol import Message
from tests.test_gpsd import REAL_TPV, WAIT, Peer, peer  # noqa: F401 - peer: a fixture


@dataclass(frozen=True)
class Row:
    """A frame as the pipeline reads it."""

    t_us: int
    rate: int
    ref: int
    temp_c: float | None


def connected_link(peer: Peer, p: Pipeline) -> tuple[GpsdLink, GpsdClient]:
    c = GpsdClient("127.0.0.1", peer.port)
    link = GpsdLink(c, GpsAiding())
    link.poll(p, now=0.0)
    peer.accept()
    deadline = time.monotonic() + WAIT
    while not c.connected and time.monotonic() < deadline:
        link.poll(p, now=0.0)
    assert c.connected
    return link, c


class _Clock:
    """A monotonic clock the test sets (the link's and the aiding stage's)."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _steps(p: Pipeline, first: int, count: int) -> list[Message]:
    """Messages of ``count`` 1 s steps from step ``first`` of a gyro at rest (10 Hz frames,
    heading 0 with the given bias 0)."""
    out: list[Message] = []
    for i in range(first * 10, (first + count) * 10 + 1):
        out += p.feed(Row(i * 100_000, 32768, 0, None))
    return out


def test_link_feeds_speed_and_the_pipeline_aids_its_steps(peer):
    c = GpsdClient("127.0.0.1", peer.port)
    clock = _Clock()
    link = GpsdLink(c, GpsAiding(), clock)
    p = Pipeline(
        PipelineConfig(setup=MethodSetup(bias=given_bias(SensorModel().to_dps_scalar(32768, 0)))),
        link.aiding,
        clock,
    )
    try:
        link.poll(p)
        peer.accept()
        deadline = time.monotonic() + WAIT
        while not c.connected and time.monotonic() < deadline:
            link.poll(p)
        peer.send(REAL_TPV + "\n")
        clock.now = 1.0
        while p.stepper.speed_mps is None and time.monotonic() < deadline:
            link.poll(p)
        assert p.stepper.speed_mps == pytest.approx(10.289)
        clock.now = 1.2
        (out,) = _steps(p, 0, 1)
        assert out["mode"] == AIDED and out["heading"] == pytest.approx(31.0)
        assert out["gps_course"] == 31.0
        clock.now = 10.0
        link.poll(p)  # the fix is stale now
        assert p.stepper.speed_mps is None
        (out,) = _steps(p, 1, 1)
        assert out["mode"] == "dead-reckoning" and out["heading"] == pytest.approx(31.0)
    finally:
        link.close()
    assert c.closed


def test_link_from_config_takes_the_aiding_keys():
    from hdrd.config import Config
    from hdrd.configload import apply_overrides

    cfg = apply_overrides(
        Config(),
        {
            "gpsd.enabled": True,
            "gpsd.min_speed_mps": 3.0,
            "gpsd.max_fix_age_s": 1.5,
            "gpsd.max_epd_deg": 8.0,
            "gpsd.align_gain": 0.5,
            "gpsd.bias_window_s": 45.0,
            "gpsd.bias_gain": 0.1,
            "gpsd.device": "/dev/ttyUSB1",
        },
    )
    link = GpsdLink.from_config(cfg.gpsd, step_s=0.5)
    try:
        a = link.aiding.config
        assert (a.min_speed_mps, a.max_fix_age_s, a.max_epd_deg) == (3.0, 1.5, 8.0)
        assert (a.align_gain, a.bias_window_s, a.bias_gain, a.step_s) == (0.5, 45.0, 0.1, 0.5)
        assert a.device == "/dev/ttyUSB1" and link.aiding.device == "/dev/ttyUSB1"
    finally:
        link.close()
    # empty (the default): the first receiver with a fix
    link = GpsdLink.from_config(Config().gpsd)
    try:
        assert link.aiding.config.device is None
    finally:
        link.close()


def test_bad_lines_are_logged_at_most_every_10_s_with_their_count(peer) -> None:
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.0))))
    link, c = connected_link(peer, p)
    try:
        with capture_logs() as logs:
            peer.send("garbage one\n")
            deadline = time.monotonic() + WAIT
            while c.stats.bad_lines < 1 and time.monotonic() < deadline:
                link.poll(p, now=100.0)
            peer.send("garbage two\ngarbage three\n")
            while c.stats.bad_lines < 3 and time.monotonic() < deadline:
                link.poll(p, now=105.0)  # within 10 s of the first warning: counted, not logged
            link.poll(p, now=109.9)
            link.poll(p, now=110.0)
            link.poll(p, now=200.0)  # nothing new: nothing logged
        warned = [e for e in logs if e["event"] == "gpsd_bad_lines"]
        assert [(e["total"], e["new"]) for e in warned] == [(1, 1), (3, 2)]
        assert all(e["log_level"] == "warning" and "garbage" in e["last"] for e in warned)
    finally:
        link.close()


def test_each_change_of_mode_is_logged_once(peer) -> None:
    clock = _Clock()
    p = Pipeline(
        PipelineConfig(setup=MethodSetup(bias=given_bias(SensorModel().to_dps_scalar(32768, 0))))
    )
    link, _ = connected_link(peer, p)
    link._clock = clock
    p.set_aiding(link.aiding, clock)
    try:
        with capture_logs() as logs:
            peer.send(REAL_TPV + "\n")
            deadline = time.monotonic() + WAIT
            clock.now = 1.0
            while p.stepper.speed_mps is None and time.monotonic() < deadline:
                link.poll(p)
            for k, now in enumerate((1.2, 1.4, 1.6)):
                clock.now = now
                link.log_mode(_steps(p, k, 1))
            clock.now = 10.0
            link.poll(p)  # the fix is stale: dead reckoning from here
            for k, now in enumerate((10.0, 11.0), start=3):
                clock.now = now
                link.log_mode(_steps(p, k, 1))
        modes = [e for e in logs if e["event"] == "gps_mode"]
        assert [e["mode"] for e in modes] == [AIDED, "dead-reckoning"]
        assert modes[0]["gps_course"] == 31.0 and modes[0]["heading"] == pytest.approx(31.0)
    finally:
        link.close()
