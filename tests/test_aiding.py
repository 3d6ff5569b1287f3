"""GpsAiding (pure): mode switching, heading alignment across 0/360, continuity through an
outage, and bias learning, in closed loop with the real Pipeline fed real frames."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdrd.core.angles import wrap180
from hdrd.core.calibrate import given_bias
from hdrd.core.methods import MethodSetup
from hdrd.core.sensor import SensorModel
from hdrd.daemon.aiding import AIDED, DEAD_RECKONING, AidingConfig, GpsAiding, HeadingFix, StepView
from hdrd.daemon.pipeline import Pipeline
from hdrd.daemon.stepper import PipelineConfig, add_aid
from hdrd.io.net.gpsdjson import Fix

KNOT = 0.514444


def step_msg(
    heading: float,
    omega: float = 0.0,
    t: float = 1.0,
    raw: float = 0.0,
    bias: float = 0.0,
    **kw: Any,
) -> dict[str, Any]:
    """A step message shaped as the pipeline builds it (only the keys aiding reads)."""
    m = {
        "class": "HDR",
        "v": 1,
        "t": t,
        "step": max(0, round(t) - 1),
        "omega_raw": raw,
        "omega": omega,
        "yaw": 0.0,
        "heading": heading,
        "bias": bias,
        "status": "ok",
    }
    m.update(kw)
    return m


def on_message(
    a: GpsAiding, msg: dict[str, Any], now: float, owner: bool = False
) -> tuple[dict[str, Any], float]:
    """The aiding stage on a step shaped as the pipeline builds its message: the message with
    what the aiding adds (:func:`hdrd.daemon.pipeline.add_aid`) and the bias correction it
    returns for the static bias. A message without a heading (calibrating) is not shown to
    it."""
    if "heading" not in msg:
        return msg, 0.0
    is_step = "omega" in msg
    view = StepView(
        float(msg.get("t", 0.0)),
        float(msg["omega"]) if is_step else 0.0,
        float(msg.get("omega_raw", math.nan)),
        float(msg["bias"]),
        float(msg["heading"]),
        "gap_s" in msg,
        is_step,
    )
    aid = a.on_step(view, now, owner)
    out = dict(msg)
    add_aid(out, aid)
    return out, aid.bias_delta_dps


def good(course: float, speed: float = 15.0, **kw: Any) -> Fix:
    return Fix(mode=3, track_deg=course, speed_mps=speed, **kw)


def still(a: GpsAiding, fixes: Sequence[Fix | None], heading: float = 0.0) -> list[dict[str, Any]]:
    """A gyro standing still in its own frame (HDR heading ``heading``, omega 0) while the
    vehicle drives straight; fix k (None: none) arrives at k + 0.3 s, step k ends at k + 1."""
    out = []
    for k, f in enumerate(fixes):
        if f is not None:
            a.on_fix(f, k + 0.3)
        m, _ = on_message(a, step_msg(heading, t=k + 1.0), k + 1.0)
        out.append(m)
    return out


# -- helpers -----------------------------------------------------------------------------------


def test_config_rejects_nonsense():
    with pytest.raises(ValueError, match="align_gain"):
        AidingConfig(align_gain=1.5)
    with pytest.raises(ValueError, match="step_s"):
        AidingConfig(step_s=0.0)
    with pytest.raises(ValueError, match="min_speed_mps"):
        AidingConfig(min_speed_mps=math.nan)


# -- mode ----------------------------------------------------------------------------------------


def test_no_fix_is_dead_reckoning_and_heading_untouched():
    a = GpsAiding()
    out, delta = on_message(a, step_msg(123.0), now=10.0)
    assert out["mode"] == DEAD_RECKONING and out["heading"] == 123.0
    assert "gps_course" not in out and "heading_offset" not in out and "gps_speed" not in out
    assert delta == 0.0


def test_calibrating_message_passes_unchanged():
    a = GpsAiding()
    a.on_fix(good(90.0), 0.0)
    msg = {"class": "HDR", "v": 1, "t": 1.0, "step": 0, "omega_raw": 0.8, "status": "calibrating"}
    out, delta = on_message(a, msg, 0.5)
    assert out == msg and delta == 0.0


def test_good_fix_aligns_at_once_then_modes_follow_fix_quality():
    c = AidingConfig(min_speed_mps=5.0, max_fix_age_s=2.5, max_epd_deg=15.0)
    a = GpsAiding(c)
    a.on_fix(good(250.0, 12.0, epd=3.0), now=0.0)
    out, _ = on_message(a, step_msg(10.0), now=0.1)
    assert out["mode"] == AIDED
    assert out["heading"] == pytest.approx(250.0)
    assert out["heading_offset"] == pytest.approx(wrap180(240.0))
    assert out["gps_course"] == 250.0 and out["gps_speed"] == 12.0

    cases: list[tuple[str, Fix, float]] = [
        ("no fix (mode 1)", Fix(mode=1), 1.0),
        ("mode 0", Fix(mode=0, track_deg=250.0, speed_mps=12.0), 1.0),
        ("below min speed", good(250.0, 4.9), 1.0),
        ("no course", Fix(mode=3, speed_mps=12.0), 1.0),
        ("no speed", Fix(mode=2, track_deg=250.0), 1.0),
        ("course error too large", good(250.0, 12.0, epd=40.0), 1.0),
        ("stale", good(250.0, 12.0), -3.0),  # received 3 s before the step
    ]
    for what, fix, at in cases:
        a.on_fix(fix, now=at)
        out, _ = on_message(a, step_msg(10.0, t=2.0), now=1.1)
        assert out["mode"] == DEAD_RECKONING, what
        assert "gps_course" not in out, what
        # the last alignment still applies: heading continues
        assert out["heading"] == pytest.approx(250.0), what
    # a 2D fix above the speed threshold is good enough
    a.on_fix(Fix(mode=2, track_deg=251.0, speed_mps=5.0), now=2.0)
    out, _ = on_message(a, step_msg(10.0, t=3.0), now=2.2)
    assert out["mode"] == AIDED


def test_speed_for_the_standstill_detector():
    a = GpsAiding()
    assert a.speed(0.0) is None
    a.on_fix(good(0.0, speed=0.0), now=0.0)
    assert a.speed(1.0) == 0.0  # standing still: speed known, course not used
    out, _ = on_message(a, step_msg(5.0), now=1.0)
    assert out["mode"] == DEAD_RECKONING and out["gps_speed"] == 0.0
    assert a.speed(10.0) is None  # stale
    a.on_fix(Fix(mode=1), now=11.0)
    assert a.speed(11.0) is None


# -- the gate: each course tested against the gyro's prediction ------------------------------------


def test_one_outlier_course_moves_nothing():
    """The gyro is still, the GPS says 90 each second, and once 270 (a reversed course from
    a glitch): that course is rejected, its step is dead reckoning, the heading stays."""
    a = GpsAiding()
    fixes = [good(90.0)] * 10 + [good(270.0)] + [good(90.0)] * 5
    msgs = still(a, fixes)
    headings = [m["heading"] for m in msgs]
    assert max(herr(h, 90.0) for h in headings) < 1e-9, headings  # was a 36 deg step
    assert [m["mode"] for m in msgs] == [AIDED] * 10 + [DEAD_RECKONING] + [AIDED] * 5
    assert "gps_course" not in msgs[10]
    assert a.courses_rejected == 1 and a.realignments == 0
    (name, fields_), *_ = [e for e in a.events if e[0] == "gps_course_rejected"]
    assert fields_["course"] == 270.0 and abs(fields_["innovation_deg"]) == 180.0


def test_agreeing_rejections_realign():
    """The gyro's heading is what is wrong (it drifted 40 deg in an outage): after
    realign_after rejections in a row that agree, the heading takes the GPS course."""
    a = GpsAiding(AidingConfig(realign_after=3))
    msgs = still(a, [good(90.0)] * 5 + [good(130.0)] * 5)
    assert [m["mode"] for m in msgs] == [AIDED] * 5 + [DEAD_RECKONING] * 2 + [AIDED] * 3
    assert [round(m["heading"], 6) for m in msgs] == [90.0] * 7 + [130.0] * 3
    assert a.realignments == 1 and a.courses_rejected == 3
    assert ("gps_realigned", {"offset_deg": 130.0, "previous_offset_deg": 90.0}) in a.events


def test_rejections_that_disagree_never_realign():
    """Glitches in all directions: each is rejected, none realigns the heading."""
    a = GpsAiding(AidingConfig(realign_after=2))
    wild = [good(c) for c in (200.0, 300.0, 20.0, 250.0, 160.0, 330.0)]
    msgs = still(a, [good(90.0)] * 3 + wild)
    assert a.realignments == 0 and a.courses_rejected == 6
    assert all(herr(m["heading"], 90.0) < 1e-9 for m in msgs)


def test_the_gate_is_the_fixs_own_error_plus_the_gyros():
    c = AidingConfig(default_course_err_deg=5.0, gate_min_deg=2.0, max_drift_dps=0.1, latency_s=0.5)
    a = GpsAiding(c)
    assert a.course_err_deg(good(0.0, epd=7.5)) == 7.5  # gpsd's course error, 95 %
    assert a.course_err_deg(good(0.0, 10.0, eps=10.0)) == pytest.approx(45.0)  # atan(eps/speed)
    assert a.course_err_deg(good(0.0)) == 5.0  # neither sent
    assert a.gate_deg(good(0.0, epd=1.0), 0.0, 0.0) == 2.0  # never below gate_min_deg
    a.on_fix(good(10.0), 0.0)
    on_message(a, step_msg(10.0), 0.0)  # accepted at 0 s
    # 60 s later, in a 4 deg/s turn: 5 + 0.1 * 60 + 4 * 0.5
    assert a.gate_deg(good(0.0), 4.0, 60.0) == pytest.approx(13.0)
    # so a course 12 deg off is taken after a minute's outage, not a second after
    a.on_fix(good(22.0), 60.0)
    assert on_message(a, step_msg(10.0, omega=4.0, t=60.0), 60.0)[0]["mode"] == AIDED
    b = GpsAiding(c)
    b.on_fix(good(10.0), 0.0)
    on_message(b, step_msg(10.0), 0.0)
    b.on_fix(good(22.0), 1.0)
    assert on_message(b, step_msg(10.0, t=1.0), 1.0)[0]["mode"] == DEAD_RECKONING


def _after_an_hour(a: GpsAiding, fixes: Sequence[Fix | None]) -> list[dict[str, Any]]:
    """Aligned to 90 by five fixes while the gyro stands still in its own frame (HDR heading
    0), then an hour without a course, then ``fixes``, one a second."""
    still(a, [good(90.0)] * 5)
    out = []
    for k, f in enumerate(fixes):
        now = 3600.0 + k
        if f is not None:
            a.on_fix(f, now - 0.7)
        out.append(on_message(a, step_msg(0.0, t=now), now)[0])
    return out


def test_after_a_long_gap_one_course_moves_nothing_and_several_agreeing_reacquire():
    """After an hour with no course accepted the gate had grown to 365 deg: one fix 180 deg
    off was accepted and moved the heading 90 -> 54 deg (reported "aided"), and the true
    courses after it were rejected. Now the gate stops at gate_max_deg, and after a long gap
    no single course is taken: realign_after courses in a row that agree re-acquire."""
    a = GpsAiding(AidingConfig(realign_after=3))
    msgs = _after_an_hour(a, [good(270.0)] + [good(90.0)] * 5)
    assert [round(m["heading"], 6) for m in msgs] == [90.0] * 6
    assert [m["mode"] for m in msgs] == [DEAD_RECKONING] * 3 + [AIDED] * 3
    assert a.realignments == 1
    (name, fields_) = next(e for e in a.events if e[0] == "gps_realigned")
    assert fields_["reason"] == "re-acquired after a long gap"
    rejected = [f for n, f in a.events if n == "gps_course_rejected"]
    assert rejected[0]["course"] == 270.0 and rejected[0]["long_gap_s"] >= 3590.0


def test_after_a_long_gap_one_true_course_is_not_enough_either():
    a = GpsAiding(AidingConfig(realign_after=3))
    msgs = _after_an_hour(a, [good(95.0), None, None])
    assert msgs[0]["mode"] == DEAD_RECKONING and herr(msgs[0]["heading"], 90.0) < 1e-9


def test_the_gate_stops_widening_at_gate_max_deg():
    a = GpsAiding(AidingConfig(gate_max_deg=30.0, max_drift_dps=0.1))
    a.on_fix(good(10.0), 0.0)
    on_message(a, step_msg(10.0), 0.0)
    assert a.gate_deg(good(0.0), 0.0, 100.0) == pytest.approx(15.0)
    assert a.gate_deg(good(0.0), 0.0, 3600.0) == 30.0
    assert a.gate_deg(good(0.0), 100.0, 1.0) == 30.0  # a fast turn's latency too
    assert not a.long_gap(299.0) and a.long_gap(300.0)
    with pytest.raises(ValueError, match="gate_max_deg"):
        AidingConfig(gate_min_deg=10.0, gate_max_deg=5.0)


@pytest.mark.parametrize(
    "fix",
    [
        good(150.0, 10.0, eps=10.0 * math.tan(math.radians(60.0))),  # 60 deg from eps
        good(150.0, epd=60.0),
    ],
)
def test_a_course_error_above_max_epd_deg_is_not_used_however_it_is_known(fix: Fix) -> None:
    """A course error worked out from eps was not held to max_epd_deg: a course 60 deg off
    with eps saying 60 deg was accepted. Now any course error above max_epd_deg means no
    course."""
    a = GpsAiding(AidingConfig(max_epd_deg=15.0))
    msgs = still(a, [good(90.0)] * 3 + [fix])
    assert a.course_err_deg(fix) == pytest.approx(60.0)
    assert a.good_fix(3.5) is None
    assert msgs[-1]["mode"] == DEAD_RECKONING and herr(msgs[-1]["heading"], 90.0) < 1e-9
    assert a.courses_rejected == 0  # not a gate rejection: no course at all


@given(
    st.floats(0.0, 359.9),
    st.floats(-179.0, 179.0),
    st.floats(0.1, 15.0),  # up to max_epd_deg: a larger error is no good fix at all
)
def test_a_course_is_taken_if_and_only_if_it_is_inside_the_gate(course, off, epd):
    a = GpsAiding(AidingConfig(gate_min_deg=1.0))
    a.on_fix(good(course), 0.0)
    on_message(a, step_msg(0.0), 0.0)  # aligned to course
    a.on_fix(good((course + off) % 360.0, epd=epd), 1.0)
    out, _ = on_message(a, step_msg(0.0, t=2.0), 1.0)
    inside = abs(off) <= a.gate_deg(good(0.0, epd=epd), 0.0, 1.0) - 1e-9
    outside = abs(off) >= a.gate_deg(good(0.0, epd=epd), 0.0, 1.0) + 1e-9
    if inside:
        assert out["mode"] == AIDED
    elif outside:
        assert out["mode"] == DEAD_RECKONING and herr(out["heading"], course) < 1e-6


# -- one receiver followed ---------------------------------------------------------------------------


def test_a_second_receiver_without_a_fix_is_ignored():
    """gpsd reads two receivers; the second has no fix. Its TPVs (mode 1) used to end aiding
    at every step."""
    a = GpsAiding()
    for k in range(100):
        a.on_fix(good(90.0, device="/dev/ttyUSB0"), k + 0.2)
        a.on_fix(Fix(mode=1, device="/dev/ttyUSB1"), k + 0.4)
        out, _ = on_message(a, step_msg(0.0, t=k + 1.0), k + 1.0)
        assert out["mode"] == AIDED, k
    assert a.device == "/dev/ttyUSB0" and a.fixes_ignored == 100
    assert [e for e in a.events if e[0] == "gps_device"] == [
        ("gps_device", {"device": "/dev/ttyUSB0"})
    ]


def test_two_receivers_courses_never_alternate():
    """Two receivers with fixes, courses 90 and 93 (a different antenna, a different
    error): the heading follows the first alone."""
    a = GpsAiding()
    for k in range(60):
        a.on_fix(good(90.0, device="/dev/ttyACM0"), k + 0.2)
        a.on_fix(good(93.0, device="/dev/ttyACM1"), k + 0.4)
        out, _ = on_message(a, step_msg(0.0, t=k + 1.0), k + 1.0)
        assert out["mode"] == AIDED and out["gps_course"] == 90.0
        assert herr(out["heading"], 90.0) < 1e-9
    assert a.courses_rejected == 0 and a.fixes_ignored == 60


def test_a_configured_receiver_only_and_a_quiet_one_hands_over():
    a = GpsAiding(AidingConfig(device="/dev/gps1"))
    a.on_fix(good(50.0, device="/dev/gps0"), 0.0)
    assert on_message(a, step_msg(0.0), 0.1)[0]["mode"] == DEAD_RECKONING
    a.on_fix(good(60.0, device="/dev/gps1"), 0.2)
    out, _ = on_message(a, step_msg(0.0, t=2.0), 0.3)
    assert out["mode"] == AIDED and out["gps_course"] == 60.0
    # a configured receiver is never replaced, however long it is quiet
    a.on_fix(good(50.0, device="/dev/gps0"), 100.0)
    assert on_message(a, step_msg(0.0, t=3.0), 100.1)[0]["mode"] == DEAD_RECKONING

    b = GpsAiding(AidingConfig(device_timeout_s=10.0))
    b.on_fix(good(60.0, device="A"), 0.0)
    on_message(b, step_msg(0.0), 0.1)
    b.on_fix(Fix(mode=1, device="A"), 1.0)  # A loses its fix
    b.on_fix(good(61.0, device="B"), 5.0)  # B within the timeout: ignored
    assert on_message(b, step_msg(0.0, t=5.0), 5.1)[0]["mode"] == DEAD_RECKONING
    b.on_fix(good(61.0, device="B"), 10.5)  # A has had no fix for 10.5 s: B takes over
    out, _ = on_message(b, step_msg(0.0, t=11.0), 10.6)
    assert out["mode"] == AIDED and out["gps_course"] == 61.0 and b.device == "B"
    assert ("gps_device", {"device": "B", "previous": "A"}) in b.events


# -- alignment -------------------------------------------------------------------------------------


def test_alignment_is_smooth_and_wraps_at_north():
    c = AidingConfig(align_gain=0.25)
    a = GpsAiding(c)
    a.on_fix(good(2.0), 0.0)
    on_message(a, step_msg(100.0, t=1.0), 0.0)  # snap: offset -98
    assert a.offset_deg == pytest.approx(-98.0)
    # GPS now says 358 (4 deg to the left across north): the error is -4, not +356
    a.on_fix(good(358.0), 1.0)
    out, _ = on_message(a, step_msg(100.0, t=2.0), 1.0)
    assert a.offset_deg == pytest.approx(-99.0)
    assert out["heading"] == pytest.approx(1.0)
    out, _ = on_message(a, step_msg(100.0, t=3.0), 1.0)
    assert out["heading"] == pytest.approx(0.25)
    out, _ = on_message(a, step_msg(100.0, t=4.0), 1.0)
    assert out["heading"] == pytest.approx(359.6875)
    assert 0.0 <= out["heading"] < 360.0


def test_no_alignment_update_in_a_fast_turn():
    a = GpsAiding(AidingConfig(align_max_rate_dps=3.0))
    a.on_fix(good(90.0), 0.0)
    on_message(a, step_msg(90.0, t=1.0), 0.0)
    a.on_fix(good(86.0), 1.0)
    on_message(a, step_msg(90.0, omega=10.0, t=2.0), 1.0)
    assert a.offset_deg == 0.0
    on_message(a, step_msg(90.0, omega=2.0, t=3.0), 1.0)
    assert a.offset_deg != 0.0


def test_course_carried_forward_by_the_gyro_over_the_fix_age():
    """A left turn (omega > 0, CCW) lowers the compass course: a fix 0.5 s old at 10 deg/s
    predicts 5 deg less than it says."""
    a = GpsAiding()
    a.on_fix(good(3.0), 0.0)
    out, _ = on_message(a, step_msg(50.0, omega=10.0), 0.5)
    assert out["heading"] == pytest.approx(358.0)


# -- closed loop with the real pipeline ---------------------------------------------------------------


@dataclass(frozen=True)
class Frame:
    t_us: int
    rate: int
    ref: int = 0
    temp_c: float | None = None


@dataclass
class Run:
    msgs: list[dict[str, Any]]
    hdr_headings: list[float]
    truth: list[float]  # true compass course at each step's end
    gps_ok: list[bool]
    pipeline: Pipeline
    aiding: GpsAiding


def drive(
    rate_ccw: Callable[[np.ndarray], np.ndarray],
    seconds: float,
    *,
    course0: float = 80.0,
    speed: Callable[[float], float] = lambda t: 15.0,
    gps_ok: Callable[[float], bool] = lambda t: True,
    bias_true: float = 0.5,
    bias_given: float = 0.3,
    gyro_noise: float = 0.05,
    course_noise: float = 0.3,
    config: AidingConfig | None = None,
    method: str = "hdr",
    seed: int = 1,
    heading0: float = 0.0,
) -> Run:
    """A drive: the true CCW rate profile (deg/s), the raw gyro = truth + bias + noise at
    10 Hz through the real sensor model and Pipeline; a 1 Hz GPS fix of the true course
    (+ noise) before each step while ``gps_ok``; the step's device time is the clock."""
    hz = 10.0
    rng = np.random.default_rng(seed)
    n = int(seconds * hz)
    t = np.arange(n) / hz
    w_true = rate_ccw(t)
    raw = w_true + bias_true + rng.normal(0, gyro_noise, n)
    counts = SensorModel().to_counts(raw)
    # true course at t: course0 - integral of the CCW rate (trapezoid on the 10 Hz grid,
    # evaluated at the samples; block ends fall on samples)
    yaw_true = np.concatenate([[0.0], np.cumsum(w_true[:-1]) / hz])
    p = Pipeline(
        PipelineConfig(
            heading0_deg=heading0, setup=MethodSetup(method=method, bias=given_bias(bias_given))
        )
    )
    a = GpsAiding(config or AidingConfig())
    run = Run([], [], [], [], p, a)
    for i in range(n):
        for m in p.feed(Frame(round(t[i] * 1e6), int(counts[i]))):
            now = float(m["t"])
            truth = (course0 - yaw_true[i]) % 360.0  # m["t"] is this sample's time
            ok = gps_ok(now)
            if ok:
                a.on_fix(good((truth + rng.normal(0, course_noise)) % 360.0, speed(now)), now)
            else:
                a.on_fix(Fix(mode=1), now)
            out, delta = on_message(a, m, now)
            p.adjust_bias(delta, "gps")
            run.msgs.append(out)
            run.hdr_headings.append(m["heading"])
            run.truth.append(truth)
            run.gps_ok.append(ok)
    return run


