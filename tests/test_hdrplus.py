"""HDR+, the one estimator of heading and bias (hdrd/core/hdrplus.py, hdrd/core/plusparams.py):
its two forms agree to the bit, it measures by stops, roads and courses as the model says,
and what it learns follows the kind of unit it carries. Rates deg/s, + = CCW; speeds m/s;
temperatures degC; headings deg; steps of T = 1 s."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.core import hdrplus
from hdrd.core.gyronoise import GyroNoise
from hdrd.core.hdr import HdrParams
from hdrd.core.hdrplus import INITIAL_PLUS_STATE, PlusState, run_batch, step
from hdrd.core.plusparams import (
    DEFAULTS,
    FRESH_BANK,
    PROFILE_OFFSET_SD_DPS,
    Hypothesis,
    PlusParams,
    Road,
    unit_bank,
)
from hdrd.core.standstill import CalibrationNoise, StopDetection
from hdrd.core.steps import StepInput

NAN = math.nan
rate = st.floats(-5.0, 5.0)
rows = st.lists(
    st.tuples(
        rate,
        st.floats(0.0, 1.0),
        st.one_of(st.just(NAN), st.just(0.0), st.floats(0.0, 30.0)),
        st.one_of(st.just(NAN), st.floats(-10.0, 40.0)),
        st.one_of(st.just(NAN), st.floats(-20.0, 20.0)),
    ),
    max_size=60,
)


@st.composite
def core_params(draw: st.DrawFn) -> HdrParams:
    """The paper's HDR parameters across their ranges (the other methods' settings)."""
    return HdrParams(
        i_c=draw(st.floats(0.0, 0.1)),
        tau=draw(st.floats(0.0, 3.0)),
        theta_w=draw(st.floats(0.01, 2.0)),
        c1=draw(st.floats(0.0, 1.0)),
        c2=draw(st.floats(0.0, 3.0)),
        T=draw(st.sampled_from([0.5, 1.0, 2.0])),
        lowpass=draw(st.booleans()),
        turn_switch=draw(st.booleans()),
        attenuator=draw(st.booleans()),
        enabled=draw(st.booleans()),
    )


@st.composite
def plus_params(draw: st.DrawFn) -> PlusParams:
    """Settings across their ranges: banks of one to three members, every measurement."""
    m = draw(st.integers(1, 3))
    bank = tuple(
        Hypothesis(
            f"h{i}",
            draw(st.floats(0.05, 1.0)),
            draw(st.sampled_from([0.0, 1e-9, 1e-5])),
            draw(st.floats(-0.1, 0.1)),
            draw(st.floats(0.0, 0.1)),
        )
        for i in range(m)
    )
    return PlusParams(
        T=draw(st.sampled_from([0.5, 1.0, 2.0])),
        bank=bank,
        standstill=StopDetection(
            enabled=draw(st.booleans()),
            gyro_only=draw(st.booleans()),
            samples_per_step=draw(st.sampled_from([1.0, 10.0, 100.0])),
        ),
        stop_scatter_dps=draw(st.floats(0.0, 0.05)),
        bias_p0=draw(st.floats(0.0, 1e-3)),
        block_var=draw(st.sampled_from([NAN, 0.0, 1e-4])),
        quant_var=draw(st.sampled_from([0.0, 1e-4])),
        temp_coeff_sd=draw(st.floats(0.0, 0.01)),
        heading_q=draw(st.floats(0.0, 0.1)),
        measure=draw(st.booleans()),
    )


def _columns(data: list[tuple[float, float, float, float, float]]) -> list[list[float]]:
    return [list(c) for c in zip(*data, strict=True)] if data else [[], [], [], [], []]


@settings(max_examples=120, deadline=None)
@given(data=rows, params=plus_params())
def test_batch_is_bit_identical_to_step(
    data: list[tuple[float, float, float, float, float]], params: PlusParams
) -> None:
    u, sp, v, te, herr = _columns(data)
    var = [4.0 if e == e else NAN for e in herr]
    reset = [i == 3 for i in range(len(data))]
    trace = run_batch(u, sp, v, te, params.T, params, INITIAL_PLUS_STATE, herr, var, reset)
    state = INITIAL_PLUS_STATE
    outs = []
    for i in range(len(data)):
        state, o = step(
            state, StepInput(u[i], sp[i], v[i], te[i], params.T, herr[i], var[i], reset[i]), params
        )
        outs.append(o)
    assert trace.yaw.tolist() == [o.yaw for o in outs]
    assert trace.heading_sd_deg.tolist() == [o.heading_sd_deg for o in outs]
    assert trace.bias_corr_dps.tolist() == [o.bias_corr_dps for o in outs]
    assert trace.standstill.tolist() == [o.standstill for o in outs]
    assert trace.final == state
    for o in outs:
        assert (
            math.isfinite(o.yaw)
            and o.heading_sd_deg >= 0.0
            and sum(o.weights) == pytest.approx(1.0)
        )


@settings(max_examples=40, deadline=None)
@given(data=rows, params=plus_params(), cut=st.integers(0, 60))
def test_batch_continues_from_a_state(
    data: list[tuple[float, float, float, float, float]], params: PlusParams, cut: int
) -> None:
    u, sp, v, te, _ = _columns(data)
    whole = run_batch(u, sp, v, te, params.T, params)
    k = min(cut, len(data))
    first = run_batch(u[:k], sp[:k], v[:k], te[:k], params.T, params)
    rest = run_batch(u[k:], sp[k:], v[k:], te[k:], params.T, params, first.final)
    assert whole.yaw.tolist() == first.yaw.tolist() + rest.yaw.tolist()
    assert whole.final == rest.final


def test_inputs_may_be_none_scalar_or_per_step_and_a_wrong_length_is_named() -> None:
    a = run_batch([0.1, 0.2, 0.3], None, 10.0, None)
    b = run_batch([0.1, 0.2, 0.3], [NAN] * 3, [10.0] * 3, [NAN] * 3)
    assert a.yaw.tolist() == b.yaw.tolist()
    with pytest.raises(ValueError, match="speed must have one value per step"):
        run_batch([0.1, 0.2], None, [1.0, 2.0, 3.0])
    empty = run_batch([])
    assert empty.yaw.shape == (0,) and empty.weights.shape == (0, len(DEFAULTS.bank))


def test_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="prior must be in"):
        Hypothesis("x", 0.0)
    with pytest.raises(ValueError, match="share must be in"):
        Hypothesis("x", 0.5, share=1.5)
    with pytest.raises(ValueError, match="offset_sd_dps must be >= 0"):
        Hypothesis("x", 0.5, offset_sd_dps=-1.0)
    with pytest.raises(ValueError, match="p_straight must be in"):
        Road(p_straight=0.0)
    with pytest.raises(ValueError, match="stop_scatter_dps must be a number >= 0"):
        PlusParams(stop_scatter_dps=-0.1)
    with pytest.raises(ValueError, match="needs at least one hypothesis"):
        PlusParams(bank=())
    assert math.isnan(PlusParams(block_var=NAN).block_var)


# -- drives made of steps ---------------------------------------------------------------------


def drive(
    minutes: float,
    seed: int,
    offset: float = 0.0,
    stop_every_s: int = 0,
    stop_s: int = 30,
    road_sd: float = 0.0,
    sway: float = 0.15,
) -> dict[str, np.ndarray]:
    """Steps of a drive: straight road with sway (and a gentle Gauss-Markov curvature of
    road_sd), a turn now and then, a stop of stop_s every stop_every_s (0: none); the gyro
    reads the true rate plus a motion offset while moving. Returns u (what HDR+ gets: the
    rest bias already removed), the true rate, speed and spread."""
    rng = np.random.default_rng(seed)
    n = int(minutes * 60)
    true = rng.normal(0.0, sway, n)
    a, r = math.exp(-1 / 120.0), 0.0
    for i in range(n):
        r = a * r + road_sd * math.sqrt(1 - a * a) * rng.normal()
        true[i] += r
    for start in range(40, n - 20, 150):  # a 90 deg turn every 2.5 min
        true[start : start + 10] += rng.choice([-9.0, 9.0])
    speed = np.full(n, 15.0)
    if stop_every_s:
        for s0 in range(stop_every_s, n - stop_s, stop_every_s):
            speed[s0 : s0 + stop_s] = 0.0
            true[s0 : s0 + stop_s] = 0.0
    moving = speed > 0.3
    u = true + np.where(moving, offset, 0.0) + rng.normal(0.0, 0.01, n)
    return {"u": u, "true": true, "speed": speed, "spread": np.full(n, 0.1)}


def _run(d: dict[str, np.ndarray], p: PlusParams = DEFAULTS, **kw: Any) -> hdrplus.PlusTrace:
    return run_batch(d["u"], d["spread"], d["speed"], None, 1.0, p, **kw)


def _yaw_error(d: dict[str, np.ndarray], yaw: np.ndarray) -> np.ndarray:
    return yaw - np.cumsum(d["true"])


def test_a_stop_does_not_integrate_what_it_reads() -> None:
    # At a stop the vehicle does not turn: omega is 0 and the yaw does not integrate u. Here
    # every stop reads 0.1 deg/s (a rest bias the start-up calibration missed): integrated
    # over a 30 s stop that would be 3 deg. The yaw moves at a stop's first steps by what the
    # bias the stop reveals says the driving before had integrated (a correction, not
    # integration); once the stop is known, not at all.
    d = drive(5, 1, stop_every_s=100)
    d["u"] = np.where(d["speed"] > 0.3, d["u"], d["u"] + 0.1)
    tr = _run(d)
    stops = np.flatnonzero(tr.standstill)
    assert stops.shape[0] > 50 and np.all(tr.omega[stops] == 0.0)
    settled = stops[np.isin(stops - 10, stops)]  # the 11th step of a stop and on
    assert np.abs(tr.yaw[settled] - tr.yaw[settled - 1]).sum() < 0.5 * 0.1 * settled.shape[0]


def test_a_motion_offset_is_learned_from_the_road() -> None:
    # A unit whose driving bias is 0.09 deg/s off its rest bias (a stop cannot see it): the
    # road shows it; the offset member takes over and the heading comes back.
    d = drive(20, 2, offset=0.09, stop_every_s=300)
    tr = _run(d)
    assert tr.bias_corr_dps[-1] == pytest.approx(0.09, abs=0.02)
    assert tr.offset_dps[-1] == pytest.approx(0.09, abs=0.02)
    assert tr.weights[-1][1] + tr.weights[-1][2] > 0.9  # not steady any more
    err_none = np.abs(np.cumsum(d["u"]) - np.cumsum(d["true"]))
    err = np.abs(_yaw_error(d, tr.yaw))
    assert err.mean() < 0.3 * err_none.mean()


def test_a_steady_unit_on_a_curving_road_keeps_its_bias() -> None:
    # No offset, a real-road-like curvature: the bank stays with steady and the bias hardly
    # moves (a good gyro is not harmed by what roads do).
    d = drive(20, 3, road_sd=0.02, stop_every_s=400)
    tr = _run(d)
    assert np.max(np.abs(tr.bias_corr_dps)) < 0.02
    assert tr.weights[-1][0] > 0.7


def test_a_profile_s_offset_is_in_force_from_the_first_step() -> None:
    d = drive(3, 4, offset=-0.06)
    noise = GyroNoise(motion_offset_dps=-0.06, motion_offset_sd_dps=0.003, source="config")
    p = DEFAULTS.fitted(None, noise)
    assert p.model == "config" and p.bank[0].offset_dps == -0.06
    tr = _run(d, p)
    assert tr.bias_corr_dps[0] == pytest.approx(-0.06, abs=0.005)
    assert np.abs(_yaw_error(d, tr.yaw)).max() < 2.0


def test_unit_bank_puts_what_is_known_into_the_fresh_bank() -> None:
    b = unit_bank(
        GyroNoise(motion_offset_dps=0.05, motion_offset_sd_dps=0.004, rrw_dps_per_sqrt_s=1e-4)
    )
    assert [h.name for h in b] == [h.name for h in FRESH_BANK]
    assert all(h.offset_dps == 0.05 for h in b)
    # the steady member: the profile's sd and how far an offset moves between drives
    assert b[0].offset_sd_dps == pytest.approx(math.hypot(0.004, PROFILE_OFFSET_SD_DPS))
    assert b[1].offset_sd_dps == FRESH_BANK[1].offset_sd_dps
    assert b[0].drift_q == pytest.approx(1e-8) and b[2].drift_q == FRESH_BANK[2].drift_q
    assert unit_bank(GyroNoise()) == FRESH_BANK  # nothing known: the fresh bank


def test_courses_teach_the_driving_bias_and_the_heading_sd_follows_them() -> None:
    d = drive(10, 5, offset=0.05)
    n = d["u"].shape[0]
    reset = np.zeros(n, bool)
    reset[0] = True
    state = INITIAL_PLUS_STATE
    sds = []
    true_yaw = np.cumsum(d["true"])
    yaw_prev = 0.0
    for i in range(n):
        herr = true_yaw[i - 1] - yaw_prev if 0 < i < n // 2 else NAN  # courses, then an outage
        inp = StepInput(
            d["u"][i],
            0.1,
            d["speed"][i],
            NAN,
            1.0,
            herr,
            1.0 if herr == herr else NAN,
            bool(reset[i]),
        )
        state, o = step(state, inp, DEFAULTS)
        yaw_prev = o.yaw
        sds.append(o.heading_sd_deg)
    assert o.bias_corr_dps == pytest.approx(0.05, abs=0.01)
    assert sds[n // 2 - 1] < 1.2  # aided: about a course's sd
    assert sds[-1] > sds[n // 2]  # in the outage the sd grows
    assert abs(o.yaw - true_yaw[-1]) < 3.0


def test_the_frozen_policy_measures_nothing() -> None:
    d = drive(5, 6, offset=0.08, stop_every_s=100)
    tr = _run(d, DEFAULTS.with_(measure=False))
    assert not tr.standstill.any()
    assert np.all(tr.bias_corr_dps == 0.0)
    assert tr.yaw == pytest.approx(np.cumsum(d["u"]), abs=1e-9)


def test_a_stop_reading_off_a_steady_unit_moves_its_driving_bias_by_less_than_the_stop_reads() -> (
    None
):
    # Real stops read 0.005-0.04 deg/s off a still-good driving bias: one stop 0.03 off moves
    # a steady unit's driving bias, but by less than it reads (each stop has its own offset).
    u = np.concatenate([np.full(100, 0.0), np.full(60, 0.03), np.full(100, 0.0)])
    speed = np.concatenate([np.full(100, 15.0), np.zeros(60), np.full(100, 15.0)])
    p = DEFAULTS.fitted(CalibrationNoise(1e-6, 1e-4, NAN, 10.0))
    tr = run_batch(u, 0.1, speed, None, 1.0, p)
    assert 0.0 < tr.bias_corr_dps[170] < 0.03


def test_an_undithered_unit_knows_its_rest_bias_only_to_its_step() -> None:
    q = 0.573  # a unit stored in 0.01 rad/s codes, one code at rest
    cal = CalibrationNoise(0.0, 0.0, q, 100.0, codes=1)
    p = DEFAULTS.fitted(cal, None, q)
    assert p.quant_var == pytest.approx(q * q / 12)
    f = hdrplus.prior_filters(p)[0]
    assert math.sqrt(f.P[hdrplus.BIAS][hdrplus.BIAS]) > 0.15  # the driving bias: +- half a code
    dithered = DEFAULTS.fitted(CalibrationNoise(1e-6, 1e-4, q, 100.0, codes=40), None, q)
    assert dithered.quant_var == 0.0


def test_a_turn_under_a_stale_speed_is_not_a_stop() -> None:
    u = np.concatenate([np.zeros(20), np.full(5, 8.0), np.zeros(5)])
    tr = run_batch(u, 0.1, 0.0, None, 1.0)  # gpsd says 0 m/s throughout
    assert not tr.standstill[20:25].any()
    assert tr.yaw[24] - tr.yaw[19] == pytest.approx(40.0, abs=0.5)


def test_the_temperature_coefficient_is_learned_from_stops_at_different_temperatures() -> None:
    k = 0.01  # deg/s per degC
    temp = np.linspace(10.0, 30.0, 1200)
    speed = np.where((np.arange(1200) // 100) % 2 == 0, 0.0, 15.0)
    u = k * (temp - 10.0) + np.random.default_rng(7).normal(0, 0.01, 1200)
    p = DEFAULTS.with_(temp_coeff_sd=0.01)
    tr = run_batch(u, 0.05, speed, temp, 1.0, p)
    assert tr.bias_corr_dps[-1] == pytest.approx(k * 20.0, abs=0.03)


def test_the_published_sd_weighs_the_members_by_how_common_they_are() -> None:
    # a member of small prior but a large share widens the published sd (the units there are)
    narrow = DEFAULTS.with_(
        bank=(
            Hypothesis("a", 0.98, share=0.98),
            Hypothesis("b", 0.02, offset_sd_dps=0.1, share=0.02),
        )
    )
    wide = DEFAULTS.with_(
        bank=(Hypothesis("a", 0.98, share=0.5), Hypothesis("b", 0.02, offset_sd_dps=0.1, share=0.5))
    )
    d = drive(5, 8)
    a, b = _run(d, narrow), _run(d, wide)
    assert a.yaw.tolist() == b.yaw.tolist()  # the same estimate ...
    assert b.heading_sd_deg[30] > 1.3 * a.heading_sd_deg[30]  # ... a more honest sd


def test_a_state_of_another_bank_starts_from_the_prior_with_its_yaw() -> None:
    s, o = step(INITIAL_PLUS_STATE, StepInput(0.5, 0.1, 10.0, NAN, 1.0), DEFAULTS)
    one = DEFAULTS.with_(bank=(Hypothesis("only", 1.0),), measure=False)
    s2, o2 = step(s, StepInput(0.5, 0.1, 10.0, NAN, 1.0), one)
    assert len(s2.xs) == 1 and o2.yaw == pytest.approx(o.yaw + 0.5, abs=1e-9)
    assert isinstance(s2, PlusState)
