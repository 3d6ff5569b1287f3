"""The low-pass at rest, fitted by the Whittle likelihood of neighbouring differences
(hdrd/analysis/gap/lowpass.py, docs/model-gap.md section 3): its number of sections, and the
slow processes' power above the block frequency, which the fit must not take for its own.

The logs are tests/gap_standins.py's phone at rest (float output), at 10 Hz."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hdrd.analysis.gap.lowpass import cascade_cutoff_hz, fit_lowpass, noise_share, slow_noise
from hdrd.sim.effects import Bandwidth, WhiteNoise
from hdrd.sim.gyro import GyroModel
from tests.gap_standins import phone_log

HZ = 10.0
BLOCK_SAMPLES = 15.0 * HZ  # a 6-hour log's blocks


@pytest.mark.parametrize("sections", [1, 2])
def test_the_filter_s_sections_and_its_white_noise_are_read(sections: int) -> None:
    """White noise through one or two sections (-3 dB at 0.2 Hz): the fit keeps as many,
    the cutoff and the white level at the input. With one section only, two read as a cutoff
    at its bound and a white noise tens of times too large (fitted so before)."""
    log, h = phone_log(
        seed=7, hours=2.0, hz=HZ, filter_order=sections, cutoff_hz=0.2, gm_sigma_dps=0.0
    )
    lp = fit_lowpass(np.diff(log.omega), BLOCK_SAMPLES, slow=slow_noise(0.0, 1.0, 1.5e-4, 0.1))
    assert lp.order == sections
    assert cascade_cutoff_hz(lp.a, lp.order, 1.0 / HZ) == pytest.approx(h.cutoff_hz, rel=0.05)
    assert math.sqrt(lp.white_var / HZ) == pytest.approx(0.015, rel=0.05)


def test_noise_share_is_the_simulator_s() -> None:
    """The variance the fit's sections pass is the simulator's (``bandwidth`` of that many
    sections)."""
    for sections in (1, 2, 3):
        bw = Bandwidth(cutoff_hz=0.5, sections=sections)
        t = np.arange(0.0, 4000.0, 0.1)
        y = GyroModel((WhiteNoise(1.0), bw)).apply(
            t, np.zeros_like(t), None, np.random.default_rng(1)
        )
        a = math.exp(-2.0 * math.pi * bw.section_hz() * 0.1)
        assert float(np.var(y)) == pytest.approx(10.0 * noise_share(a, sections), rel=0.05)


def test_a_fast_bias_instability_is_not_read_as_the_low_pass() -> None:
    """A bias of tau_c 20 s under a white noise of 0.004 deg/s/sqrt(Hz) has much of its power
    above the block frequency: known to the fit, the cutoff and the white noise are read; left
    out (as before), the cutoff came out near 0.11 Hz and the white noise 1.8x."""
    sigma, tau, k = 0.0055 / 0.62, 20.0, 1.5e-4
    log, h = phone_log(
        seed=8, hz=HZ, cutoff_hz=0.2, white_dps_per_rthz=0.004, gm_sigma_dps=sigma, gm_tau_s=tau
    )
    de = np.diff(log.omega)
    lp = fit_lowpass(de, BLOCK_SAMPLES, slow=slow_noise(sigma, tau, k, 1.0 / HZ))
    assert cascade_cutoff_hz(lp.a, lp.order, 1.0 / HZ) == pytest.approx(0.2, rel=0.1)
    assert math.sqrt(lp.white_var / HZ) == pytest.approx(0.004, rel=0.1)
    blind = fit_lowpass(de, BLOCK_SAMPLES)
    assert cascade_cutoff_hz(blind.a, blind.order, 1.0 / HZ) < 0.8 * h.cutoff_hz