def herr(a: float, b: float) -> float:
    return abs(wrap180(a - b))


def test_bias_learning_converges_on_a_straight_drive():
    run = drive(lambda t: np.zeros_like(t), 900.0, bias_true=0.5, bias_given=0.3, course0=359.5)
    assert run.pipeline.bias is not None
    learned = run.pipeline.bias.bias_dps
    assert learned == pytest.approx(0.5, abs=0.02), learned
    assert type(learned) is float  # published as JSON: no numpy scalars
    assert run.aiding.windows >= 40 and run.aiding.windows_discarded == 0
    assert any(name == "bias_adjusted" and f["source"] == "gps" for name, f in run.pipeline.events)
    # the published bias follows the pipeline's, and the heading stays on the GPS course
    assert run.msgs[-1]["bias"] == pytest.approx(learned, abs=0.1)
    assert all(m["mode"] == AIDED for m in run.msgs)
    assert max(herr(m["heading"], tr) for m, tr in zip(run.msgs[-300:], run.truth[-300:])) < 1.5


def test_no_bias_learning_while_turning():
    # a slow circle: 2 deg/s, well above the straight-driving threshold, for 5 minutes
    run = drive(lambda t: np.full_like(t, 2.0), 300.0, bias_true=0.5, bias_given=0.3)
    assert run.aiding.windows == 0 and run.aiding.bias_learned_dps == 0.0
    assert run.pipeline.bias is not None and run.pipeline.bias.bias_dps == 0.3
    # aided all along: the heading follows the GPS course through the turn
    assert all(m["mode"] == AIDED for m in run.msgs)
    assert max(herr(m["heading"], tr) for m, tr in zip(run.msgs[10:], run.truth[10:])) < 3.0


