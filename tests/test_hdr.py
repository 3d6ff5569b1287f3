"""HDR stepper (hdrd/core/hdr.py) against shared/paper/HDR-NOTES.md.

Rates in deg/s, + = counter-clockwise; yaw in deg CCW. Defaults are the paper's Table III:
i_c = 0.0422 deg/s, tau = 0.75 s, Theta_w = 0.564 deg/s, c1 = 0.16, c2 = 1.80, T = 1 s.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TypedDict

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.core.hdr import (
    INITIAL_STATE,
    HdrOutput,
    HdrParams,
    HdrState,
    attenuation,
    run_batch,
    run_many,
    step,
)

TOL = 1e-9  # hand-worked numbers below carry 10 decimals


def basic(**kw: float) -> HdrParams:
    """Basic HDR (Sec. 3.1): the binary I-controller alone, no enhancements."""
    return HdrParams(lowpass=False, turn_switch=False, attenuator=False, **kw)  # type: ignore[arg-type]


def off(**kw: float) -> HdrParams:
    """No HDR: I stays 0, so omega = u (static bias removal only; the ``none`` method)."""
    return HdrParams(enabled=False, **kw)  # type: ignore[arg-type]


def test_defaults_are_table_iii() -> None:
    p = HdrParams()
    assert (p.i_c, p.tau, p.theta_w, p.c1, p.c2, p.T) == (0.0422, 0.75, 0.564, 0.16, 1.80, 1.0)
    assert p.lowpass and p.turn_switch and p.attenuator and p.enabled
    assert INITIAL_STATE == HdrState(x=0.0, I=0.0, yaw=0.0, r=1, s=0, n=0)


# -- hand-worked steps ----------------------------------------------------------------------
#
# Input u = 0.2, 0.2, -0.5, 2.0, 2.0 deg/s from the initial state (x=0, I=0, yaw=0, r=1, s=0),
# paper defaults. Worked by hand from the HDR-NOTES equations:
#
# step 0, u=0.2:  x = (1*0.2 + 0.75*0)/1.75 = 0.1142857143;  y = x + I = 0.1142857143
#   omega = 0.2 + 0 = 0.2;  yaw = 0 + 0.2*1 = 0.2;  s = +1 != s_prev 0 -> r = 1, R = 1
#   |y| <= 0.564 -> W = 1;  I_next = 0 - (+1)(1)(1)(0.0422) = -0.0422
# step 1, u=0.2:  x = (0.2 + 0.75*0.1142857143)/1.75 = 0.2857142857/1.75 = 0.1632653061
#   y = 0.1632653061 - 0.0422 = 0.1210653061;  omega = 0.2 - 0.0422 = 0.1578
#   yaw = 0.2 + 0.1578 = 0.3578;  s = +1 == +1 -> r = 2, R = 1.16/(1 + 0.16*2^1.8)
#   = 1.16/(1 + 0.16*3.4822022531) = 1.16/1.5571523605 = 0.7449495820;  W = 1
#   I_next = -0.0422 - 0.7449495820*0.0422 = -0.0422 - 0.0314368724 = -0.0736368724
# step 2, u=-0.5 (sign change):  x = (-0.5 + 0.75*0.1632653061)/1.75
#   = -0.3775510204/1.75 = -0.2157434402;  y = -0.2157434402 - 0.0736368724 = -0.2893803126
#   omega = -0.5 - 0.0736368724 = -0.5736368724;  yaw = 0.3578 - 0.5736368724 = -0.2158368724
#   s = -1 != +1 -> r reset to 1, R = 1;  W = 1
#   I_next = -0.0736368724 - (-1)(1)(1)(0.0422) = -0.0314368724
# step 3, u=2.0 (a turn):  x = (2 + 0.75*(-0.2157434402))/1.75 = 1.8381924198/1.75
#   = 1.0503956685;  y = 1.0503956685 - 0.0314368724 = 1.0189587961 > 0.564 -> W = 0
#   omega = 2 - 0.0314368724 = 1.9685631276;  yaw = -0.2158368724 + 1.9685631276 = 1.7527262553
#   s = +1 != -1 -> r = 1, R = 1;  I_next = I (frozen) = -0.0314368724
# step 4, u=2.0:  x = (2 + 0.75*1.0503956685)/1.75 = 1.5930267151;  y = 1.5615898427 -> W = 0
#   omega = 1.9685631276;  yaw = 3.7212893829;  s = +1 == +1 -> r = 2, R = 0.7449495820
#   I_next = I (frozen) = -0.0314368724
HAND_U = [0.2, 0.2, -0.5, 2.0, 2.0]
#          omega          yaw            I              W  R             r  filtered
HAND_OUT = [
    (0.2000000000, 0.2000000000, 0.0, 1, 1.0, 1, 0.1142857143),
    (0.1578000000, 0.3578000000, -0.0422, 1, 0.7449495820, 2, 0.1210653061),
    (-0.5736368724, -0.2158368724, -0.0736368724, 1, 1.0, 1, -0.2893803126),
    (1.9685631276, 1.7527262553, -0.0314368724, 0, 1.0, 1, 1.0189587961),
    (1.9685631276, 3.7212893829, -0.0314368724, 0, 0.7449495820, 2, 1.5615898427),
]
HAND_X = [0.1142857143, 0.1632653061, -0.2157434402, 1.0503956685, 1.5930267151]
HAND_I_NEXT = [-0.0422, -0.0736368724, -0.0314368724, -0.0314368724, -0.0314368724]
HAND_S = [1, 1, -1, 1, 1]


def _assert_out(out: HdrOutput, want: tuple[float, float, float, int, float, int, float]) -> None:
    omega, yaw, I, W, R, r, filtered = want  # noqa: E741
    assert out.omega == pytest.approx(omega, abs=TOL)
    assert out.yaw == pytest.approx(yaw, abs=TOL)
    assert out.I == pytest.approx(I, abs=TOL)
    assert out.W == W
    assert out.R == pytest.approx(R, abs=TOL)
    assert out.r == r
    assert out.filtered == pytest.approx(filtered, abs=TOL)


def test_hand_worked_steps() -> None:
    state = INITIAL_STATE
    for i, u in enumerate(HAND_U):
        state, out = step(state, u)
        _assert_out(out, HAND_OUT[i])
        assert state.x == pytest.approx(HAND_X[i], abs=TOL)
        assert state.I == pytest.approx(HAND_I_NEXT[i], abs=TOL)
        assert state.yaw == out.yaw
        assert state.r == out.r
        assert state.s == HAND_S[i]
        assert state.n == i + 1


def test_hand_worked_steps_batch() -> None:
    tr = run_batch(HAND_U)
    for i in range(len(HAND_U)):
        out = HdrOutput(
            float(tr.omega[i]), float(tr.yaw[i]), float(tr.I[i]), int(tr.W[i]),
            float(tr.R[i]), int(tr.r[i]), float(tr.filtered[i]),
        )  # fmt: skip
        _assert_out(out, HAND_OUT[i])
    assert tr.final.I == pytest.approx(HAND_I_NEXT[-1], abs=TOL)
    assert tr.final.n == len(HAND_U)


def test_first_step_from_initial_state_uses_full_increment() -> None:
    # s_{-1} = 0, so any non-zero first sign starts a run: r = 1, R = 1, I moves by i_c.
    for u, sign in ((0.3, 1), (-0.3, -1)):
        state, out = step(INITIAL_STATE, u)
        assert (out.r, out.R, out.W, out.I) == (1, 1.0, 1, 0.0)
        assert state.I == -sign * 0.0422


def test_zero_first_step_counts_as_a_repetition() -> None:
    # HDR-NOTES: r_{i+1} = r_i + 1 if s_i == s_{i-1}; with u = 0, s_0 = 0 == s_{-1} = 0.
    state, out = step(INITIAL_STATE, 0.0)
    assert out.r == 2 and out.R == pytest.approx(0.7449495820, abs=TOL)
    assert state.I == 0.0  # s = 0: no correction


def test_basic_hdr_hand_worked() -> None:
    # Basic HDR (Sec. 3.1): x = u (no low-pass), W = 1 always, R = 1 always.
    p = basic()
    state = INITIAL_STATE
    # u = 5 (a turn, but no turn switch): y = 5, s = +1, I -> -0.0422
    state, out = step(state, 5.0, p)
    assert (out.filtered, out.W, out.R, out.r) == (5.0, 1, 1.0, 1)
    assert state.I == -0.0422
    # u = 5 again: y = 5 - 0.0422, s = +1 == +1 -> r = 2 but R stays 1: I -> -0.0844
    state, out = step(state, 5.0, p)
    assert out.filtered == 5.0 - 0.0422 and out.omega == 5.0 - 0.0422
    assert (out.W, out.R, out.r) == (1, 1.0, 2)
    assert state.I == pytest.approx(-0.0844, abs=1e-15)


def test_off_hand_worked() -> None:
    p = off()
    state = INITIAL_STATE
    for u, yaw in ((0.5, 0.5), (0.5, 1.0), (-2.0, -1.0)):
        state, out = step(state, u, p)
        assert out.omega == u and out.yaw == yaw and out.I == 0.0 and state.I == 0.0


# -- Eq. 10 ---------------------------------------------------------------------------------


@pytest.mark.parametrize("r, R", [(1, 1.0), (2, 0.745), (3, 0.538), (5, 0.298), (10, 0.105)])
def test_attenuator_eq10_values(r: int, R: float) -> None:
    assert attenuation(r) == pytest.approx(R, abs=5e-4)
    assert attenuation(r, 0.16, 1.80) == attenuation(r)


def test_attenuator_in_steps_follows_r() -> None:
    # A steady small positive rate keeps s = +1 (y stays > 0 while I is small): r counts up
    # 1, 2, 3, ... and each step's R is Eq. 10 at that r.
    tr = run_batch(np.full(10, 0.5))
    assert tr.r.tolist() == list(range(1, 11))
    assert tr.R == pytest.approx([attenuation(r) for r in range(1, 11)], abs=0)
    # ... and I moved by exactly sum(R(r)) * i_c.
    assert tr.final.I == pytest.approx(-0.0422 * sum(attenuation(r) for r in range(1, 11)))


# -- batch and per-step forms agree to the last bit -------------------------------------------

rates = st.floats(min_value=-300.0, max_value=300.0, allow_nan=False, allow_infinity=False)
small_rates = st.floats(min_value=-2.0, max_value=2.0, allow_nan=False, allow_infinity=False)


class Gains(TypedDict):
    """HdrParams' numeric fields, as keywords."""

    i_c: float
    tau: float
    theta_w: float
    c1: float
    c2: float
    T: float


