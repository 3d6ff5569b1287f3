"""hdrd.core.steps: what a drift reducer sees of a step (StepInput) and a drive's steps as
arrays (StepInputs), and step i of the arrays as the daemon's pipeline hands it to a method.
Pure. Rates deg/s, + = CCW; speed m/s; temperature degC; NaN: unknown.

Every method's batch run equal to its step run over ``StepInputs.input``: test_methods.py.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from hdrd.core.steps import StepInput, StepInputs


def drive(**kw: object) -> StepInputs:
    base: dict[str, object] = dict(
        u=np.array([0.5, -1.25, 0.0]),
        t_end=np.array([31.0, 32.0, 34.0]),  # a step without samples (33 s) has no element
        T=1.0,
        bias_dps=0.3,
        n_samples=np.array([100, 98, 100], np.int64),
    )
    base.update(kw)
    return StepInputs(**base)  # type: ignore[arg-type]


def test_step_i_takes_the_ith_of_every_array() -> None:
    steps = drive(
        speed=np.array([0.0, 12.5, math.nan]),
        temp_c=np.array([21.0, 21.5, 22.0]),
        omega_std=np.array([0.1, 0.4, 0.0]),
    )
    assert steps.input(1) == StepInput(u=-1.25, spread_dps=0.4, speed_mps=12.5, temp_c=21.5, T=1.0)
    last = steps.input(2)
    assert last.u == 0.0 and last.spread_dps == 0.0 and last.temp_c == 22.0
    assert math.isnan(last.speed_mps)  # unknown in the log: unknown to the method
    assert repr(steps.input(-1)) == repr(last)  # (NaN is not equal to itself)


def test_what_a_drive_lacks_is_nan_in_every_step() -> None:
    steps = drive()
    for i in range(3):
        inp = steps.input(i)
        assert inp.u == steps.u[i] and inp.T == 1.0
        assert math.isnan(inp.spread_dps) and math.isnan(inp.speed_mps) and math.isnan(inp.temp_c)
    assert math.isnan(steps.bias_var)  # the bias was given, not measured


def test_a_step_input_holds_plain_floats() -> None:
    inp = drive(omega_std=np.array([0.1, 0.2, 0.3], np.float32)).input(0)
    assert all(type(v) is float for v in inp[:-1])  # not numpy scalars: a method's hot loop
    assert inp.heading_reset is False


def test_a_step_past_the_end_is_an_error() -> None:
    with pytest.raises(IndexError):
        drive().input(3)


def test_both_are_immutable() -> None:
    steps = drive()
    with pytest.raises(dataclasses.FrozenInstanceError):
        steps.T = 2.0  # type: ignore[misc]
    inp = steps.input(0)
    with pytest.raises(AttributeError):
        inp.u = 1.0  # type: ignore[misc]
    assert inp._replace(u=1.0).u == 1.0 and inp.u == 0.5