def test_no_aiding_below_the_speed_threshold():
    run = drive(
        lambda t: np.zeros_like(t),
        200.0,
        speed=lambda t: 3.0,
        config=AidingConfig(min_speed_mps=5.0),
        heading0=10.0,
    )
    assert all(m["mode"] == DEAD_RECKONING for m in run.msgs)
    assert all(m["gps_speed"] == 3.0 for m in run.msgs)
    assert run.aiding.windows == 0 and run.aiding.offset_deg is None
    assert [m["heading"] for m in run.msgs] == run.hdr_headings


def test_a_window_with_an_implausible_estimate_is_discarded():
    run = drive(
        lambda t: np.zeros_like(t),
        100.0,
        bias_true=0.9,
        bias_given=0.0,
        config=AidingConfig(max_residual_dps=0.5, straight_max_dps=2.0),
        method="none",
    )
    assert run.aiding.windows >= 4 and run.aiding.windows_discarded == run.aiding.windows
    assert run.aiding.bias_learned_dps == 0.0


def test_outage_dead_reckons_with_hdr_and_heading_stays_continuous():
    """Drive north-west through north with turns; GPS lost for 120 s (with a right turn
    inside), then back. Aided -> dead-reckoning -> aided; the published heading never
    jumps: step-to-step it changes like the HDR heading, up to the smooth alignment."""

    def rate(t: np.ndarray) -> np.ndarray:
        w = np.zeros_like(t)
        w[(t >= 100) & (t < 110)] = 9.0  # left 90 deg (compass course down, through north)
        w[(t >= 200) & (t < 215)] = -6.0  # right 90 deg, inside the outage
        w[(t >= 350) & (t < 360)] = 4.5  # left 45 deg after the outage
        return w

    outage = (170.0, 290.0)
    c = AidingConfig()
    run = drive(
        rate,
        450.0,
        course0=40.0,
        gps_ok=lambda t: not (outage[0] <= t < outage[1]),
        bias_true=0.5,
        bias_given=0.3,
        config=c,
    )
    modes = [m["mode"] for m in run.msgs]
    # the sequence of modes: aided, dead-reckoning, aided
    runs = [modes[0]] + [b for a_, b in itertools.pairwise(modes) if a_ != b]
    assert runs == [AIDED, DEAD_RECKONING, AIDED]
    dr = [i for i, m in enumerate(modes) if m == DEAD_RECKONING]
    assert run.msgs[dr[0]]["t"] == pytest.approx(outage[0]) and run.msgs[dr[-1] + 1][
        "t"
    ] == pytest.approx(outage[1])
    # the heading crossed north while aided (wrap handled: close to the truth throughout)
    crossed = [m["heading"] for m in run.msgs[100:115]]
    assert min(crossed) < 10.0 and max(crossed) > 350.0
    for i, (m, tr) in enumerate(zip(run.msgs, run.truth)):
        if 20 <= i < outage[0]:
            assert herr(m["heading"], tr) < 1.5, (i, m["heading"], tr)
    # during the outage the heading is the HDR heading plus the last offset (no jumps)
    off = run.msgs[dr[0]]["heading_offset"]
    for i in dr:
        assert run.msgs[i]["heading_offset"] == off
        assert herr(run.msgs[i]["heading"], run.hdr_headings[i] + off) < 1e-9
    # dead reckoning with the GPS-learned bias: within a few degrees after 2 minutes
    assert herr(run.msgs[dr[-1]]["heading"], run.truth[dr[-1]]) < 3.0
    # continuity: each step's change equals the HDR heading's change, plus at most
    # align_gain of the (small) remaining error; no snap when the GPS comes back
    for i in range(1, len(run.msgs)):
        d_pub = wrap180(run.msgs[i]["heading"] - run.msgs[i - 1]["heading"])
        d_hdr = wrap180(run.hdr_headings[i] - run.hdr_headings[i - 1])
        assert abs(d_pub - d_hdr) <= c.align_gain * 5.0 + 1e-6, (i, d_pub, d_hdr)
    # and back on the GPS course after re-acquisition
    assert herr(run.msgs[-1]["heading"], run.truth[-1]) < 1.5


