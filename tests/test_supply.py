# ruff: noqa: F811 - the fixtures hdrd and receivers come from test_rel_daemon by import
"""The supply monitor and the gyro's range: a sample the gyro cannot have given is not a turn.

The ``ref`` channel reads the gyro's supply through a divider, and the rate is scaled by it
(ratiometric, :mod:`hdrd.core.sensor`). A divider that opens puts the channel at the ADC's
rail ("10 V") and a still vehicle read -125 deg/s, ``status: turning``, a spinning heading and
``$HNROT,7499.9,A``; a reading of one count ("0 V") gave 8,191,750 deg/s, and a supply read as
4.0 V +62.5 deg/s, without a word in the log. Now a sample whose supply reading is outside the
CRS03-04's specified 4.75 .. 5.25 V, or jumps more than a supply can from one sample to the
next, is left out of its step, as is a sample beyond the gyro's range: a step with none left
is a report of the held heading that says why (``supply_fault``, ``saturated``), and NMEA
sends nothing valid for it.

The pure pipeline (frame by frame and a whole capture, bit for bit the same), then a real
daemon on a real pty.
"""

from __future__ import annotations

import math
import socket
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdrd.core.calibrate import given_bias
from hdrd.core.methods import MethodSetup
from hdrd.core.sensor import SensorModel
from hdrd.daemon.pipeline import Pipeline
from hdrd.daemon.stepper import PipelineConfig
from hdrd.io.net.formats import nmea_sentences, parse_nmea
from hdrd.io.wire.codec import FRAME_DTYPE, array_to_frames
from tests.test_rel_daemon import (  # noqa: F401 - hdrd and receivers are fixtures
    Receiver,
    hdrd,
    receivers,
    run_args,
    wait_port_open,
)

SENSOR = SensorModel()
HZ = 10  # samples per 1 s step
GOOD_V = 5.0


