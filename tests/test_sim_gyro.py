"""The gyro error model: each effect on hand-made inputs, noise statistics by Allan deviation,
physical order, determinism, and the YAML/dict form with its error messages."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.core.allan import (
    allan_deviation,
    arw_from_adev,
    bias_instability_from_adev,
    gauss_markov_adev,
    rrw_from_adev,
)
from hdrd.core.sensor import SensorModel
from hdrd.sim.effects import (
    EFFECT_NAMES,
    EFFECTS,
    STREAMS,
    Bandwidth,
    BiasInstability,
    MotionOffset,
    Quantization,
    RateRandomWalk,
    Saturation,
    ScaleAsymmetry,
    ScaleFactor,
    StaticBias,
    StopOffset,
    TemperatureBias,
    TimeOffset,
    WarmupTransient,
    WhiteNoise,
    ar1,
    effect_from_dict,
)
from hdrd.sim.gyro import (
    DEFAULT_START_MODEL,
    GyroModel,
    crs03_default_model,
    load_model,
    save_model,
)
from hdrd.sim.gyrolimits import LIMITS

ISSUE_VOCABULARY = {
    "static_bias": {"bias_dps"},
    "white_noise": {"density_dps_per_rthz"},
    "bias_instability": {"sigma_dps", "tau_s"},
    "rate_random_walk": {"k_dps_per_sqrt_s"},
    "quantization": {"step_dps"},
    "temperature_bias": {"coeff_dps_per_c", "ref_temp_c", "quad_dps_per_c2"},
    "motion_offset": {"offset_dps", "moving_mps", "coeff_dps_per_mps"},
    "stop_offset": {"sd_dps", "moving_mps"},
    "warmup_transient": {"amplitude_dps", "tau_s"},
    "scale_factor": {"error"},
    "scale_asymmetry": {"pos_error", "neg_error"},
    "saturation": {"limit_dps"},
    "time_offset": {"delay_s"},
    "bandwidth": {"cutoff_hz"},
}


def test_each_stop_reads_its_own_offset_and_driving_none() -> None:
    t = np.arange(120.0)
    speed = np.where((t < 10) | ((t >= 40) & (t < 60)) | (t >= 100), 0.0, 10.0)
    y = GyroModel((StopOffset(0.02),)).apply(
        t, np.zeros(120), None, np.random.default_rng(3), speed
    )
    stops = [y[:10], y[40:60], y[100:]]
    assert all(np.all(s == s[0]) for s in stops)  # one offset a stop ...
    assert len({float(s[0]) for s in stops}) == 3  # ... each its own
    assert np.all(y[speed > 0.5] == 0.0)  # none while driving
    with pytest.raises(ValueError, match="stop_offset needs the vehicle's speed"):
        GyroModel((StopOffset(0.02),)).apply(t, np.zeros(120), None, np.random.default_rng(3))


def _run(
    model: GyroModel,
    x: np.ndarray,
    fs: float = 10.0,
    temp: np.ndarray | None = None,
    seed: int = 0,
    t0: float = 0.0,
) -> np.ndarray:
    t = t0 + np.arange(x.shape[0]) / fs
    return model.apply(t, x, temp, np.random.default_rng(seed))


def test_vocabulary_is_exactly_the_issues() -> None:
    assert {
        n: {
            p
            for p in effect_from_dict(
                {"name": n, **{q: min(1.0, LIMITS[n, q][1]) for q in ps}}
            ).params()
        }
        for n, ps in ISSUE_VOCABULARY.items()
    } == ISSUE_VOCABULARY
    assert set(EFFECT_NAMES) == set(ISSUE_VOCABULARY)
    assert list(EFFECT_NAMES) == [c.name for c in sorted(EFFECTS.values(), key=lambda c: c.order)]


# -- deterministic effects on hand-made inputs -------------------------------------------------

X = np.array([-250.0, -30.0, -0.5, 0.0, 0.25, 12.0, 199.0, 320.0])


def test_static_bias_adds_a_constant() -> None:
    np.testing.assert_array_equal(_run(GyroModel((StaticBias(0.3),)), X), X + 0.3)


def test_scale_factor_multiplies() -> None:
    np.testing.assert_allclose(_run(GyroModel((ScaleFactor(0.02),)), X), 1.02 * X, rtol=1e-15)


def test_scale_asymmetry_by_sign_of_true_rate() -> None:
    out = _run(GyroModel((ScaleAsymmetry(pos_error=0.01, neg_error=-0.03),)), X)
    expect = np.where(X > 0, 1.01 * X, 0.97 * X)
    np.testing.assert_allclose(out, expect, rtol=1e-15)
    assert out[X == 0][0] == 0.0


def test_saturation_clips() -> None:
    np.testing.assert_array_equal(_run(GyroModel((Saturation(200.0),)), X), np.clip(X, -200, 200))


def test_quantization_rounds_to_steps() -> None:
    step = SensorModel().lsb_dps
    out = _run(GyroModel((Quantization(step),)), X)
    k = out / step
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)
    assert np.max(np.abs(out - X)) <= step / 2 + 1e-12
    assert out[X == 0][0] == 0.0
    # Rounding is idempotent, and the default step is the 16-bit CRS03-04 LSB.
    np.testing.assert_array_equal(_run(GyroModel((Quantization(step),)), out), out)
    assert Quantization().step_dps == pytest.approx(5.0 / 65536 / 0.010)


def test_motion_offset_only_while_moving() -> None:
    """+ offset (+ coeff * speed) above the speed threshold, nothing at or below it; the sign
    as given (a negative offset reads less while driving)."""
    x = np.array([0.0, 2.0, -3.0, 0.0, 10.0, -0.5])
    v = np.array([0.0, 0.3, 0.5, 0.51, 10.0, 30.0])  # m/s
    moving = v > 0.5
    m = GyroModel((MotionOffset(offset_dps=0.09),))
    out = m.apply(np.arange(6.0), x, None, np.random.default_rng(0), speed_mps=v)
    np.testing.assert_array_equal(out, np.where(moving, x + 0.09, x))
    neg = GyroModel((MotionOffset(offset_dps=-0.2, moving_mps=2.0, coeff_dps_per_mps=0.001),))
    out = neg.apply(np.arange(6.0), x, None, np.random.default_rng(0), speed_mps=v)
    np.testing.assert_allclose(out, np.where(v > 2.0, x - 0.2 + 0.001 * v, x), atol=1e-15)
    assert out[5] == pytest.approx(-0.5 - 0.2 + 0.03)


def test_motion_offset_needs_the_speed_and_interpolates_its_gaps() -> None:
    m = GyroModel((MotionOffset(offset_dps=0.1),))
    t, x = np.arange(5.0), np.zeros(5)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="motion_offset needs the vehicle's speed"):
        m.apply(t, x, None, rng)
    with pytest.raises(ValueError, match="motion_offset needs the vehicle's speed"):
        m.apply(t, x, None, rng, speed_mps=np.full(5, np.nan))  # no speed at all
    with pytest.raises(ValueError, match="speed_mps must have one value per sample"):
        m.apply(t, x, None, rng, speed_mps=np.zeros(4))
    v = np.array([0.0, np.nan, 2.0, np.nan, np.nan])  # gaps: 1.0, then held at 2.0
    np.testing.assert_array_equal(m.apply(t, x, None, rng, speed_mps=v), [0, 0.1, 0.1, 0.1, 0.1])
    # Models without it ignore the speed.
    plain = GyroModel((StaticBias(0.3),))
    np.testing.assert_array_equal(plain.apply(t, x, None, rng, speed_mps=np.ones(5)), x + 0.3)
    with pytest.raises(ValueError, match="moving_mps: -1.0 must be >= 0"):
        MotionOffset(offset_dps=0.1, moving_mps=-1.0)


def test_time_offset_lags_the_truth() -> None:
    fs = 100.0
    t = np.arange(2000) / fs
    x = np.sin(2 * math.pi * 0.5 * t) * 10.0
    out = GyroModel((TimeOffset(0.25),)).apply(t, x, None, np.random.default_rng(0))
    inner = t >= 0.25
    np.testing.assert_allclose(
        out[inner], 10 * np.sin(2 * math.pi * 0.5 * (t[inner] - 0.25)), atol=0.02
    )
    # Before the record starts the first true value is held.
    assert np.all(out[~inner] == x[0])
    # On a ramp the lag is exact.
    ramp = GyroModel((TimeOffset(0.3),)).apply(t, 2.0 * t, None, np.random.default_rng(0))
    np.testing.assert_allclose(ramp[t >= 0.3], 2.0 * (t[t >= 0.3] - 0.3), atol=1e-12)


def test_warmup_transient_from_power_on() -> None:
    out = _run(GyroModel((WarmupTransient(0.2, 60.0),)), np.zeros(1200), t0=1000.0)
    t = np.arange(1200) / 10.0
    np.testing.assert_allclose(out, 0.2 * np.exp(-t / 60.0), rtol=1e-12)


def test_temperature_bias_linear_and_quadratic() -> None:
    temp = np.array([5.0, 15.0, 25.0, 35.0, np.nan, 45.0])
    out = _run(GyroModel((TemperatureBias(0.01, 25.0, -0.001),)), np.zeros(6), temp=temp)
    filled = np.array([5.0, 15.0, 25.0, 35.0, 40.0, 45.0])  # NaN gap interpolated
    d = filled - 25.0
    np.testing.assert_allclose(out, 0.01 * d - 0.001 * d * d, rtol=1e-12)
    with pytest.raises(ValueError, match="temperature"):
        _run(GyroModel((TemperatureBias(0.01, 25.0),)), np.zeros(6))
    with pytest.raises(ValueError, match="one value per sample"):
        _run(GyroModel((TemperatureBias(0.01, 25.0),)), np.zeros(6), temp=np.zeros(5))


def test_bandwidth_step_response_and_dc_gain() -> None:
    fs, fc = 1000.0, 10.0
    x = np.concatenate((np.zeros(10), np.ones(400)))
    out = _run(GyroModel((Bandwidth(fc),)), x, fs=fs)
    a = math.exp(-2 * math.pi * fc / fs)
    k = np.arange(1, 401)
    np.testing.assert_allclose(out[10:], 1.0 - a**k, atol=1e-12)
    # One time constant 1 / (2 pi fc) after the step: 1 - 1/e.
    i = 10 + round(fs / (2 * math.pi * fc))
    assert out[i - 1] == pytest.approx(1 - math.exp(-1), abs=0.01)
    assert out[-1] == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("sections", [1, 2, 3])
def test_bandwidth_sections_are_3_db_down_at_the_cutoff(sections: int) -> None:
    """Equal first-order sections, each at the cutoff that puts the whole filter 3 dB down at
    cutoff_hz; unit gain at DC; written to a model file only when more than one."""
    fs, fc = 100.0, 2.0
    t = np.arange(0.0, 60.0, 1.0 / fs)
    bw = Bandwidth(fc, sections=sections)
    for f, want in ((fc, 1.0 / math.sqrt(2.0)), (0.0, 1.0)):
        x = np.cos(2.0 * math.pi * f * t)
        out = _run(GyroModel((bw,)), x, fs=fs)[len(t) // 2 :]
        assert float(np.max(np.abs(out))) == pytest.approx(want, rel=0.01)
    d = GyroModel((bw,)).to_dict()["effects"][0]
    assert ("sections" in d) == (sections > 1)
    assert GyroModel.from_dict({"effects": [d]}) == GyroModel((bw,))
    with pytest.raises(ValueError, match="sections"):
        Bandwidth(fc, sections=5)


def test_ar1_matches_a_plain_loop_on_irregular_steps() -> None:
    rng = np.random.default_rng(5)
    dt = rng.uniform(0.01, 3.0, 3000)
    u = rng.standard_normal(3000)
    for tau in (0.005, 0.4, 30.0, 1e5):
        d = dt / tau
        ref = np.empty(3000)
        ref[0] = 0.7
        for k in range(1, 3000):
            ref[k] = math.exp(-d[k]) * ref[k - 1] + u[k]
        np.testing.assert_allclose(ar1(d, u, 0.7), ref, atol=1e-9)


# -- stochastic effects: statistics --------------------------------------------------------------


@pytest.mark.parametrize("fs", [10.0, 100.0])
def test_white_noise_density_by_allan(fs: float) -> None:
    n_density = 0.05
    out = _run(GyroModel((WhiteNoise(n_density),)), np.zeros(int(4000 * fs)), fs=fs)
    assert np.std(out) == pytest.approx(n_density * math.sqrt(fs), rel=0.03)
    taus, adev = allan_deviation(out, fs)
    assert arw_from_adev(taus, adev) == pytest.approx(n_density, rel=0.06)


def test_bias_instability_allan_shape() -> None:
    sigma, tc, fs = 0.05, 20.0, 10.0
    out = _run(GyroModel((BiasInstability(sigma, tc),)), np.zeros(100_000), fs=fs, seed=4)
    assert np.std(out) == pytest.approx(sigma, rel=0.15)
    taus, adev = allan_deviation(out, fs, np.logspace(0, 2.3, 12))
    np.testing.assert_allclose(adev, gauss_markov_adev(taus, sigma, tc), rtol=0.15)


def test_bias_instability_is_stationary_from_the_start() -> None:
    # Many short realisations: the first sample already has variance sigma^2.
    m = GyroModel((BiasInstability(0.1, 100.0),))
    first = np.array([_run(m, np.zeros(3), seed=s)[0] for s in range(400)])
    assert np.std(first) == pytest.approx(0.1, rel=0.15)


def test_rate_random_walk_allan_slope() -> None:
    k, fs = 0.002, 10.0
    out = _run(GyroModel((RateRandomWalk(k),)), np.zeros(200_000), fs=fs, seed=6)
    assert out[0] == 0.0
    taus, adev = allan_deviation(out, fs)
    sel = (taus >= 1) & (taus <= 1000)
    slope = np.polyfit(np.log(taus[sel]), np.log(adev[sel]), 1)[0]
    assert slope == pytest.approx(0.5, abs=0.1)
    assert rrw_from_adev(taus, adev) == pytest.approx(k, rel=0.3)


def test_crs03_default_is_plausible_for_the_part() -> None:
    m = crs03_default_model()
    bw, sat, q = m.get("bandwidth"), m.get("saturation"), m.get("quantization")
    assert isinstance(bw, Bandwidth) and bw.cutoff_hz == 10.0
    assert isinstance(sat, Saturation) and sat.limit_dps == 200.0
    assert isinstance(q, Quantization) and q.step_dps == SensorModel().lsb_dps
    # An hour at rest at constant temperature: in-run bias instability below the CRS03-04's
    # specified 66 deg/h (1.1 deg/min = 0.0183 deg/s).
    n = 36_000
    out = _run(m, np.zeros(n), temp=np.full(n, 25.0), seed=7)
    taus, adev = allan_deviation(out[3000:], 10.0)
    b, _ = bias_instability_from_adev(taus, adev)
    assert 0.001 < b < 66.0 / 3600.0
    assert np.max(np.abs(out)) < 200.0


def test_paper_like_cabin_warm_up_moves_the_bias_by_a_tenth_of_a_degree_per_second() -> None:
    m = crs03_default_model()
    te = m.get("temperature_bias")
    assert isinstance(te, TemperatureBias)

    def bias(c: float) -> float:
        d = c - te.ref_temp_c
        return te.coeff_dps_per_c * d + te.quad_dps_per_c2 * d**2

    assert 0.1 < bias(21.0) - bias(5.0) < 0.3
    # ... yet stays within the part's +/-3 deg/s over its -40..85 degC range.
    assert all(abs(bias(c)) < 3.0 for c in np.linspace(-40, 85, 126))


# -- the model: order, determinism, editing ---------------------------------------------------------


def test_effects_apply_in_physical_order_whatever_the_list_order() -> None:
    effects = (Quantization(0.5), Saturation(10.0), StaticBias(3.2), ScaleFactor(1.0))
    a, b = GyroModel(effects), GyroModel(tuple(reversed(effects)))
    assert a == b
    assert a.names() == ["scale_factor", "static_bias", "saturation", "quantization"]
    out = _run(a, np.array([1.0, 4.0, -20.0]))
    # scale (x2) -> bias (+3.2) -> clip (+/-10) -> round to 0.5
    np.testing.assert_array_equal(out, [5.0, 10.0, -10.0])


def test_same_rng_same_output_other_seed_other_output() -> None:
    m = crs03_default_model()
    x = np.zeros(500)
    temp = np.full(500, 20.0)
    a, b, c = (
        _run(m, x, temp=temp, seed=1),
        _run(m, x, temp=temp, seed=1),
        _run(m, x, temp=temp, seed=2),
    )
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_adding_an_effect_leaves_the_others_noise_unchanged() -> None:
    base = GyroModel((WhiteNoise(0.05), BiasInstability(0.01, 100.0)))
    more = base.with_effect(StaticBias(0.7)).with_effect(RateRandomWalk(0.0))
    x = np.zeros(1000)
    np.testing.assert_allclose(_run(more, x, seed=3) - _run(base, x, seed=3), 0.7, atol=1e-12)


def test_random_streams_are_fixed_per_effect() -> None:
    """Each effect's stream number is its own and never moves with the order of application:
    a new effect placed among the others leaves every other effect's output bit for bit."""
    assert set(STREAMS) == set(EFFECTS)
    assert len(set(STREAMS.values())) == len(STREAMS)
    m = crs03_default_model()
    x, temp, v = np.zeros(600), np.full(600, 20.0), np.full(600, 8.0)
    a = _run(m, x, temp=temp, seed=4)
    t = np.arange(600) / 10.0
    b = m.with_effect(MotionOffset(offset_dps=0.0)).apply(
        t, x, temp, np.random.default_rng(4), speed_mps=v
    )
    np.testing.assert_array_equal(a, b)