def test_stale_messages_get_the_alignment_but_change_nothing():
    a = GpsAiding()
    a.on_fix(good(200.0), 0.0)
    on_message(a, step_msg(20.0), 0.0)
    stale = {
        "class": "HDR",
        "v": 1,
        "step": 0,
        "yaw": -20.0,
        "heading": 20.0,
        "bias": 0.0,
        "status": "stale",
        "stale_s": 3.0,
    }
    a.on_fix(good(203.0), 1.0)  # within the gate: aided, but a stale report moves nothing
    out, delta = on_message(a, stale, 1.0)
    assert out["heading"] == pytest.approx(200.0) and out["mode"] == AIDED and delta == 0.0
    assert a.offset_deg == pytest.approx(-180.0)  # wrapped to [-180, 180)


def test_a_gap_restarts_the_bias_window():
    c = AidingConfig(bias_window_s=5.0, bias_gain=1.0, max_bias_step_dps=1.0)
    a = GpsAiding(c)
    deltas = []
    for k in range(1, 12):
        a.on_fix(good(90.0), float(k))
        extra = {"gap_s": 2.0} if k == 4 else {}
        _, d = on_message(a, step_msg(90.0, t=float(k), raw=0.2, bias=0.0, **extra), float(k))
        deltas.append(d)
    # windows: steps 5..9 (the gap at 4 restarts at 5), the next would end at 14
    assert [i + 1 for i, d in enumerate(deltas) if d] == [10]
    assert deltas[9] == pytest.approx(0.2)