def capture(
    supply_v: list[float] | np.ndarray,
    omega_dps: float | np.ndarray = 0.0,
    ref: np.ndarray | None = None,
) -> np.ndarray:
    """Frames at 10 Hz of a gyro reading ``omega_dps`` (deg/s, + CCW) on a supply of
    ``supply_v`` (V, one per frame; its output is ratiometric to it); the supply monitor
    reads ``ref`` counts when given (a broken divider reads what the supply is not), else the
    supply."""
    v = np.asarray(supply_v, dtype=np.float64)
    n = v.shape[0]
    arr = np.zeros(n, FRAME_DTYPE)
    arr["seq"] = np.arange(n) & 0xFFFF
    arr["t_us"] = np.arange(n, dtype=np.int64) * (1_000_000 // HZ)
    w = np.broadcast_to(np.asarray(omega_dps, dtype=np.float64), (n,))
    arr["rate"] = [SENSOR.to_counts(wi, vi) for wi, vi in zip(w, v)]
    arr["ref"] = [SENSOR.ref_counts_for(x) for x in v] if ref is None else ref
    arr["temp"] = 2500
    return arr


def both_paths(arr: np.ndarray, **cfg: Any) -> list[dict[str, Any]]:
    """The messages frame by frame (``hdrd run``) and of the whole capture (``hdrd
    replay``): the same, bit for bit; returned once."""
    make = lambda: Pipeline(  # noqa: E731
        PipelineConfig(**{"setup": MethodSetup(bias=given_bias(0.0)), **cfg})
    )
    live = make()
    a = [m for f in array_to_frames(arr) for m in live.feed(f)] + live.finish()
    whole = make()
    b = whole.feed_array(arr) + whole.finish()
    assert a == b
    assert [type(v) for m in a for v in m.values()] == [type(v) for m in b for v in m.values()]
    return a


def ref_counts(volts: float) -> int:
    """What the supply monitor reads for ``volts`` at the gyro (through the divider), clipped
    to the ADC's range as a real ADC clips it."""
    return int(min(max(round(volts / 2.0 * 65536 / 5.0), 1), 65535))


@pytest.mark.parametrize(
    "ref, volts",
    [(65535, 10.0), (1, 0.0), (ref_counts(4.0), 4.0), (ref_counts(5.3), 5.3)],
    ids=["divider-open-10V", "0V", "4.0V", "5.3V"],
)
def test_a_supply_outside_its_range_is_not_a_turn(ref: int, volts: float) -> None:
    """A still vehicle: 10 s on a good supply, 5 s with the monitor reading ``volts``, 5 s
    good again. The fault's steps are reports of the held heading (``supply_fault``, the volts
    seen), no rate, NMEA invalid; the first step after says how long nothing was usable."""
    supply = [GOOD_V] * (20 * HZ)
    refs = np.array([SENSOR.ref_counts_for(GOOD_V)] * (20 * HZ))
    refs[10 * HZ : 15 * HZ] = ref
    msgs = both_paths(capture(supply, 0.0, refs), heading0_deg=10.0)
    assert [m["step"] for m in msgs] == list(range(20))
    fault, after = msgs[10:15], msgs[15:]
    for m in fault:
        assert m["status"] == "supply_fault" and m["supply_faults"] == HZ and m["samples"] == 0
        assert m["supply_v"] == pytest.approx(volts, abs=2e-3)
        assert m["heading"] == 10.0 and m["yaw"] == 0.0 and m["bias"] == 0.0
        assert not {"omega", "omega_raw", "I", "W"} & set(m)
        said = {parse_nmea(s)[0][2:]: parse_nmea(s)[1] for s in nmea_sentences(m, ths=True)}
        assert "HDT" not in said and said["ROT"] == ["", "V"] and said["THS"][1] == "V"
    assert after[0]["gap_s"] == 5.0 and after[0]["status"] == "ok"
    # the first reading after the fault jumps back by more than a supply can: not trusted
    assert (after[0]["supply_faults"], after[0]["samples"]) == (1, HZ - 1)
    assert all("supply_faults" not in m for m in msgs[:10] + after[1:])
    assert all(m["heading"] == 10.0 for m in msgs)
    assert not any(m["status"] == "turning" for m in msgs)


def test_a_jump_no_supply_makes_is_left_out_and_a_slow_drift_is_not() -> None:
    """One sample reads 5.2 V between readings of 5.0 V: it and the one after (the jump back)
    are left out of their step, the rest stepped; a supply that drifts across its whole range
    over a minute is a supply, scaled as always."""
    supply = [GOOD_V] * (5 * HZ)
    supply[23] = 5.2
    msgs = both_paths(capture(supply, 3.0))
    m = msgs[2]
    assert (m["supply_faults"], m["samples"], m["status"]) == (2, HZ - 2, "turning")
    assert m["supply_v"] == pytest.approx(5.2, abs=2e-3)
    assert all("supply_faults" not in x for i, x in enumerate(msgs) if i != 2)
    drift = np.linspace(4.76, 5.24, 60 * HZ)
    slow = both_paths(capture(drift, 3.0))
    assert all("supply_faults" not in x and x["status"] == "turning" for x in slow)
    assert max(abs(x["omega_raw"] - 3.0) for x in slow) < 0.05  # ratiometric, as before


def test_a_rate_beyond_the_gyros_range_is_not_a_turn() -> None:
    """Samples beyond sensor.range_dps (200 deg/s) or at an ADC rail are left out: a step of
    nothing else is a report of the held heading (``saturated``), a step with some is stepped
    on the others."""
    omega = np.zeros(8 * HZ)
    omega[3 * HZ : 5 * HZ] = 260.0  # a rate output at its rail (250 deg/s): a broken wire
    omega[6 * HZ : 6 * HZ + 3] = 210.0  # beyond the range, inside the ADC's
    msgs = both_paths(capture([GOOD_V] * omega.shape[0], omega), heading0_deg=45.0)
    assert [m["status"] for m in msgs[3:5]] == ["saturated", "saturated"]
    for m in msgs[3:5]:
        assert m["saturated"] == HZ and m["samples"] == 0 and m["heading"] == 45.0
        assert "omega" not in m and "HDT" not in b"".join(nmea_sentences(m)).decode()
    assert (msgs[6]["saturated"], msgs[6]["samples"], msgs[6]["status"]) == (3, HZ - 3, "ok")
    assert msgs[5]["gap_s"] == 2.0
    assert all(m["heading"] == 45.0 for m in msgs)


def test_the_start_up_calibration_never_takes_a_faulty_sample() -> None:
    """A supply fault inside the start-up window starts the window again: the bias is
    measured on good samples only (a still gyro with a 0.3 deg/s bias)."""
    supply = [GOOD_V] * (12 * HZ)
    refs = np.array([SENSOR.ref_counts_for(GOOD_V)] * (12 * HZ))
    refs[HZ // 2 : HZ] = 65535  # in the first step of a 1 s window
    msgs = both_paths(capture(supply, 0.3, refs), setup=MethodSetup())
    assert (msgs[0]["status"], msgs[0]["supply_faults"]) == ("calibrating", HZ // 2)
    # the first reading after the fault jumps back: that step is not contiguous either
    assert (msgs[1]["status"], msgs[1]["supply_faults"]) == ("calibrating", 1)
    assert msgs[2]["status"] == "calibrating" and "supply_faults" not in msgs[2]  # measured
    assert msgs[3]["status"] == "ok" and msgs[3]["bias"] == pytest.approx(0.3, abs=0.01)


# -- every sample judged by the documented rule, both paths alike ------------------------------


def rule(refs: list[int]) -> list[bool]:
    """The documented rule, written from docs/protocol.md: a sample whose monitor is wired
    (ref > 0) is a fault when its supply reading (ref * 5 V / 65536 * 2) is outside 4.75 ..
    5.25 V or differs by more than 0.1 V from the sample before's (when that one was wired)."""
    out = []
    prev = None
    for r in refs:
        v = r * 5.0 / 65536 * 2.0 if r > 0 else None
        bad = v is not None and (
            not 4.75 <= v <= 5.25 or (prev is not None and abs(v - prev) > 0.1)
        )
        out.append(bad)
        prev = v
    return out


READINGS = st.one_of(
    st.sampled_from([0, 1, 65535, 32768]),
    st.integers(31130, 34406),  # inside 4.75 .. 5.25 V
    st.integers(0, 65535),
)


@given(st.lists(READINGS, min_size=1, max_size=150))
def test_each_sample_is_judged_by_the_documented_rule(refs: list[int]) -> None:
    arr = capture([GOOD_V] * len(refs), 0.0, np.array(refs))
    msgs = both_paths(arr)
    bad = rule(refs)
    assert len(msgs) == math.ceil(len(refs) / HZ)
    for m in msgs:
        k = m["step"]
        faults = sum(bad[HZ * k : HZ * k + HZ])
        assert m.get("supply_faults", 0) == faults
        assert m["samples"] == min(HZ, len(refs) - HZ * k) - faults
        assert (m["status"] == "supply_fault") == (m["samples"] == 0)
        if faults:
            seen = [
                r * 5.0 / 65536 * 2.0
                for r, b in zip(refs[HZ * k : HZ * k + HZ], bad[HZ * k :])
                if b
            ]
            # the reading farthest from the nominal 5 V (of two as far, the lower)
            assert m["supply_v"] == max(seen, key=lambda v: (abs(v - 5.0), -v))
        assert all(math.isfinite(v) for v in m.values() if isinstance(v, float))


# -- a real daemon on a real pty --------------------------------------------------------------


@pytest.mark.slow
def test_the_daemon_says_a_supply_fault_and_sends_no_valid_nmea(fake_gyro, hdrd, receivers):
    """``hdrd run`` on a fake gyro whose divider opens for 4 s while the car stands: the JSON
    says ``supply_fault`` with the volts, the heading holds, NMEA sends no HDT and an invalid
    ROT for those steps, and the log has one warning naming the volts."""
    n = 16 * HZ
    refs = np.array([SENSOR.ref_counts_for(GOOD_V)] * n)
    refs[8 * HZ : 12 * HZ] = 65535
    g = fake_gyro(capture([GOOD_V] * n, 0.0, refs), speedup=0)
    rx = receivers()
    nmea_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    nmea_sock.bind(("127.0.0.1", 0))
    nmea = Receiver(nmea_sock, bytes)
    try:
        d = hdrd(
            *run_args("--clock-rate", "0", "--port", g.path, "--bias", "0", "--heading0", "10"),
            "--udp", rx.addr, "--nmea-udp", f"127.0.0.1:{nmea_sock.getsockname()[1]}",
            "--nmea-ths",
        )  # fmt: skip
        wait_port_open(d, g.path)
        g.start()
        rx.wait(lambda ms: any(m.get("step") == 14 for m in ms), what="step 14")
        assert g.wait(30.0)
        assert d.stop() == 0 and not d.traceback
        ms = rx.wait(lambda ms: any(m.get("step") == 15 for m in ms), what="step 15")
        # HDT, ROT and THS a step; no HDT in the 4 steps of the fault
        sentences = nmea.wait(lambda xs: len(xs) >= 3 * 16 - 4, what="the sentences")
    finally:
        nmea.close()
    assert [m["step"] for m in ms] == list(range(16))
    assert [m["status"] for m in ms[8:12]] == ["supply_fault"] * 4
    assert all(m["supply_v"] == pytest.approx(10.0, abs=1e-3) for m in ms[8:12])
    assert all(m["heading"] == 10.0 for m in ms) and "turning" not in {m["status"] for m in ms}
    said = [parse_nmea(x.strip()) for x in sentences]
    hdt = [f for name, f in said if name.endswith("HDT")]
    rot = [f for name, f in said if name.endswith("ROT")]
    ths = [f for name, f in said if name.endswith("THS")]
    assert len(hdt) == 12 and {tuple(f) for f in hdt} == {("10.00", "T")}
    assert [f[1] for f in rot].count("V") == 4 and {f[0] for f in rot} <= {"0.0", ""}
    assert [f[1] for f in ths].count("V") == 4
    (warning,) = d.named("supply_fault")
    assert warning["level"] == "warning" and warning["supply_v"] == pytest.approx(10.0, abs=1e-3)
    assert warning["samples"] == HZ  # at the first step of it; the rest within the interval
    (stop,) = d.named("stop")
    assert stop["supply_faults"] == 4 * HZ + 1  # and the first reading after, jumping back
