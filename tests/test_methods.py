"""The drift-reducer registry (hdrd/core/methods.py): each method's batch form is its step looped,
settings are derived in one place, and the config and the command line take their names from it.

Rates in deg/s, + = CCW; speeds m/s; temperatures degC; steps of T seconds.
"""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd import config as config_mod
from hdrd.config import ConfigError
from hdrd.configload import parse_config
from hdrd.core import methods
from hdrd.core.calibrate import BiasRecord
from hdrd.core.hdr import HdrParams
from hdrd.core.hdrplus import PlusOutput
from hdrd.core.methods import REGISTRY, MethodSetup, StepInputs, plus_settings
from hdrd.core.plusparams import PlusParams
from tests.test_hdrplus import core_params, plus_params

NAN = math.nan
rate = st.floats(-5.0, 5.0)
spread = st.floats(0.0, 1.0)
speed = st.one_of(st.just(NAN), st.just(0.0), st.floats(0.0, 30.0))
temp = st.one_of(st.just(NAN), st.floats(-10.0, 40.0))
rows = st.lists(st.tuples(rate, spread, speed, temp), min_size=0, max_size=60)


def _steps(rows: list[tuple[float, float, float, float]], T: float) -> StepInputs:
    a = np.array(rows, dtype=np.float64).reshape(len(rows), 4)
    return StepInputs(
        u=a[:, 0],
        t_end=(np.arange(len(rows), dtype=np.float64) + 1.0) * T,
        T=T,
        bias_dps=0.0,
        n_samples=np.full(len(rows), 10, np.int64),
        speed=a[:, 2],
        temp_c=a[:, 3],
        omega_std=a[:, 1],
    )


@pytest.mark.parametrize("name", sorted(REGISTRY))
@settings(max_examples=60, deadline=None)
@given(
    data=rows,
    hdr=core_params(),
    plus=plus_params(),
    n=st.sampled_from([None, 1.0, 10.0, 100.0]),
    bias=st.one_of(
        st.none(),
        st.builds(
            BiasRecord, st.floats(-2, 2), st.floats(0, 0.5), st.integers(0, 3000), st.just(30.0)
        ),
    ),
)
def test_batch_is_the_step_looped_bit_for_bit(
    name: str,
    data: list[tuple[float, float, float, float]],
    hdr: HdrParams,
    plus: PlusParams,
    n: float | None,
    bias: BiasRecord | None,
) -> None:
    m = REGISTRY[name]
    steps = _steps(data, hdr.T)
    s = m.settings(MethodSetup(hdr, plus, n, bias))  # (fields in order: hdr, plus, ...)
    state = m.initial_state()
    yaw = []
    for i in range(len(data)):
        state, out = m.step(state, steps.input(i), s)
        yaw.append(out.yaw)
    assert m.batch(steps, s).tolist() == yaw


def test_a_method_switch_carries_the_yaw() -> None:
    # The daemon switches method on SIGHUP: the new method starts from its initial state with
    # the old one's yaw, and the heading carries on.
    steps = _steps([(0.3, 0.1, NAN, NAN)] * 5, 1.0)
    ctx = MethodSetup()
    m = REGISTRY["hdr"]
    state = m.initial_state()
    for name in ("hdr", "hdr+", "none", "hdr", "hdr+"):
        new = REGISTRY[name]
        before = m.yaw(state)
        state, m = new.initial_state(before), new
        assert m.yaw(state) == before
        state, out = m.step(state, steps.input(0), m.settings(ctx))
        # (HDR+ also corrects the heading by what its first road measurement says of the bias)
        assert out.yaw == pytest.approx(before + out.omega * 1.0, abs=0.01)
        assert m.yaw(state) == pytest.approx(out.yaw, rel=1e-12)
    assert m.yaw(state) == pytest.approx(5 * 0.3, rel=0.2)  # a whole step each, none lost


def test_publish_gives_the_message_fields_of_each_method() -> None:
    steps = _steps([(0.3, 0.1, 0.0, NAN)] * 5, 1.0)
    for name in REGISTRY:
        m = REGISTRY[name]
        s = m.settings(MethodSetup())
        state, out = m.step(m.initial_state(), steps.input(0), s)
        pub = m.publish(out, s)
        assert pub.core["yaw"] == out.yaw and pub.core["omega"] == out.omega
        if m.owns_heading:
            assert isinstance(out, PlusOutput)
            assert list(pub.core) == ["omega", "yaw", "W"]  # no paper controller
            assert list(pub.extra) == ["zupt", "model", "bias_sd", "motion_offset"]
            assert pub.extra["model"] == s.model and pub.bias_corr_dps == out.bias_corr_dps
            assert pub.heading_sd_deg == out.heading_sd_deg > 0.0
        else:
            assert list(pub.core) == ["omega", "yaw", "I", "W", "R", "r"]
            assert pub.extra == {} and pub.bias_corr_dps == 0.0 and not pub.standstill
            assert math.isnan(pub.heading_sd_deg)