@st.composite
def params_st(draw: st.DrawFn) -> HdrParams:
    kw: Gains = {
        "i_c": draw(st.floats(0.0, 0.5)),
        "tau": draw(st.floats(0.0, 5.0)),
        "theta_w": draw(st.floats(0.01, 5.0)),
        "c1": draw(st.floats(0.0, 2.0)),
        "c2": draw(st.floats(0.0, 3.0)),
        "T": draw(st.floats(0.01, 10.0)),
    }
    variant = draw(st.sampled_from(["paper", "basic", "off", "custom"]))
    if variant == "basic":
        return basic(**kw)
    if variant == "off":
        return off(**kw)
    if variant == "custom":
        flags = {
            k: draw(st.booleans()) for k in ("lowpass", "turn_switch", "attenuator", "enabled")
        }
        return HdrParams(**kw, **flags)
    return HdrParams(**kw)


@st.composite
def state_st(draw: st.DrawFn) -> HdrState:
    if draw(st.booleans()):
        return INITIAL_STATE
    return HdrState(
        x=draw(small_rates), I=draw(small_rates), yaw=draw(rates),
        r=draw(st.integers(1, 1000)), s=draw(st.sampled_from([-1, 0, 1])),
        n=draw(st.integers(0, 10**6)),
    )  # fmt: skip