def test_replace_keeps_config_frozen():
    c = AidingConfig()
    assert replace(c, min_speed_mps=2.0).min_speed_mps == 2.0
    with pytest.raises(AttributeError):
        c.min_speed_mps = 1.0  # type: ignore[misc]


def test_a_tpv_without_course_does_not_hide_a_fresh_course():
    """gpsd 3.22 reports a TPV after the GGA (no course; speed from positions) and another
    after the RMC until it has found the cycle end: aiding must not flicker."""
    a = GpsAiding(AidingConfig(max_fix_age_s=2.5))
    a.on_fix(good(45.0, 12.0), 0.0)
    a.on_fix(Fix(mode=3, speed_mps=11.5), 0.5)  # GGA-only TPV of the next epoch
    out, _ = on_message(a, step_msg(0.0), 0.6)
    assert out["mode"] == AIDED and out["gps_course"] == 45.0 and out["gps_speed"] == 11.5
    # ... but only while that course is fresh
    a.on_fix(Fix(mode=3, speed_mps=11.5), 2.0)
    out, _ = on_message(a, step_msg(0.0, t=2.0), 2.6)
    assert out["mode"] == DEAD_RECKONING and out["gps_speed"] == 11.5
    # a TPV without a fix ends aiding at once, and the speed is unknown then
    a.on_fix(good(45.0, 12.0), 3.0)
    assert on_message(a, step_msg(0.0, t=3.0), 3.1)[0]["mode"] == AIDED
    a.on_fix(Fix(mode=1), 3.5)
    out, _ = on_message(a, step_msg(0.0, t=4.0), 3.6)
    assert out["mode"] == DEAD_RECKONING and "gps_speed" not in out and a.speed(3.6) is None


