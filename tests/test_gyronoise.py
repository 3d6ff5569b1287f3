"""The gyro error model HDR+ is fitted to (hdrd/core/gyronoise.py): its parameters by name, the
random walk derived from them, and what a standstill shows of them.

Rates in deg/s, + = CCW; white noise deg/s/sqrt(Hz); times s.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from hdrd.core.gyronoise import NOISE_KEYS, GyroNoise, grade_noise, measure_noise
from hdrd.sim.grades import grade_model


def test_parameters_by_name_round_trip_and_are_checked() -> None:
    g = grade_noise("tactical")
    assert g.source == "grade tactical" and g.known()
    again = GyroNoise.from_mapping(g.to_dict(), source="recorded")
    assert again.to_dict() == g.to_dict() and again.source == "recorded"
    # a grade says nothing of a unit's own motion offset or stop scatter
    unit_only = {"motion_offset_dps", "motion_offset_sd_dps", "stop_scatter_dps"}
    assert set(g.to_dict()) == set(NOISE_KEYS) - unit_only
    signed = GyroNoise.from_mapping({"motion_offset_dps": -0.09, "motion_offset_sd_dps": 0.004})
    assert signed.motion_offset_dps == -0.09 and signed.to_dict()["motion_offset_sd_dps"] == 0.004
    with pytest.raises(ValueError, match="motion_offset_sd_dps = -0.004"):
        GyroNoise.from_mapping({"motion_offset_sd_dps": -0.004})
    with pytest.raises(ValueError, match="motion_offset_dps = inf must be a finite number"):
        GyroNoise.from_mapping({"motion_offset_dps": float("inf")})
    with pytest.raises(ValueError, match="unknown noise parameter 'white'"):
        GyroNoise.from_mapping({"white": 0.1})
    with pytest.raises(ValueError, match="rrw_dps_per_sqrt_s = -1"):
        GyroNoise.from_mapping({"rrw_dps_per_sqrt_s": -1})
    with pytest.raises(ValueError, match="bias_tau_s = 0"):
        GyroNoise.from_mapping({"bias_tau_s": 0})
    with pytest.raises(ValueError, match="is not a number"):
        GyroNoise.from_mapping({"quant_step_dps": "fine"})
    with pytest.raises(ValueError, match="is not a number"):
        GyroNoise.from_mapping({"quant_step_dps": True})
    # white noise and a step alone do not say how the bias moves
    assert not GyroNoise(white_dps_per_rthz=0.01, quant_step_dps=0.06).known()
    assert GyroNoise().to_dict() == {"bias_tau_s": 100.0}


def test_random_walk_from_the_allan_parameters() -> None:
    g = GyroNoise(bias_instability_dps=0.62 * 0.01, bias_tau_s=300.0, rrw_dps_per_sqrt_s=3e-4)
    assert g.bias_q() == pytest.approx(9e-8 + 2 * 0.01**2 / 300.0)
    assert g.bias_q_no_temp() == g.bias_q()  # no temperature coefficient: no warm-up term
    warm = GyroNoise(rrw_dps_per_sqrt_s=1e-4, temp_coeff_dps_per_c=0.01)
    assert warm.bias_q_no_temp() == pytest.approx(1e-8 + (0.01 * 16.0) ** 2 / 900.0)
    assert math.isnan(GyroNoise().bias_q())


def _standstill(grade: str, seconds: float, hz: float, seed: int) -> np.ndarray:
    t = np.arange(0.0, seconds, 1.0 / hz)
    model = grade_model(grade, seed)
    out = model.apply(t, np.zeros_like(t), np.full_like(t, 20.0), np.random.default_rng(seed))
    return np.asarray(out)


def test_a_long_standstill_shows_the_bias_instability() -> None:
    # 40 minutes of the simulated tactical-grade IMU at rest: white noise, its output step,
    # the Allan floor (the grade's B = 5.6e-4 deg/s) and a random walk of the right order.
    truth = grade_noise("tactical")
    got = measure_noise(_standstill("tactical", 2400.0, 50.0, 2), 50.0)
    assert got.source == "recorded" and got.known()
    assert got.white_dps_per_rthz == pytest.approx(truth.white_dps_per_rthz, rel=0.15)
    assert got.quant_step_dps == pytest.approx(truth.quant_step_dps, rel=0.01)
    assert 0.5 < got.bias_instability_dps / truth.bias_instability_dps < 1.5
    assert 0.25 < got.bias_q() / truth.bias_q() < 4.0


def test_a_short_window_shows_only_white_noise_and_the_step() -> None:
    w = _standstill("phone", 30.0, 100.0, 3)
    got = measure_noise(w, 100.0)
    assert got.white_dps_per_rthz == pytest.approx(0.007, rel=0.25)
    assert got.quant_step_dps == pytest.approx(1 / 16.4, rel=0.01)
    assert math.isnan(got.bias_instability_dps) and not got.known()
    # one code at rest (a coarse ADC whose noise is below its step): no step seen, N = 0
    one = measure_noise(np.zeros(300), 10.0)
    assert one.white_dps_per_rthz == 0.0 and math.isnan(one.quant_step_dps)
    with pytest.raises(ValueError, match="2 or more finite samples"):
        measure_noise([1.0], 10.0)
    with pytest.raises(ValueError, match="rate > 0"):
        measure_noise([1.0, 2.0], 0.0)


def test_the_error_model_in_force_recorded_then_config_then_grade() -> None:
    from hdrd.config import method_setup
    from hdrd.configload import parse_config
    from hdrd.core.calibrate import BiasRecord
    from hdrd.core.gyronoise import noise_in_force
    from hdrd.core.methods import plus_settings

    assert noise_in_force() is None
    assert noise_in_force("phone").source == "grade phone"  # type: ignore[union-attr]
    given = noise_in_force("phone", {"rrw_dps_per_sqrt_s": 2e-4, "bias_tau_s": 300.0})
    assert given is not None and given.source == "config"
    assert given.rrw_dps_per_sqrt_s == 2e-4 and given.bias_tau_s == 100.0  # the grade's tau
    recorded = GyroNoise(rrw_dps_per_sqrt_s=1e-6, source="recorded")
    assert noise_in_force("phone", {}, recorded) == recorded
    # what a standstill recording cannot show (the motion offset) still comes from the config
    unit = {"motion_offset_dps": -0.09, "motion_offset_sd_dps": 0.004}
    both = noise_in_force("phone", unit, recorded)
    assert both is not None and both.source == "recorded" and both.motion_offset_dps == -0.09
    assert noise_in_force("none", {"motion_offset_dps": -0.09}) is None  # no sd: not given
    # a learned offset known better than the configured one is the one in force
    learned = GyroNoise(motion_offset_dps=-0.07, motion_offset_sd_dps=0.002, source="learned")
    got = noise_in_force("none", unit, None, learned)
    assert got is not None and got.source == "learned" and got.motion_offset_dps == -0.07
    vague = GyroNoise(motion_offset_dps=0.0, motion_offset_sd_dps=0.05, source="learned")
    assert noise_in_force("none", unit, None, vague).motion_offset_dps == -0.09  # type: ignore[union-attr]
    short = GyroNoise(white_dps_per_rthz=0.01, source="recorded")  # says nothing of the walk
    assert noise_in_force("phone", {}, short).source == "grade phone"  # type: ignore[union-attr]
    # the daemon's choice from its config and bias file, in the one place HDR+'s settings
    # are derived
    cfg = method_setup(parse_config({"gyro": {"grade": "tactical"}}))
    assert plus_settings(cfg).model == "grade tactical"
    rec = BiasRecord(0.1, 0.01, 100, 10.0, noise=recorded)
    assert plus_settings(replace(cfg, bias=rec)).model == "recorded"
    assert plus_settings(method_setup(parse_config({}))).model == "defaults"
    with pytest.raises(ValueError, match="unknown gyro grade"):
        noise_in_force("nav")


def test_replay_publishes_the_error_model_of_the_bias_file_and_the_config() -> None:
    # `hdrd replay --bias-file F` (and `hdrd run`) fits HDR+ to the noise recorded in F,
    # else to gyro.grade, and says which in every step.
    from hdrd.configload import parse_config
    from hdrd.core.calibrate import BiasRecord
    from hdrd.daemon.replay import replay_capture
    from hdrd.io.wire.capture import encode_array
    from hdrd.io.wire.codec import FRAME_DTYPE

    n = 600
    a = np.zeros(n, FRAME_DTYPE)
    a["seq"] = np.arange(n)
    a["t_us"] = np.arange(n) * 100_000
    a["rate"] = 32768 + np.random.default_rng(0).integers(-3, 4, n)
    data = encode_array(a)
    cfg = parse_config({"hdr": {"method": "hdr+"}, "gyro": {"grade": "automotive"}})
    known = GyroNoise(rrw_dps_per_sqrt_s=1e-5, source="recorded")
    rec = BiasRecord(0.0, 0.02, 300, 30.0, noise=known)
    for record, model in ((None, "grade automotive"), (rec, "recorded")):
        msgs = [m for m in replay_capture(data, cfg, 0.0, None, record) if "yaw" in m]
        assert msgs and {m["model"] for m in msgs} == {model}