@settings(deadline=None)
@given(
    u=st.lists(st.one_of(small_rates, rates, st.just(0.0)), max_size=60),
    params=st.one_of(st.just(HdrParams()), params_st()),
    state0=state_st(),
)
def test_batch_equals_steps_bit_for_bit(
    u: list[float], params: HdrParams, state0: HdrState
) -> None:
    tr = run_batch(np.array(u, dtype=np.float64), params, state0)
    state = state0
    for i, ui in enumerate(u):
        state, out = step(state, ui, params)
        assert out.omega == tr.omega[i]
        assert out.yaw == tr.yaw[i]
        assert out.I == tr.I[i]
        assert out.W == tr.W[i]
        assert out.R == tr.R[i]
        assert out.r == tr.r[i]
        assert out.filtered == tr.filtered[i]
    assert state == tr.final
    assert all(math.copysign(1, a) == math.copysign(1, b) for a, b in zip(state, tr.final))


def test_batch_of_nothing_keeps_the_state() -> None:
    s0 = HdrState(x=0.1, I=-0.2, yaw=3.0, r=4, s=1, n=7)
    tr = run_batch(np.empty(0), HdrParams(), s0)
    assert tr.final == s0 and tr.omega.shape == (0,)


def test_batch_can_continue_where_it_stopped() -> None:
    rng = np.random.default_rng(3)
    u = 0.3 + 0.2 * rng.standard_normal(400)
    whole = run_batch(u)
    first = run_batch(u[:150])
    second = run_batch(u[150:], state=first.final)
    assert np.array_equal(np.concatenate([first.yaw, second.yaw]), whole.yaw)
    assert second.final == whole.final


