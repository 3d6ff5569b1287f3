"""The self-check through GNSS outages (hdrd/core/selfcheck.py): virtual outages on the
estimator's own steps, scored only from what came after their start, and the record that picks
a real outage's policy. Headings deg; rates deg/s, + = CCW."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hdrd.core import hdrplus
from hdrd.core.plusparams import DEFAULTS
from hdrd.core.selfcheck import (
    FROZEN,
    MIN_TRIALS,
    REDUCED,
    OutageRecord,
    PolicyScore,
    SelfCheck,
    frozen_params,
)
from hdrd.core.steps import StepInput

NAN = math.nan


def _aided_run(
    u: np.ndarray, speed: np.ndarray, check: SelfCheck, true_yaw: np.ndarray
) -> list[OutageRecord]:
    """HDR+ aided by a perfect course every step (variance 1 deg^2), with the self-check; the
    record after each step."""
    state = hdrplus.INITIAL_PLUS_STATE
    yaw_prev = 0.0
    records = []
    for i in range(u.shape[0]):
        herr = true_yaw[i - 1] - yaw_prev if i > 0 else 0.0
        inp = StepInput(float(u[i]), 0.1, float(speed[i]), NAN, 1.0, herr, 1.0, i == 0)
        before = state
        state, out = hdrplus.step(state, inp, DEFAULTS)
        check.on_step(before, inp, DEFAULTS, out.yaw, True)
        yaw_prev = out.yaw
        records.append(check.record)
    return records


def test_the_record_takes_frozen_until_drift_reduction_has_shown_it_is_better() -> None:
    r = OutageRecord()
    assert r.policy() == FROZEN and r.trials == 0
    for _ in range(MIN_TRIALS - 1):
        r = r.add(FROZEN, 3.0).add(REDUCED, -1.0)
    assert r.policy() == FROZEN  # better, but not yet often enough
    r = r.add(FROZEN, -3.0).add(REDUCED, 1.0)
    assert r.policy() == REDUCED and r.trials == MIN_TRIALS
    for _ in range(3):
        r = r.add(FROZEN, 0.5).add(REDUCED, 9.0)
    assert r.policy() == FROZEN  # the record turned
    assert r.score(REDUCED).mean_abs_deg == pytest.approx((1.0 * 3 + 9.0 * 3) / 6)


def test_a_record_round_trips_and_bad_ones_are_refused() -> None:
    r = OutageRecord().add(FROZEN, 2.0).add(FROZEN, -4.0).add(REDUCED, 1.0)
    back = OutageRecord.from_dict(r.to_dict())
    assert back.score(FROZEN).n == 2 and back.score(FROZEN).mean_abs_deg == pytest.approx(3.0)
    assert back.score(FROZEN).sum_sq_deg2 == pytest.approx(20.0, rel=1e-3)
    assert OutageRecord.from_dict({}).trials == 0
    for bad, why in (
        ([], "must be a mapping"),
        ({FROZEN: 3}, "must be a mapping"),
        ({FROZEN: {"n": -1}}, "must be a count"),
        ({FROZEN: {"n": 2, "mean_abs_deg": 1e9, "rms_deg": 1.0}}, "must be in 0..360"),
        ({FROZEN: {"n": 2, "mean_abs_deg": 1.0}}, "rms_deg must be in 0..360"),
    ):
        with pytest.raises(ValueError, match=why):
            OutageRecord.from_dict(bad)


def test_virtual_outages_are_scored_against_the_aided_heading_at_their_end() -> None:
    # A unit whose driving bias is 0.05 deg/s off its calibration: the courses teach it, so a
    # 20 s virtual outage ends within about a degree of the aided heading, for either policy.
    rng = np.random.default_rng(1)
    n = 300
    true = rng.normal(0.0, 0.2, n)
    u = true + 0.05
    check = SelfCheck(length_steps=20, every_steps=30)
    _aided_run(u, np.full(n, 15.0), check, np.cumsum(true))
    f, r = check.record.score(FROZEN), check.record.score(REDUCED)
    assert f.n == r.n >= 8  # a new one every 30 steps once aligned
    assert f.mean_abs_deg < 1.0 and r.mean_abs_deg < 1.0


def test_a_virtual_outage_uses_nothing_after_its_end() -> None:
    # Two drives alike up to step 60, then one turns: the outages that ended by then are
    # scored the same in both, and the record differs only once the turn is in an outage.
    rng = np.random.default_rng(2)
    n = 120
    true = rng.normal(0.0, 0.2, n)
    later = true.copy()
    later[61:] += 5.0
    a, b = SelfCheck(length_steps=20, every_steps=40), SelfCheck(length_steps=20, every_steps=40)
    ra = _aided_run(true + 0.03, np.full(n, 15.0), a, np.cumsum(true))
    rb = _aided_run(later + 0.03, np.full(n, 15.0), b, np.cumsum(later))
    assert ra[60].trials >= 1 and ra[60] == rb[60]
    assert ra[-1] != rb[-1]


def test_an_outage_that_ends_unaided_is_dropped_and_frozen_settings_measure_nothing() -> None:
    check = SelfCheck(length_steps=3, every_steps=3)
    state = hdrplus.INITIAL_PLUS_STATE
    for i in range(10):
        inp = StepInput(
            0.1, 0.1, 10.0, NAN, 1.0, 0.0 if i < 5 else NAN, 1.0 if i < 5 else NAN, i == 0
        )
        before = state
        state, out = hdrplus.step(state, inp, DEFAULTS)
        check.on_step(before, inp, DEFAULTS, out.yaw, i < 5)
    assert check.record.trials <= 1  # those ending after step 5 were not scored
    assert frozen_params(DEFAULTS).measure is False and DEFAULTS.measure is True
    with pytest.raises(ValueError, match="at least one step"):
        SelfCheck(length_steps=0)
    assert PolicyScore().mean_abs_deg != PolicyScore().mean_abs_deg  # NaN before one
