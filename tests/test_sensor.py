"""CRS03-04 sensor model (hdrd/core/sensor.py): ADC counts <-> deg/s (+ = CCW), one sample in
plain floats (the live path) and arrays (captures) alike.

Defaults: 16-bit unipolar ADC, volts = counts * 5.0 / 2**16, null 2.5 V, 10 mV/(deg/s),
polarity +1, range +/-200 deg/s; ratiometric with a supply monitor behind a 1:2 divider.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.core.sensor import SensorModel

M = SensorModel()
COUNTS_PER_V = 2**16 / 5.0  # 13107.2 counts per volt


def counts_at(volts: float) -> float:
    """Counts (not rounded) a 16-bit 5 V ADC reads at this voltage."""
    return volts * COUNTS_PER_V


def dps_at(m: SensorModel, volts: float, ref: float = 0) -> float:
    """The rate a sensor reads at this voltage (counts not rounded: the array path takes them)."""
    return float(m.to_dps_array(counts_at(volts), ref))


def test_defaults_are_the_crs03_04_on_a_16_bit_adc() -> None:
    assert (M.adc_bits, M.vref_v, M.null_v, M.scale_v_per_dps) == (16, 5.0, 2.5, 0.010)
    assert (M.polarity, M.range_dps, M.ref_divider, M.supply_nominal_v) == (1, 200.0, 2.0, 5.0)
    assert M.full_scale == 65535


def test_null_at_2_5_v_is_zero() -> None:
    assert counts_at(2.5) == 32768
    assert M.to_dps_scalar(32768) == 0.0
    assert SensorModel(polarity=-1).to_dps_scalar(32768) == 0.0
    assert M.to_counts(0.0) == 32768


def test_plus_10_mv_is_plus_1_dps() -> None:
    assert dps_at(M, 2.51) == pytest.approx(1.0, abs=1e-12)
    assert dps_at(M, 2.49) == pytest.approx(-1.0, abs=1e-12)
    assert dps_at(M, 2.5 + 0.5) == pytest.approx(50.0, abs=1e-10)
    # One count more than null is one LSB: 5 V / 65536 / 10 mV = 0.00762939453125 deg/s.
    assert M.to_dps_scalar(32769) == 5.0 / 65536 / 0.010


def test_polarity_minus_one_flips_the_sign() -> None:
    up = SensorModel(polarity=-1)
    assert dps_at(up, 2.51) == pytest.approx(-1.0, abs=1e-12)
    c = np.arange(0, 65536, 97)
    assert np.array_equal(up.to_dps_array(c, 0), -M.to_dps_array(c, 0))
    assert up.to_counts(1.0) == M.to_counts(-1.0)


@pytest.mark.parametrize("bits, lsb", [(16, 0.0076), (12, 0.122), (10, 0.488)])
def test_lsb_resolution(bits: int, lsb: float) -> None:
    # HDR-NOTES: 10-bit ~0.49, 12-bit ~0.12, 16-bit ~0.0076 deg/s; only 16 bits beat i_c.
    m = SensorModel(adc_bits=bits)
    assert m.lsb_dps == pytest.approx(lsb, rel=5e-3)
    mid = 1 << (bits - 1)
    assert m.to_dps_scalar(mid + 1) - m.to_dps_scalar(mid) == pytest.approx(m.lsb_dps, rel=1e-12)
    assert (m.lsb_dps < 0.0422) == (bits == 16)


# -- round trips ------------------------------------------------------------------------------


@settings(deadline=None)
@given(
    counts=st.integers(0, 65535),
    polarity=st.sampled_from([1, -1]),
    supply=st.one_of(st.none(), st.floats(4.5, 5.5)),
)
def test_counts_to_dps_and_back_is_exact(counts: int, polarity: int, supply: float | None) -> None:
    m = SensorModel(polarity=polarity)
    ref = 0 if supply is None else m.ref_counts_for(supply)
    omega = m.to_dps_scalar(counts, ref)
    assert isinstance(omega, float)
    supply_v = None if supply is None else m.supply_v(ref)
    assert supply_v is None or isinstance(supply_v, float)  # one ref count: one voltage
    back = m.to_counts(omega, supply_v)
    assert int(back) == counts


@settings(deadline=None)
@given(
    omega=st.floats(-199.0, 199.0),
    polarity=st.sampled_from([1, -1]),
    bits=st.sampled_from([10, 12, 16, 24]),
)
def test_dps_to_counts_and_back_within_half_an_lsb(omega: float, polarity: int, bits: int) -> None:
    m = SensorModel(polarity=polarity, adc_bits=bits)
    c = m.to_counts(omega)
    assert 0 <= int(c) <= m.full_scale
    assert abs(m.to_dps_scalar(int(c)) - omega) <= m.lsb_dps / 2 * (1 + 1e-9)


def test_arrays_in_arrays_out() -> None:
    c = np.array([0, 32768, 65535])
    w = M.to_dps_array(c, 0)
    assert isinstance(w, np.ndarray) and w.shape == (3,)
    assert w[1] == 0.0 and w[0] == -250.0
    assert np.array_equal(M.to_counts(w), c)
    assert M.to_counts([0.0, 1.0]).dtype == np.int64


def test_to_counts_clips_to_the_rails() -> None:
    assert M.to_counts(300.0) == 65535
    assert M.to_counts(-300.0) == 0


# -- ratiometric supply correction --------------------------------------------------------------


def test_supply_from_the_monitor_channel() -> None:
    # supply = ref_counts * 5.0 / 2**16 * ref_divider
    assert M.supply_v(counts_at(2.4)) == pytest.approx(4.8, abs=1e-12)
    assert M.supply_v(32768) == 5.0
    assert M.supply_v(0) == 5.0  # not wired: nominal
    assert SensorModel(ref_divider=3.0).supply_v(counts_at(1.6)) == pytest.approx(4.8, abs=1e-12)
    got = M.supply_v(np.array([0, 32768]))
    assert isinstance(got, np.ndarray) and got.tolist() == [5.0, 5.0]


def test_supply_4_8_v_scales_null_and_scale() -> None:
    ref = counts_at(4.8 / 2.0)  # 2.4 V on the monitor behind the 1:2 divider
    # At 4.8 V the gyro's null is 2.4 V (= 4.8/2) and its scale 9.6 mV/(deg/s) (= 10 * 4.8/5).
    assert dps_at(M, 2.4, ref) == pytest.approx(0.0, abs=1e-12)
    assert dps_at(M, 2.4 + 0.0096, ref) == pytest.approx(1.0, abs=1e-12)
    assert dps_at(M, 2.4 - 0.96, ref) == pytest.approx(-100.0, abs=1e-10)
    # Without the monitor, the same 2.4 V would read as a 10 deg/s right turn.
    assert dps_at(M, 2.4) == pytest.approx(-10.0, abs=1e-12)


def test_ratiometric_round_trip_at_4_8_v() -> None:
    ref = M.ref_counts_for(4.8)
    supply = M.supply_v(ref)
    assert isinstance(supply, float)
    assert supply == pytest.approx(4.8, abs=M.vref_v / 2**16 * 2)
    omega = np.linspace(-150, 150, 301)
    c = M.to_counts(omega, supply)
    assert np.all(np.abs(M.to_dps_array(c, ref) - omega) <= M.lsb_dps)
    # Per-sample reference counts (an array) work as well as one value.
    refs = np.full(c.shape, ref)
    assert np.array_equal(M.to_dps_array(c, refs), M.to_dps_array(c, ref))


def test_ref_counts_for_stays_inside_the_adc() -> None:
    assert M.ref_counts_for(5.0) == 32768
    assert M.ref_counts_for(100.0) == 65535
    assert M.ref_counts_for(0.0) == 1  # 0 would mean "not wired"


# -- saturation -------------------------------------------------------------------------------


def test_saturation_at_rails_and_beyond_range() -> None:
    c = np.array([0, 1, 32768, 65534, 65535])
    w = M.to_dps_array(c, 0)
    sat = M.saturated(c, w)
    assert isinstance(sat, np.ndarray)
    # The rails (0, 65535) read -250 / +249.99 deg/s and are flagged; so are 1 and 65534
    # (beyond +/-200 deg/s); null is not.
    assert sat.tolist() == [True, True, False, True, True]


@pytest.mark.parametrize(
    "omega, flagged", [(0.0, False), (199.0, False), (-199.0, False), (201.0, True), (-201.0, True)]
)
def test_saturation_beyond_200_dps(omega: float, flagged: bool) -> None:
    c = int(M.to_counts(omega))
    assert 0 < c < 65535
    assert M.saturated(c, M.to_dps_scalar(c)) is flagged


def test_saturation_of_a_rail_even_with_a_small_rate() -> None:
    # A rail count is suspect whatever rate it converts to (e.g. under a low supply).
    assert M.saturated(65535, 10.0) is True
    assert M.saturated(0, -10.0) is True
    assert M.saturated(40000, 10.0) is False


# -- the daemon's scalar path, and what the array path takes ----------------------------------


@pytest.mark.parametrize("polarity", [1, -1])
@pytest.mark.parametrize("ref", [0, 1, 29491, 32768, 36045, 65535])
def test_scalar_path_is_the_array_path_bit_for_bit(polarity: int, ref: int) -> None:
    """Every count, with the monitor not wired (0), at its least (1), at 4.5, 5.0 and 5.5 V
    and at its rail: the live daemon's plain-float path gives exactly the capture path's
    deg/s, and flags exactly the same samples."""
    m = SensorModel(polarity=polarity)
    counts = np.arange(0, 65536)
    want = m.to_dps_array(counts, ref)
    got = np.array([m.to_dps_scalar(int(c), ref) for c in counts])
    assert np.array_equal(got, want)
    sat = m.saturated(counts, want)
    assert isinstance(sat, np.ndarray)
    assert [m.saturated_scalar(int(c), float(w)) for c, w in zip(counts, want)] == sat.tolist()


def test_one_sample_in_plain_floats_out() -> None:
    assert type(M.supply_v(32768)) is float
    assert type(M.to_dps_scalar(32769)) is float
    assert M.saturated(0, 0.0) is True and M.saturated(1, 0.0) is False


def test_counts_of_any_numeric_type_give_the_same_rate() -> None:
    # Frames hold uint16 counts; a CSV or a test may hand float32 or int64 ones. The
    # conversion is done in float64 whatever comes in (float32 arithmetic would differ).
    c = np.array([1, 12345, 32769, 40001, 65534])
    ref = np.array([0, 1, 29491, 36045, 65535])
    want = M.to_dps_array(c.astype(np.int64), ref.astype(np.int64))
    for dtype in (np.uint16, np.int32, np.float32, np.float64):
        assert np.array_equal(M.to_dps_array(c.astype(dtype), ref.astype(dtype)), want), dtype
        assert np.array_equal(M.supply_v(ref.astype(dtype)), M.supply_v(ref)), dtype
    w = np.array([-123.456789, -0.0123, 0.0, 0.0123, 77.7777, 199.99])
    assert np.array_equal(
        M.to_counts(w.astype(np.float32)), M.to_counts(w.astype(np.float32).astype(np.float64))
    )
    sat = M.saturated(c.astype(np.uint16), np.float32(199.99999))
    assert isinstance(sat, np.ndarray) and not sat[1:-1].any()


def test_a_monitor_reading_one_count_is_wired() -> None:
    # ref 0 means "not wired" (nominal supply); 1 is the smallest reading of a wired monitor
    # (what ref_counts_for gives for 0 V): its supply is used, however implausible.
    assert M.supply_v(1) == 5.0 / 65536 * 2.0
    assert M.to_dps_scalar(32768, 1) != M.to_dps_scalar(32768, 0)
    assert float(M.to_dps_array(32768, 1)) == M.to_dps_scalar(32768, 1)


@pytest.mark.parametrize(
    "counts, omega, flagged",
    [
        (1, -10.0, False),  # one count above the low rail: not a rail
        (65534, 10.0, False),  # one count below the high rail
        (0, 0.0, True),
        (65535, 0.0, True),
        (40000, 200.0, True),  # exactly the specified range: beyond what is guaranteed
        (40000, -200.0, True),
        (40000, 199.99999, False),
        (40000, -199.99999, False),
    ],
)
def test_saturation_boundaries(counts: int, omega: float, flagged: bool) -> None:
    assert M.saturated(counts, omega) is flagged
    assert M.saturated_scalar(counts, omega) is flagged