def test_the_age_of_the_last_course_is_published_once_there_is_one() -> None:
    a = GpsAiding()
    assert "gps_age_s" not in on_message(a, step_msg(10.0), 1.0)[0]  # no course yet
    a.on_fix(good(90.0), 1.25)
    assert on_message(a, step_msg(10.0), 2.0)[0]["gps_age_s"] == 0.75
    a.on_fix(Fix(mode=1), 2.5)  # no fix: the course keeps its age
    out = on_message(a, step_msg(10.0), 31.0)[0]
    assert out["mode"] == DEAD_RECKONING and out["gps_age_s"] == 29.75


def test_a_method_that_owns_the_bias_gets_the_course_as_a_measurement() -> None:
    """HDR+ estimates bias and heading error itself: the aiding aligns its heading once (a
    reset of known variance), then hands it each good course as the published heading minus
    the course, and neither moves the offset nor returns a bias correction."""
    a = GpsAiding()
    a.on_fix(good(100.0, epd=3.92), 0.0)
    first = a.on_step(StepView(1.0, 0.0, 0.2, 0.0, 90.0), 0.5, owner=True)
    assert first.fix is not None and first.fix.reset and first.fix.err_deg == 0.0
    assert first.fix == HeadingFix(0.0, first.fix.var_deg2, True)
    assert first.fix.var_deg2 == pytest.approx(4.0)  # (3.92 / 1.96)^2
    assert first.offset_deg == pytest.approx(10.0) and first.heading_deg == pytest.approx(100.0)
    for k in range(2, 60):  # a gyro drifting 0.05 deg/s clockwise of a straight course
        a.on_fix(good(100.0, epd=3.92), k - 0.7)
        aid = a.on_step(StepView(float(k), 0.0, 0.2, 0.0, 90.0 + 0.05 * k), k - 0.5, owner=True)
        assert aid.mode == AIDED and aid.bias_delta_dps == 0.0
        assert aid.fix is not None and not aid.fix.reset
        assert aid.fix.err_deg == pytest.approx(0.05 * k)  # heading - course
        assert aid.offset_deg == pytest.approx(10.0)  # the offset stays
    # in a fast turn the course's latency makes it no measurement
    a.on_fix(good(100.0, epd=3.92), 59.3)
    turning = a.on_step(StepView(60.0, 5.0, 5.2, 0.0, 96.0), 59.5, owner=True)
    assert turning.fix is None
    # the baselines (owner False) get the offset moved instead
    b = GpsAiding()
    b.on_fix(good(100.0), 0.0)
    b.on_step(StepView(1.0, 0.0, 0.2, 0.0, 90.0), 0.5)
    b.on_fix(good(100.0), 1.3)
    base = b.on_step(StepView(2.0, 0.0, 0.2, 0.0, 91.0), 1.5)
    assert base.fix is None and base.offset_deg == pytest.approx(10.0 - 0.2)