# -- run_many --------------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 400),
    P=st.integers(1, 6),
    T=st.sampled_from([1.0, 0.5, 0.1, 2.0]),
)
def test_run_many_agrees_with_run_batch(seed: int, n: int, P: int, T: float) -> None:
    rng = np.random.default_rng(seed)
    # A drive-like signal: a drift, white noise and a few turns.
    u = rng.normal(0.0, 0.3) + rng.normal(0, 0.2, n)
    for _ in range(rng.integers(0, 4)):
        a = rng.integers(0, n)
        u[a : a + rng.integers(1, 20)] += rng.normal(0, 10)
    i_c = rng.uniform(0.0, 0.2, P)
    tau = rng.uniform(0.0, 3.0, P)
    theta_w = rng.uniform(0.05, 3.0, P)
    c1 = rng.uniform(0.0, 1.0, P)
    c2 = rng.uniform(0.0, 3.0, P)
    yaw = run_many(u, i_c, tau, theta_w, c1, c2, T=T)
    assert yaw.shape == (n, P)
    for k in range(P):
        p = HdrParams(i_c=i_c[k], tau=tau[k], theta_w=theta_w[k], c1=c1[k], c2=c2[k], T=T)
        assert np.allclose(yaw[:, k], run_batch(u, p).yaw, rtol=0, atol=1e-9)


def test_run_many_broadcasts_scalars_with_paper_defaults() -> None:
    u = np.array(HAND_U)
    yaw = run_many(u, 0.0422, 0.75, [0.564, 0.1], 0.16, 1.80)
    assert yaw.shape == (5, 2)
    assert yaw[:, 0] == pytest.approx([o[1] for o in HAND_OUT], abs=TOL)
    assert np.allclose(yaw[:, 1], run_batch(u, HdrParams(theta_w=0.1)).yaw, atol=1e-12)


# -- properties ------------------------------------------------------------------------------