def test_names_get_with_without() -> None:
    m = GyroModel((StaticBias(0.1),))
    assert m.names() == ["static_bias"] and "static_bias" in m
    assert m.get("white_noise") is None
    m2 = m.with_effect(WhiteNoise(0.02)).with_effect(StaticBias(0.4))
    assert m2.names() == ["static_bias", "white_noise"]
    assert m2.get("static_bias") == StaticBias(0.4)
    assert m2.without("static_bias").names() == ["white_noise"]
    assert m2.without("saturation") == m2
    assert m.names() == ["static_bias"]  # immutable
    with pytest.raises(ValueError, match="unknown effect name 'bogus'"):
        m.get("bogus")
    with pytest.raises(ValueError, match="unknown effect name 'bogus'"):
        m.without("bogus")
    with pytest.raises(ValueError, match="more than once: static_bias"):
        GyroModel((StaticBias(0.1), StaticBias(0.2)))


def test_default_start_model() -> None:
    assert DEFAULT_START_MODEL.names() == ["static_bias", "white_noise"]


def test_apply_rejects_bad_input() -> None:
    m = GyroModel((StaticBias(0.1),))
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="strictly increasing"):
        m.apply(np.array([0.0, 0.1, 0.1]), np.zeros(3), None, rng)
    with pytest.raises(ValueError, match="equal length"):
        m.apply(np.arange(3.0), np.zeros(4), None, rng)
    with pytest.raises(ValueError, match="finite"):
        m.apply(np.arange(3.0), np.array([0.0, np.nan, 0.0]), None, rng)