# -- courses faster than the step, and speeds no car has ------------------------------------------


def alternating(a: GpsAiding, seconds: int, seed: int = 3) -> list[dict[str, Any]]:
    """A still gyro (HDR heading 90) whose GPS first says 90 once a second for 5 s, then
    reports at about 100 Hz, alternating 90 and 270 (two antennas, a receiver's bug); how many
    fixes land in a step varies, so the course last before a step is now one, now the other."""
    rng = np.random.default_rng(seed)
    out = still(a, [good(90.0)] * 5, heading=90.0)
    k = 0
    for s in range(5, 5 + seconds):
        n = int(rng.integers(95, 106))
        for i in range(n):
            a.on_fix(good(90.0 if k % 2 == 0 else 270.0), s + i / n)
            k += 1
        m, _ = on_message(a, step_msg(90.0, t=s + 1.0), s + 1.0)
        out.append(m)
    return out


def test_courses_that_disagree_within_a_step_are_not_evidence() -> None:
    """100 fixes a step, alternating 90 and 270: they are not a hundred agreeing witnesses
    of either; the step takes no course (dead reckoning) and nothing realigns. The heading used
    to flip to 270 and back (twice in 17 s), published as aided."""
    a = GpsAiding()
    msgs = alternating(a, 60)
    assert a.realignments == 0, [e for e in a.events if e[0] == "gps_realigned"]
    assert all(herr(m["heading"], 90.0) < 1e-9 for m in msgs), [m["heading"] for m in msgs]
    assert [m["mode"] for m in msgs[5:]] == [DEAD_RECKONING] * 60
    assert a.courses_disagreeing == 60
    (first, *_) = [f for name, f in a.events if name == "gps_courses_disagree"]
    assert first["spread_deg"] == 180.0 and first["allowed_deg"] < 180.0