@pytest.mark.parametrize("params", [HdrParams(), basic(), off()])
def test_zero_input_stays_zero(params: HdrParams) -> None:
    tr = run_batch(np.zeros(500), params)
    assert not tr.omega.any() and not tr.yaw.any() and not tr.I.any()
    assert not tr.filtered.any() and tr.final.I == 0.0 and tr.final.yaw == 0.0
    state = INITIAL_STATE
    for _ in range(20):
        state, out = step(state, 0.0, params)
        assert out.omega == 0.0 and out.yaw == 0.0 and out.I == 0.0


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("sigma", [0.05, 0.1, 0.2])
@pytest.mark.parametrize("drift", [-0.25, -0.1, -0.05, 0.05, 0.15, 0.25])
def test_constant_drift_is_driven_toward_zero(drift: float, sigma: float, seed: int) -> None:
    # Straight driving (true rate 0) with a residual drift below Theta_w under white noise:
    # I converges to -drift (Eq. 6), so the corrected rate omega = u + I loses the drift.
    rng = np.random.default_rng(seed)
    noise = sigma * rng.standard_normal(2000)
    tr = run_batch(drift + noise)
    residual = tr.omega[1000:] - noise[1000:]  # = drift + I, the drift HDR left in omega
    assert abs(residual.mean()) < 0.5 * abs(drift)
    assert tr.I[1000:].mean() == pytest.approx(-drift, abs=0.5 * abs(drift))
    # ... whereas without HDR all of it stays.
    none = run_batch(drift + noise, off())
    assert np.array_equal(none.omega, drift + noise)


def test_drift_correction_reduces_heading_error() -> None:
    rng = np.random.default_rng(11)
    u = 0.15 + 0.1 * rng.standard_normal(1200)  # 20 min straight, 0.15 deg/s drift
    assert abs(run_batch(u).yaw[-1]) < 0.2 * abs(run_batch(u, off()).yaw[-1])


def test_attenuator_bounds_what_one_run_can_correct() -> None:
    # Within one run of equal signs I moves by at most i_c * sum_r R(r) = 0.0422 * 5.1117
    # = 0.2157 deg/s (Eq. 10 decays like r**-1.8, so the sum converges). A noise-free drift
    # larger than that is never fully absorbed: the attenuator trades tracking for robustness.
    bound = 0.0422 * sum(attenuation(r) for r in range(1, 200_000))
    assert bound == pytest.approx(0.2157, abs=1e-4)
    tr = run_batch(np.full(3000, 0.45))
    assert np.all(tr.r == np.arange(1, 3001))  # never a sign change
    assert -bound < tr.final.I < -0.21
    # With the attenuator off (basic HDR), the same drift is absorbed.
    assert run_batch(np.full(3000, 0.45), HdrParams(attenuator=False)).I[
        -100:
    ].mean() == pytest.approx(-0.45, abs=0.05)


@settings(max_examples=100, deadline=None)
@given(
    pre=st.lists(small_rates, min_size=0, max_size=30),
    turn=st.floats(min_value=1.0, max_value=100.0),
    sign=st.sampled_from([-1.0, 1.0]),
    length=st.integers(5, 60),
)
def test_turn_above_theta_w_freezes_I(
    pre: list[float], turn: float, sign: float, length: int
) -> None:
    u = np.array(pre + [sign * turn] * length)
    tr = run_batch(u)
    # While the filtered corrected rate is above Theta_w, W = 0 and I does not change.
    above = np.abs(tr.filtered) > 0.564
    assert np.array_equal(tr.W == 0, above)
    I_next = np.append(tr.I[1:], tr.final.I)
    assert np.array_equal(I_next[above], tr.I[above])
    # A held turn of >= 1 deg/s gets above the threshold within a few steps and I stays put.
    k = len(pre)
    last = np.flatnonzero(~above[k:])
    settled = k + (int(last[-1]) + 1 if last.size else 0)
    assert settled <= k + 4
    assert np.all(tr.I[settled:] == tr.I[settled])


def test_turn_switch_off_lets_I_move_during_a_turn() -> None:
    tr = run_batch(np.full(10, 5.0), HdrParams(turn_switch=False))
    assert np.all(tr.W == 1) and tr.final.I < -0.1