def test_apply_does_not_modify_its_input() -> None:
    x = np.array([1.0, 2.0, 3.0])
    _run(crs03_default_model(), x, temp=np.full(3, 20.0))
    np.testing.assert_array_equal(x, [1.0, 2.0, 3.0])


# -- dict and YAML forms -------------------------------------------------------------------------------


def test_yaml_round_trip(tmp_path: Path) -> None:
    m = crs03_default_model().with_effect(TimeOffset(0.02)).with_effect(ScaleAsymmetry(0.01, -0.02))
    path = tmp_path / "m.yaml"
    save_model(m, path)
    assert load_model(path) == m
    text = path.read_text()
    assert "name: static_bias" in text and "bias_dps: 1.0" in text


def test_yaml_round_trip_with_a_motion_offset(tmp_path: Path) -> None:
    m = crs03_default_model().with_effect(MotionOffset(offset_dps=0.09, coeff_dps_per_mps=-1e-3))
    path = tmp_path / "m.yaml"
    save_model(m, path)
    back = load_model(path)
    assert back == m
    assert back.names().index("motion_offset") == back.names().index("temperature_bias") + 1
    path.write_text("effects:\n  - {name: motion_offset, offset_dps: -0.09}\n")
    assert load_model(path) == GyroModel((MotionOffset(-0.09, 0.5, 0.0),))  # defaults
    path.write_text("effects:\n  - {name: motion_offset, moving_mps: 1}\n")
    with pytest.raises(ValueError, match="motion_offset: missing parameter\\(s\\) offset_dps"):
        load_model(path)


