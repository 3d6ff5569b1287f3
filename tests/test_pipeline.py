"""The pure pipeline: frames -> deg/s -> blocks -> HDR -> messages."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.core import hdr
from hdrd.core.calibrate import given_bias
from hdrd.core.hdr import HdrParams
from hdrd.core.methods import MethodSetup
from hdrd.core.sensor import SensorModel
from hdrd.daemon.pipeline import Pipeline
from hdrd.daemon.stepper import PipelineConfig, heading_from_yaw

CAPTURE_DTYPE = np.dtype(
    [("seq", "<u2"), ("t_us", "<u4"), ("rate", "<u2"), ("ref", "<u2"), ("temp", "<i2")]
)


@dataclass(frozen=True)
class F:
    seq: int
    t_us: int
    rate: int
    ref: int = 0
    temp_cc: int | None = None

    @property
    def temp_c(self) -> float | None:
        return None if self.temp_cc is None else self.temp_cc / 100


def make_frames(
    omega_dps: np.ndarray, hz: float = 10.0, t0_us: int = 0, temp_cc: int | None = None
) -> list[F]:
    counts = SensorModel().to_counts(omega_dps)
    dt = round(1e6 / hz)
    return [
        F(i & 0xFFFF, (t0_us + i * dt) % 2**32, int(c), 0, temp_cc) for i, c in enumerate(counts)
    ]


def to_array(frames: list[F]) -> np.ndarray:
    a = np.zeros(len(frames), CAPTURE_DTYPE)
    a["seq"] = [f.seq for f in frames]
    a["t_us"] = [f.t_us for f in frames]
    a["rate"] = [f.rate for f in frames]
    a["ref"] = [f.ref for f in frames]
    a["temp"] = [-32768 if f.temp_cc is None else f.temp_cc for f in frames]
    return a


def run_live(p: Pipeline, frames: list[F], bad: list[int] | None = None) -> list[dict]:
    out: list[dict] = []
    for i, f in enumerate(frames):
        out.extend(p.feed(f, bad[i] if bad else 0))
    out.extend(p.finish(bad[-1] if bad else 0))
    return out


def test_known_profile_matches_hdr_core():
    rng = np.random.default_rng(4)
    bias = 0.8
    omega = bias + rng.normal(0, 0.3, 600)  # 60 s at 10 Hz, straight with drift
    omega[300:330] += 15.0  # a 3 s turn
    frames = make_frames(omega)
    p = Pipeline(PipelineConfig(heading0_deg=90.0, setup=MethodSetup(bias=given_bias(bias))))
    msgs = run_live(p, frames)
    assert [m["step"] for m in msgs] == list(range(60))
    sensor = SensorModel()
    w = sensor.to_dps_array(np.array([f.rate for f in frames]), 0)
    means = w.reshape(60, 10).mean(axis=1)
    np.testing.assert_allclose([m["omega_raw"] for m in msgs], means, rtol=0, atol=1e-12)
    trace = hdr.run_batch(np.array([m["omega_raw"] for m in msgs]) - bias)
    assert [m["yaw"] for m in msgs] == trace.yaw.tolist()
    assert [m["I"] for m in msgs] == trace.I.tolist()
    assert [m["W"] for m in msgs] == trace.W.tolist()
    assert [m["heading"] for m in msgs] == [heading_from_yaw(90.0, y) for y in trace.yaw]
    assert all(m["samples"] == 10 for m in msgs)
    assert {m["status"] for m in msgs[30:34]} == {"turning"}
    assert msgs[0]["t"] == 1.0 and msgs[-1]["t"] == 60.0
    for m in msgs:
        assert "time" not in m  # no clock given: left out, never null
        assert m["class"] == "HDR" and m["v"] == 1
        assert "temp" not in m  # not fitted: left out


def test_startup_calibration_then_steps():
    rng = np.random.default_rng(1)
    bias = -0.37
    omega = bias + rng.normal(0, 0.05, 200)
    frames = make_frames(omega, temp_cc=2150)
    p = Pipeline(PipelineConfig(startup_s=2.0))
    msgs = run_live(p, frames)
    assert [m["status"] for m in msgs[:2]] == ["calibrating", "calibrating"]
    for m in msgs[:2]:
        for key in ("omega", "yaw", "heading", "I", "bias"):
            assert key not in m  # unknown while calibrating: left out
    w = SensorModel().to_dps_array(np.array([f.rate for f in frames[:20]]), 0)
    assert p.bias is not None
    assert p.bias.bias_dps == pytest.approx(float(np.mean(w)), abs=1e-12)
    assert msgs[2]["bias"] == p.bias.bias_dps
    assert msgs[2]["yaw"] == msgs[2]["omega"]  # first HDR step starts from yaw 0
    assert msgs[2]["temp"] == pytest.approx(21.5)
    assert ("calibrated",) == tuple(e[0] for e in p.events)


def test_startup_calibration_rejects_motion_and_retries():
    omega = np.concatenate([np.linspace(0, 20, 10), np.full(10, 0.2)])  # turning, then still
    p = Pipeline(PipelineConfig(startup_s=1.0))
    msgs = run_live(p, make_frames(omega) + make_frames(np.full(10, 0.2), t0_us=2_000_000))
    assert msgs[0]["status"] == "calibrating"
    assert p.events[0][0] == "calibration_rejected"
    assert "moved" in p.events[0][1]["reason"]
    assert p.bias is not None and p.bias.bias_dps == pytest.approx(0.2, abs=0.01)
    assert msgs[-1]["status"] == "ok"


def test_gap_reported_and_steps_not_invented():
    omega = np.zeros(100)
    frames = make_frames(omega)
    frames = frames[:30] + frames[65:]  # 3.5 s of frames lost
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.0))))
    msgs = run_live(p, frames)
    steps = [m["step"] for m in msgs]
    assert steps == [0, 1, 2, 6, 7, 8, 9]
    assert msgs[3]["gap_s"] == pytest.approx(3.0)
    assert "gap_s" not in msgs[4]
    assert msgs[3]["samples"] == 5  # a dropped frame shortens its block


def test_clock_wrap_inside_capture():
    omega = np.full(50, 1.5)
    frames = make_frames(omega, t0_us=2**32 - 1_250_000)
    p = Pipeline(
        PipelineConfig(setup=MethodSetup(hdr=HdrParams(enabled=False), bias=given_bias(0.0)))
    )
    msgs = run_live(p, frames)
    assert [m["step"] for m in msgs] == [0, 1, 2, 3, 4]
    assert all(m["samples"] == 10 for m in msgs)
    assert p.clock.wraps == 1


def test_resync_keeps_heading_and_numbers():
    p = Pipeline(
        PipelineConfig(setup=MethodSetup(hdr=HdrParams(enabled=False), bias=given_bias(0.0)))
    )
    first = run_live_no_finish(p, make_frames(np.full(31, 2.0)))
    resumed = p.resync(gap_s=7.5)
    # the device comes back with its clock restarted
    after = run_live(p, make_frames(np.full(21, 2.0), t0_us=123))
    msgs = first + resumed + after
    steps = [m["step"] for m in msgs]
    # 7.5 s out: 7 steps skipped (not invented), then the numbers go on
    assert steps == list(range(len(first) + len(resumed))) + [
        s + 7 for s in range(len(first) + len(resumed), len(msgs))
    ]
    yaws = [m["yaw"] for m in msgs]
    assert all(b > a for a, b in zip(yaws, yaws[1:]))  # heading continuous, no reset
    assert after[0]["gap_s"] == 7.5
    ts = [m["t"] for m in msgs]
    assert all(b > a for a, b in zip(ts, ts[1:]))
    assert after[0]["t"] - resumed[-1]["t"] == 7.0 + 1.0


def run_live_no_finish(p: Pipeline, frames: list[F]) -> list[dict]:
    out: list[dict] = []
    for f in frames:
        out.extend(p.feed(f))
    return out


def test_stale_message_holds_heading_without_a_step():
    p = Pipeline(PipelineConfig(heading0_deg=10.0, setup=MethodSetup(bias=given_bias(0.0))))
    run_live(p, make_frames(np.full(30, -3.0)))
    m = p.stale_message(now=1234.5, silent_s=4.2, bad_frames=3)
    assert m["status"] == "stale" and m["stale_s"] == 4.2 and m["time"] == 1234.5
    assert m["heading"] == heading_from_yaw(p.config.heading0_deg, p.stepper.yaw)
    assert "omega" not in m


def test_saturation_is_flagged():
    omega = np.full(20, 250.0)  # beyond the CRS03-04's 200 deg/s
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.0))))
    msgs = run_live(p, make_frames(omega))
    assert msgs[0]["saturated"] == 10


def test_method_none_is_plain_integration():
    omega = np.full(100, 0.5)
    p = Pipeline(PipelineConfig(setup=MethodSetup(method="none", bias=given_bias(0.0))))
    msgs = run_live(p, make_frames(omega))
    assert all(m["I"] == 0.0 for m in msgs)
    w = SensorModel().to_dps_scalar(make_frames(omega)[0].rate)
    assert msgs[-1]["yaw"] == pytest.approx(10 * w)


def test_reconfigure_keeps_state_and_refuses_new_T():
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.1))))
    run_live_no_finish(p, make_frames(np.full(50, 0.4)))
    before = p.stepper.state
    p.reconfigure(PipelineConfig(setup=MethodSetup(hdr=HdrParams(i_c=0.1), bias=given_bias(0.1))))
    assert p.stepper.state == before
    with pytest.raises(ValueError, match="T"):
        p.reconfigure(PipelineConfig(setup=MethodSetup(hdr=HdrParams(T=2.0), bias=given_bias(0.1))))


@st.composite
def captures(draw):
    n = draw(st.integers(1, 400))
    hz = draw(st.sampled_from([5.0, 10.0, 50.0, 100.0]))
    dt = round(1e6 / hz)
    t0 = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(draw(st.integers(0, 2**31)))
    steps = np.full(n, dt, np.int64)
    # occasional gaps (lost frames / unplugged) and jitter
    gaps = rng.random(n) < 0.02
    steps[gaps] += rng.integers(dt, 5_000_000, int(gaps.sum()))
    steps += rng.integers(-dt // 10, dt // 10 + 1, n)
    t = (t0 + np.cumsum(steps) - steps[0]) % 2**32
    rate = rng.integers(0, 65536, n)
    ref = np.where(rng.random(n) < 0.3, rng.integers(20000, 40000, n), 0)
    temp = np.where(rng.random(n) < 0.5, rng.integers(-2000, 6000, n), -32768)
    a = np.zeros(n, CAPTURE_DTYPE)
    a["seq"] = np.arange(n) & 0xFFFF
    a["t_us"], a["rate"], a["ref"], a["temp"] = t, rate, ref, temp
    bad = np.cumsum(rng.random(n) < 0.05)
    bias = draw(st.one_of(st.none(), st.floats(-3, 3)))
    startup = draw(st.sampled_from([0.5, 1.0, 3.0]))
    method = draw(st.sampled_from(["none", "hdr", "hdr+"]))
    return a, bad, bias, startup, method


@settings(max_examples=60, deadline=None)
@given(captures())
def test_array_path_is_bit_identical_to_live(cap):
    a, bad, bias, startup, method = cap
    limits_loose = PipelineConfig().limits.__class__(1e9, 1e9, 1e9)
    cfg = PipelineConfig(
        startup_s=startup,
        limits=limits_loose,
        setup=MethodSetup(method=method, bias=given_bias(bias)),
    )
    live = Pipeline(cfg)
    frames = [
        F(
            int(r["seq"]),
            int(r["t_us"]),
            int(r["rate"]),
            int(r["ref"]),
            None if r["temp"] == -32768 else int(r["temp"]),
        )
        for r in a
    ]
    expected = run_live(live, frames, bad.tolist())
    fast = Pipeline(cfg)
    got = fast.feed_array(a, bad)
    got.extend(fast.finish(int(bad[-1])))
    assert got == expected
    for m in got:
        for v in m.values():
            assert not (isinstance(v, float) and math.isnan(v))


def test_hdr_plus_zero_rate_update_at_standstill():
    rng = np.random.default_rng(3)
    bias = 0.5
    omega = bias + 0.1 + rng.normal(0, 0.05, 400)  # 0.1 deg/s of drift beyond eps0
    p = Pipeline(PipelineConfig(setup=MethodSetup(method="hdr+", bias=given_bias(bias))))
    p.set_speed(0.0)  # gpsd says the vehicle stands still
    msgs = run_live(p, make_frames(omega))
    still = [m for m in msgs if m["zupt"] == 1]
    assert len(still) > 30 and all(m["status"] == "standstill" and m["omega"] == 0.0 for m in still)
    # The yaw does not turn at standstill; it moves only by HDR+'s heading fix, back towards
    # the truth (0) by the drift the first steps integrated before the stop was known.
    assert abs(msgs[-1]["yaw"]) <= abs(msgs[5]["yaw"])
    # eps0 refined from the stop: a stop reads the rest bias, each stop with a scatter of its
    # own (stop_scatter_dps), so one stop moves the driving bias most of the way, not all
    assert 0.57 <= msgs[-1]["bias"] <= 0.6
    ref = Pipeline(PipelineConfig(setup=MethodSetup(method="hdr", bias=given_bias(bias))))
    plain = run_live(ref, make_frames(omega))
    assert all(m["omega"] != 0.0 for m in plain[5:])  # paper HDR has no zero-rate update
    assert "zupt" not in plain[0] and "model" not in plain[0]
    # which error model is in force: a given bias without a record, no noise model
    assert {m["model"] for m in msgs} == {"defaults"} and msgs[-1]["bias_sd"] > 0.0


def test_hdr_plus_publishes_the_error_model_it_is_fitted_to() -> None:
    # A configured grade (a known error model): published as such; a tactical-grade gyro's
    # bias wanders too little to move on a straight road read with a gyro's noise. Measured
    # at start-up without one: fitted to the calibration window.
    from hdrd.core.methods import MethodSetup

    rng = np.random.default_rng(5)
    omega = 0.3 + rng.normal(0, 0.02, 600)
    tactical = MethodSetup(grade="tactical")
    known = Pipeline(PipelineConfig(setup=replace(tactical, method="hdr+", bias=given_bias(0.3))))
    msgs = run_live(known, make_frames(omega))
    assert {m["model"] for m in msgs} == {"grade tactical"}
    assert all("I" not in m for m in msgs)  # HDR+ has no paper controller
    assert all(abs(m["bias"] - 0.3) < 0.002 for m in msgs)
    measured = Pipeline(PipelineConfig(startup_s=5.0, setup=MethodSetup(method="hdr+")))
    got = [m for m in run_live(measured, make_frames(omega)) if "yaw" in m]
    assert got and {m["model"] for m in got} == {"calibration"}


@pytest.mark.parametrize(("from_gyro", "enabled"), [(False, True), (True, True), (True, False)])
def test_standstill_from_gyro_alone_is_a_config_switch(from_gyro: bool, enabled: bool) -> None:
    # No speed source: a stop can only be seen in the gyro's own statistics, and only when
    # the config says so (standstill.from_gyro); standstill.enabled false switches stops off.
    from hdrd.configload import parse_config
    from hdrd.daemon.pipeline import pipeline_config

    cfg = parse_config(
        {"hdr": {"method": "hdr+"}, "standstill": {"enabled": enabled, "from_gyro": from_gyro}}
    )
    pc = pipeline_config(cfg, given_bias(0.5))
    rng = np.random.default_rng(4)
    omega = 0.5 + rng.normal(0, 0.05, 400)  # 40 s parked, 10 Hz, eps0 known
    msgs = run_live(Pipeline(pc), make_frames(omega))
    still = [m for m in msgs if m["zupt"] == 1]
    if from_gyro and enabled:
        assert len(still) > 20 and all(m["omega"] == 0.0 for m in still)
        # (the yaw moves at a stop only by HDR+'s heading fix, towards the truth, 0)
        assert abs(msgs[-1]["yaw"]) <= abs(msgs[12]["yaw"])
    else:
        assert still == []


def test_switching_method_keeps_the_heading():
    p = Pipeline(PipelineConfig(setup=MethodSetup(method="hdr", bias=given_bias(0.0))))
    a = run_live_no_finish(p, make_frames(np.full(100, 1.0)))
    p.reconfigure(PipelineConfig(setup=MethodSetup(method="hdr+", bias=given_bias(0.0))))
    b = run_live(p, make_frames(np.full(50, 1.0), t0_us=10_000_000))
    assert b[0]["yaw"] - a[-1]["yaw"] == pytest.approx(1.0, abs=0.2)
    assert "zupt" in b[0] and "zupt" not in a[-1]


# -- the published message, field by field; the pacing helpers; the configuration's wiring -----


def test_a_step_message_has_every_field_under_its_name() -> None:
    rng = np.random.default_rng(8)
    bias = 0.5
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(bias))))
    msgs = []
    for f in make_frames(bias + rng.normal(0.0, 0.3, 200), temp_cc=2150):
        msgs.extend(p.feed(f, 4, now=1000.0))
    trace = hdr.run_batch(np.array([m["omega_raw"] for m in msgs]) - bias)
    assert [m["R"] for m in msgs] == trace.R.tolist()
    assert [m["r"] for m in msgs] == trace.r.tolist() and max(trace.r) > 1
    m = msgs[-1]
    assert list(m)[:2] == ["class", "v"] and m["class"] == "HDR" and m["v"] == 1
    assert m["time"] == 1000.0 and m["bad_frames"] == 4 and m["bias"] == bias
    assert m["temp"] == 21.5 and "gap_s" not in m
    assert {"omega", "yaw", "heading", "I", "W", "R", "r", "samples", "status"} <= set(m)


def test_gaps_add_up_until_the_next_step_reports_them() -> None:
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.0))))
    frames = make_frames(np.zeros(100))
    # two gaps: the steps of 2-3 s and 4-5 s get no sample; each is reported by the next step
    msgs = run_live(p, frames[:20] + frames[35:36] + frames[56:])
    assert [m["step"] for m in msgs] == [0, 1, 3, 5, 6, 7, 8, 9]
    assert [m.get("gap_s") for m in msgs[2:4]] == [1.0, 1.0] and "gap_s" not in msgs[4]


def test_the_stale_message_names_its_fields() -> None:
    p = Pipeline(PipelineConfig(heading0_deg=10.0, setup=MethodSetup(bias=given_bias(0.25))))
    run_live(p, make_frames(np.full(30, 0.25)))
    m = p.stale_message(now=None, silent_s=1.0, bad_frames=7)
    assert m["class"] == "HDR" and m["v"] == 1 and "time" not in m
    assert m["yaw"] == p.stepper.yaw and m["bias"] == 0.25 and m["bad_frames"] == 7
    assert m["step"] == 2


def test_sample_interval_and_time_to_the_next_step() -> None:
    p = Pipeline(PipelineConfig(setup=MethodSetup(hdr=HdrParams(T=1.0), bias=given_bias(0.0))))
    frames = make_frames(np.zeros(14), hz=10.0)
    assert p.sample_interval_s() is None and p.until_step_s() is None
    for f in frames[:11]:  # one step closed; the open block [1 s, 2 s) holds the 1.0 s sample
        p.feed(f)
    assert p.sample_interval_s() is None  # one sample in the open block: no interval yet
    p.feed(frames[11])
    p.feed(frames[12])
    assert p.sample_interval_s() == pytest.approx(0.1)  # (1.2 - 1.0) s over two intervals
    # from the last sample (1.2 s) to one interval before the block ends (2.0 s)
    assert p.until_step_s() == pytest.approx(2.0 - 1.2 - 0.1)


def test_a_bias_adjustment_is_recorded_and_moves_eps0() -> None:
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.5))))
    p.adjust_bias(0.0, "gps")
    assert p.stepper.events == [] and p.stepper.bias is not None
    p.adjust_bias(0.125, "gps")
    assert p.stepper.bias.bias_dps == 0.625
    assert p.stepper.events[-1] == (
        "bias_adjusted",
        {"delta_dps": 0.125, "bias_dps": 0.625, "source": "gps"},
    )
    cal = Pipeline(PipelineConfig())  # still calibrating: nothing to adjust
    cal.adjust_bias(0.1, "gps")
    assert cal.stepper.bias is None and cal.stepper.events == []


def test_reconfigure_names_what_cannot_change() -> None:
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.0))))
    with pytest.raises(ValueError, match="^hdr.T cannot change while running; restart"):
        p.reconfigure(PipelineConfig(setup=MethodSetup(hdr=HdrParams(T=2.0), bias=given_bias(0.0))))


def test_a_configured_bias_has_no_spread_and_a_recorded_one_keeps_its_own() -> None:
    from hdrd.config import Config
    from hdrd.core.calibrate import BiasRecord
    from hdrd.core.gyronoise import GyroNoise
    from hdrd.daemon.pipeline import pipeline_config

    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.3))))
    assert p.stepper.bias == BiasRecord(0.3, 0.0, 0, 0.0)
    noise = GyroNoise(white_dps_per_rthz=0.05, rrw_dps_per_sqrt_s=3e-4, quant_step_dps=0.0076)
    rec = BiasRecord(0.42, 0.1, 300, 30.0, None, 1.0, noise)
    pc = pipeline_config(Config(), rec)
    assert pc.setup.bias is rec  # one route: the record is the bias
    # the recorded error model is the one HDR+ is fitted to
    hp = Pipeline(replace(pc, setup=replace(pc.setup, method="hdr+")))
    run_live(hp, make_frames(np.full(30, 0.42)))
    assert hp.stepper.settings.model == noise.source
    assert pipeline_config(Config()).setup.bias is None


# -- the health of the heading and the link (bias_source, calib_age_s, frames, reconnects) ----


def test_bias_source_says_what_last_changed_the_bias() -> None:
    omega = np.full(100, 0.2)
    p = Pipeline(PipelineConfig(startup_s=1.0))  # measured at start-up
    first = p.feed_array(to_array(make_frames(omega)))
    steps = [m for m in first if "yaw" in m]
    assert steps and "bias_source" not in first[0]  # calibrating: no bias yet
    assert p.bias is not None
    measured = p.bias.bias_dps  # the start-up window's mean
    assert measured == pytest.approx(0.2, abs=SensorModel().lsb_dps)
    assert {(m["bias"], m["bias_source"]) for m in steps} == {(measured, "calibration")}
    p.adjust_bias(0.01, "gps")
    later = p.feed_array(to_array(make_frames(omega, t0_us=10_000_000)))
    assert later and {(m["bias"], m["bias_source"]) for m in later} == {(measured + 0.01, "gps")}
    stale = p.stale_message(1.0e9, 3.0)
    assert (stale["bias"], stale["bias_source"]) == (measured + 0.01, "gps")
    p.reconfigure(
        PipelineConfig(startup_s=1.0, setup=MethodSetup(bias=given_bias(0.3)))
    )  # a new bias from the config
    held = p.stale_message(1.0e9, 3.0)  # no step since: the last step's bias and its source
    assert (held["bias"], held["bias_source"]) == (measured + 0.01, "gps")
    after = p.feed_array(to_array(make_frames(omega, t0_us=20_000_000)))
    assert after and {(m["bias"], m["bias_source"]) for m in after} == {(0.3, "calibration")}
    # HDR+ standing still: its zero-rate updates move the bias
    plus = Pipeline(PipelineConfig(setup=MethodSetup(method="hdr+", bias=given_bias(0.5))))
    plus.set_speed(0.0)
    msgs = run_live(plus, make_frames(0.6 + np.random.default_rng(3).normal(0, 0.05, 400)))
    assert msgs[-1]["zupt"] == 1 and msgs[-1]["bias_source"] == "stops"


def test_calibration_age_by_the_host_clock_and_absent_when_unknown() -> None:
    from hdrd.core.calibrate import BiasRecord

    frames = make_frames(np.full(60, 0.2))
    p = Pipeline(PipelineConfig(startup_s=1.0))
    msgs = []
    for i, f in enumerate(frames):  # the host clock: 1000 s + 0.1 s per frame
        msgs.extend(p.feed(f, 0, 1000.0 + 0.1 * i))
    ages = [m.get("calib_age_s") for m in msgs]
    assert ages[0] is None  # calibrating
    assert ages[1] == 1.0 and ages[-1] == pytest.approx(len(ages) - 1, abs=1e-6)
    replayed = Pipeline(PipelineConfig(startup_s=1.0)).feed_array(to_array(frames))
    assert not [m for m in replayed if "calib_age_s" in m]  # no host clock
    rec = BiasRecord(0.2, 0.01, 600, 60.0, None, 500.0)  # a bias file measured at 500 s
    filed = Pipeline(PipelineConfig(setup=MethodSetup(bias=rec)))
    assert [m["calib_age_s"] for m in filed.feed(frames[0], 0, 800.0) + filed.finish(0, 801.5)] == [
        301.5
    ]
    assert filed.stale_message(802.0, 3.0)["calib_age_s"] == 302.0
    given = Pipeline(
        PipelineConfig(setup=MethodSetup(bias=given_bias(0.2)))
    )  # --bias: when is not known
    assert [m for m in run_live(given, frames) if "calib_age_s" in m] == []


def test_frames_and_reconnects_count_the_link_alike_live_and_replayed() -> None:
    frames = make_frames(np.full(95, 0.1))
    live = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.1))))
    msgs = run_live(live, frames)
    assert [m["frames"] for m in msgs] == [11, 21, 31, 41, 51, 61, 71, 81, 91, 95]
    assert {m["reconnects"] for m in msgs} == {0}
    fast = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.1))))
    assert [m["frames"] for m in fast.feed_array(to_array(frames)) + fast.finish()] == [
        m["frames"] for m in msgs
    ]
    back = live.resync(2.0)
    assert live.reconnects == 1 and back == []
    more = run_live(live, make_frames(np.full(20, 0.1)))
    assert {m["reconnects"] for m in more} == {1} and more[-1]["frames"] == 115
    stale = live.stale_message(1.0e9, 3.0)
    assert stale["frames"] == 115 and stale["reconnects"] == 1


# -- a stale report holds the last step's values ----------------------------------------------

# What a stale report says of itself (not a step) and the link's counters (frames of the open
# step came since): the rest of its fields are the last step's.
STALE_OWN = {"time", "status", "stale_s", "bad_frames", "calib_age_s", "frames"}


@pytest.mark.parametrize("method", ["none", "hdr", "hdr+"])
@pytest.mark.parametrize("speed", [0.0, None])
def test_a_stale_report_publishes_the_last_steps_values(method: str, speed: float | None) -> None:
    """HDR+ at a standstill moves the bias by zero-rate updates (``bias_source: stops``); a
    stale report used to publish the static bias of start-up (0.5) under that label. Every
    field of a stale report is the step's before it, but those that say it is a report."""
    p = Pipeline(PipelineConfig(setup=MethodSetup(method=method, bias=given_bias(0.5))))
    p.set_speed(speed)
    msgs = [m for f in make_frames(np.full(200, 0.6)) for m in p.feed(f, 0, 1000.0)]
    last = msgs[-1]
    stale = p.stale_message(now=1004.0, silent_s=3.5, bad_frames=2)
    assert stale["status"] == "stale" and stale["stale_s"] == 3.5 and stale["bad_frames"] == 2
    for key in ("step", "yaw", "heading", "bias", "bias_source", "reconnects"):
        assert key in stale, key
    assert {k: v for k, v in stale.items() if k not in STALE_OWN} == {
        k: last[k] for k in stale if k not in STALE_OWN
    }
    if method == "hdr+" and speed == 0.0:  # the case that was wrong: a bias from the stops
        assert last["bias_source"] == "stops" and last["bias"] != 0.5