def test_off_variant_yaw_is_cumulative_sum() -> None:
    rng = np.random.default_rng(5)
    u = rng.normal(0, 20, 3000)
    for T in (1.0, 0.5, 0.1):
        tr = run_batch(u, off(T=T))
        assert np.array_equal(tr.yaw, np.cumsum(u * T))
        assert np.array_equal(tr.omega, u) and not tr.I.any()


@settings(max_examples=50, deadline=None)
@given(u=st.lists(rates, max_size=40))
def test_off_variant_yaw_is_cumulative_sum_hypothesis(u: list[float]) -> None:
    tr = run_batch(u, off())
    assert np.array_equal(tr.yaw, np.cumsum(np.array(u, dtype=np.float64)))


def test_off_freezes_a_nonzero_starting_I_after_one_step() -> None:
    s0 = HdrState(I=-0.3)
    state, out = step(s0, 1.0, off())
    assert out.I == -0.3 and out.omega == 0.7 and state.I == 0.0


def test_state_and_params_are_immutable() -> None:
    s0 = HdrState(x=0.1, I=-0.2, yaw=3.0, r=4, s=1, n=7)
    copy = tuple(s0)
    with pytest.raises(AttributeError):
        s0.I = 1.0  # type: ignore[misc]
    s1, out = step(s0, 0.4)
    assert tuple(s0) == copy and s1 is not s0 and s1 != s0
    with pytest.raises(AttributeError):
        out.omega = 0.0  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        HdrParams().i_c = 1.0  # type: ignore[misc]
    # Stepping the same state twice gives the same result (no hidden state).
    assert step(s0, 0.4) == (s1, out)
    assert INITIAL_STATE == HdrState()


def test_as_dict_names_every_parameter() -> None:
    assert HdrParams().as_dict()["theta_w"] == 0.564


# -- the turn threshold is inclusive: |y| <= Theta_w is straight (Eq. 8) ------------------------


def _filtered_first(u: float, tau: float = 0.75, T: float = 1.0) -> float:
    """y_0 = x_0 from the initial state (x_-1 = 0, I_0 = 0), computed as the stepper does."""
    return (T * u + tau * 0.0) / (T + tau)


@pytest.mark.parametrize("u", [1.0, -0.7])
def test_y_exactly_at_theta_w_is_straight_and_one_ulp_above_is_a_turn(u: float) -> None:
    y0 = _filtered_first(u)
    at = HdrParams(theta_w=abs(y0))
    below = HdrParams(theta_w=math.nextafter(abs(y0), 0.0))
    (s_at, o_at), (s_below, o_below) = step(INITIAL_STATE, u, at), step(INITIAL_STATE, u, below)
    assert o_at.filtered == y0
    assert (o_at.W, o_below.W) == (1, 0)
    assert s_at.I == -math.copysign(at.i_c, u) and s_below.I == 0.0
    # The batch form and the many-parameter form draw the same line.
    for params, want_I in ((at, s_at.I), (below, 0.0)):
        trace = run_batch([u, 0.0], params)
        assert trace.W[0] == (1 if params is at else 0) and trace.I[1] == want_I
    yaw = run_many([u, 0.0], 0.0422, 0.75, [abs(y0), math.nextafter(abs(y0), 0.0)], 0.16, 1.80)
    assert yaw[1, 0] == u + (0.0 + s_at.I) and yaw[1, 1] == u


def test_batch_outputs_have_their_documented_types() -> None:
    trace = run_batch([0.3, -0.2, 0.0, 5.0])
    assert trace.r.dtype == np.int64 and trace.W.dtype == np.int8
    assert trace.omega.dtype == trace.yaw.dtype == trace.I.dtype == np.float64
    # signs of y: +, -, - (I was pulled back to 0 by step 1), +: the counter runs 1, 1, 2, 1
    assert trace.r.tolist() == [1, 1, 2, 1]