def test_yaml_in_the_documented_form(tmp_path: Path) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(
        "effects:\n"
        "  - {name: static_bias, bias_dps: 0.3}\n"
        "  - name: temperature_bias\n    coeff_dps_per_c: 0.01\n    ref_temp_c: 20\n"
    )
    m = load_model(path)
    assert m == GyroModel((StaticBias(0.3), TemperatureBias(0.01, 20.0, 0.0)))


effect_dicts = st.sampled_from(EFFECT_NAMES).flatmap(
    lambda name: st.fixed_dictionaries(
        {"name": st.just(name)}
        | {  # within what a gyro can have (hdrd.sim.gyrolimits)
            p: st.floats(max(0.001, LIMITS[name, p][0]), min(500.0, LIMITS[name, p][1]))
            for p in ISSUE_VOCABULARY[name]
        }
    )
)


@settings(max_examples=60, deadline=None)
@given(st.lists(effect_dicts, max_size=12, unique_by=lambda d: d["name"]))
def test_dict_round_trip_any_model(items: list[dict[str, float]]) -> None:
    m = GyroModel.from_dict({"effects": items})
    assert GyroModel.from_dict(m.to_dict()) == m
    assert sorted(m.names()) == sorted(d["name"] for d in items)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"effects": [{"name": "bogus"}]}, "unknown effect name\\(s\\): bogus"),
        (
            {"effects": [{"name": "static_bias", "bias": 1}]},
            "static_bias: unknown parameter\\(s\\) bias",
        ),
        (
            {"effects": [{"name": "bias_instability", "sigma_dps": 1}]},
            "bias_instability: missing parameter\\(s\\) tau_s",
        ),
        (
            {"effects": [{"name": "static_bias", "bias_dps": "x"}]},
            "static_bias.bias_dps: 'x' is not a number",
        ),
        ({"effects": [{"name": "white_noise", "density_dps_per_rthz": -1}]}, "must be >= 0"),
        (
            {"effects": [{"name": "bias_instability", "sigma_dps": 1, "tau_s": 0}]},
            "tau_s: 0.0 must be > 0",
        ),
        ({"effects": [{"name": "scale_factor", "error": -1.5}]}, "must be > -1"),
        ({"effects": [{"name": "static_bias", "bias_dps": float("nan")}]}, "not a finite number"),
        (
            {
                "effects": [
                    {"name": "static_bias", "bias_dps": 1},
                    {"name": "static_bias", "bias_dps": 2},
                ]
            },
            "more than once",
        ),
        ({"effect": []}, "'effects' list"),
        ({"effects": [], "extra": 1}, "unknown key\\(s\\) in gyro model: extra"),
        ({"effects": "static_bias"}, "must be a list"),
        ([1, 2], "'effects' list"),
    ],
)
def test_bad_model_dicts_name_the_problem(data: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        GyroModel.from_dict(data)


def test_load_model_names_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("effects: [{name: static_bias, bias_dps: 1, colour: red}]\n")
    with pytest.raises(
        ValueError, match=r"bad.yaml: effect static_bias: unknown parameter\(s\) colour"
    ):
        load_model(bad)
    broken = tmp_path / "broken.yaml"
    broken.write_text("effects: [\n")
    with pytest.raises(ValueError, match="broken.yaml: not valid YAML"):
        load_model(broken)