def test_fast_fixes_that_agree_are_aided() -> None:
    """A 10 Hz receiver on a straight road, its course noisy within its error estimate, and
    a 20 Hz one in a turn at 20 deg/s: every step aided, nothing found disagreeing."""
    rng = np.random.default_rng(4)
    a = GpsAiding()
    for s in range(60):
        for i in range(10):
            a.on_fix(good(90.0 + rng.normal(0.0, 1.5), epd=3.0), s + i / 10)
        m, _ = on_message(a, step_msg(90.0, t=s + 1.0), s + 1.0)
        assert m["mode"] == AIDED
    b = GpsAiding()
    for s in range(20):
        for i in range(20):
            b.on_fix(good((90.0 - 20.0 * (s + i / 20)) % 360.0, speed=12.0), s + i / 20)
        m, _ = on_message(b, step_msg((90.0 - 20.0 * (s + 1)) % 360.0, 20.0, t=s + 1.0), s + 1.0)
    assert a.courses_disagreeing == b.courses_disagreeing == 0


@pytest.mark.parametrize("speed", [1e9, 151.0, 1e300])
def test_a_speed_no_car_has_is_not_a_fix(speed: float) -> None:
    """A TPV with a ground speed beyond any car's (150 m/s, 540 km/h) is refused as a fix:
    its course and speed are not used nor published, aiding ends as for a report without a
    fix, and the refusal is counted and said."""
    a = GpsAiding()
    msgs = still(a, [good(90.0)] * 3 + [good(95.0, speed=speed)] * 3 + [good(90.0)] * 2)
    assert [m["mode"] for m in msgs] == [AIDED] * 3 + [DEAD_RECKONING] * 3 + [AIDED] * 2
    assert all("gps_speed" not in m and "gps_course" not in m for m in msgs[3:6])
    assert all(m["gps_speed"] == 15.0 for m in msgs[:3] + msgs[6:])
    assert a.fixes_refused == 3
    b = GpsAiding()
    b.on_fix(good(90.0), 0.0)
    b.on_fix(good(90.0, speed=speed), 0.5)
    assert b.speed(0.6) is None and b.good_fix(0.6) is None  # not the standstill test's either
    refused = [f for name, f in a.events if name == "gps_fix_refused"]
    assert refused[0]["speed_mps"] == speed and refused[0]["max_speed_mps"] == 150.0