@pytest.mark.parametrize("method", ["hdr", "hdr+"])
def test_an_aided_stale_report_publishes_the_last_steps_values(method: str) -> None:
    """The same with GPS aiding: the held heading is the aligned one, the fix still fresh."""
    from hdrd.daemon.aiding import GpsAiding
    from hdrd.io.net.gpsdjson import Fix

    clock = [0.0]
    aiding = GpsAiding()
    cfg = PipelineConfig(heading0_deg=30.0, setup=MethodSetup(method=method, bias=given_bias(0.5)))
    p = Pipeline(cfg, aiding, lambda: clock[0])
    msgs = []
    for i, f in enumerate(make_frames(np.full(200, 0.55))):
        clock[0] = i / 10
        if i % 10 == 3:
            aiding.on_fix(Fix(mode=3, track_deg=100.0 + i / 100, speed_mps=12.0), clock[0])
        msgs.extend(p.feed(f, 0, 1000.0 + clock[0]))
    last = msgs[-1]
    assert last["mode"] == "aided" and "heading_offset" in last
    stale = p.stale_message(now=1021.0, silent_s=3.5)
    # the GPS as it stands at the report (a course came after the last step)
    own = STALE_OWN | {"gps_age_s", "gps_course", "gps_speed", "mode"}
    assert {k: v for k, v in stale.items() if k not in own} == {
        k: last[k] for k in stale if k not in own
    }