def test_hdr_plus_settings_follow_the_gyro_and_the_calibration() -> None:
    base = PlusParams()
    # A 1 Hz gyro has one sample per step; a measured bias sets the prior.
    rec = BiasRecord(0.5, 0.2, 30, 30.0)
    ctx = MethodSetup(HdrParams(T=1.0), base, samples_per_step=1.0, bias=rec)
    p = plus_settings(ctx)
    assert p.standstill.samples_per_step == 1.0
    assert p.bias_p0 == 0.2 * 0.2 / 30
    assert p.T == 1.0 and p.model == "calibration"
    # A given bias (no record of its spread) keeps the configured prior.
    given = MethodSetup(HdrParams(T=2.0), base, bias=BiasRecord(0.5, 0.0, 0, 0.0))
    assert plus_settings(given).bias_p0 == base.bias_p0
    assert plus_settings(MethodSetup(HdrParams(T=2.0))).T == 2.0
    # The configuration's standstill keys and grade reach it there, and only there.
    off = plus_settings(replace(ctx, standstill=False, standstill_from_gyro=True))
    assert not off.standstill.enabled and off.standstill.gyro_only
    assert plus_settings(replace(ctx, grade="tactical")).model == "grade tactical"
    # The registry's hdr+ entry derives exactly these.
    assert REGISTRY["hdr+"].settings(ctx) == p
    assert REGISTRY["none"].settings(ctx) == HdrParams(enabled=False)
    assert REGISTRY["hdr"].settings(ctx) == HdrParams()


def test_hdr_takes_its_increment_from_a_known_error_model() -> None:
    paper = HdrParams()
    # No error model known (a start-up calibration shows white noise only): Table III.
    assert methods.hdr_settings(MethodSetup(paper)) == paper
    # A tactical grade's bias barely moves: the increment is its drift over 30 s, far below.
    tactical = methods.hdr_settings(MethodSetup(paper, grade="tactical"))
    assert 0.0 < tactical.i_c < paper.i_c / 5
    assert replace(tactical, i_c=paper.i_c) == paper  # only i_c changes
    assert REGISTRY["hdr"].settings(MethodSetup(paper, grade="tactical")) == tactical
    # A phone's bias drifts more in 30 s than Table III's increment, which stays.
    assert methods.hdr_settings(MethodSetup(paper, grade="phone")) == paper
    # hdr.i_c: NUMBER keeps what is configured whatever the gyro.
    asked = MethodSetup(paper, grade="tactical", i_c_auto=False)
    assert methods.hdr_settings(asked) == paper
    # The configuration reaches it.
    cfg = parse_config({"hdr": {"i_c": 0.0422}, "gyro": {"grade": "tactical"}})
    assert REGISTRY["hdr"].settings(config_mod.method_setup(cfg)) == paper


def test_the_config_and_the_command_line_take_the_names_from_the_registry(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    assert methods.names() == ("none", "hdr", "hdr+")
    with pytest.raises(
        ConfigError, match="hdr.method = 'kalman': must be one of none, hdr, hdr\\+"
    ):
        parse_config({"hdr": {"method": "kalman"}})
    with pytest.raises(ConfigError, match="hdr.method"):
        parse_config({"hdr": {"method": ["hdr"]}})  # not a name at all
    monkeypatch.setitem(REGISTRY, "kalman", REGISTRY["hdr"])
    assert parse_config({"hdr": {"method": "kalman"}}).hdr.method == "kalman"
    from hdrd.cli import build_parser

    args = build_parser().parse_args(["evaluate", "x.csv", "--method", "kalman"])
    assert args.method == "kalman"
    with pytest.raises(
        ValueError, match="unknown method 'nope' \\(allowed: none, hdr, hdr\\+, kalman"
    ):
        methods.get("nope")


def test_help_stays_light() -> None:
    # `hdrd --help` must not load numpy (the registry is read when a method is checked).
    code = (
        "import sys, contextlib, io\n"
        "from hdrd.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        "    try: main(['--help'])\n"
        "    except SystemExit: pass\n"
        "print('numpy' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    out = subprocess.run(
        [sys.executable, "-m", "hdrd", "evaluate", "--help"], capture_output=True, text=True
    )
    assert "one of none, hdr, hdr+" in " ".join(out.stdout.split())
