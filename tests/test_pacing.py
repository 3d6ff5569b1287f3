"""hdrd.daemon.pacing: how long the daemon may leave the serial port unread without reading a
step-closing frame late. Pure; here a simulated reader on a simulated clock, fed by a real
:class:`~hdrd.daemon.pipeline.Pipeline` (its ``until_step_s`` and ``sample_interval_s``).

How the live path reads with it (a real pty): test_fastpaths.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.core.calibrate import given_bias
from hdrd.core.methods import MethodSetup
from hdrd.daemon.pacing import ReadPacer
from hdrd.daemon.pipeline import Pipeline
from hdrd.daemon.stepper import PipelineConfig
from hdrd.io.wire.codec import Frame


def simulate_reader(hz: float, seconds: float, delays: np.ndarray, pacer: ReadPacer) -> list[float]:
    """A reader that reads everything arrived, then pauses as the pacer says (or, not pausing,
    wakes at the next arrival), on a simulated clock. Frame k has device time k/hz and arrives
    at k/hz + 5 s + delays[k]. Returns how late each step-closing frame was read, s."""
    n = int(hz * seconds)
    t_dev = np.arange(n) / hz
    arrive = np.maximum.accumulate(t_dev + 5.0 + delays[:n])  # a stream: delivered in order
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.0))))
    late: list[float] = []
    now = arrive[0]
    k = 0
    while k < n:
        j = int(np.searchsorted(arrive, now, side="right"))  # everything arrived by now
        for i in range(k, j):
            if p.feed(Frame(i & 0xFFFF, round(t_dev[i] * 1e6), 32768, 0, None)):
                late.append(now - arrive[i])  # frame i closed a step
        k = j
        if k >= n:
            break
        last = p.clock.last_us
        assert last is not None
        pause = pacer.pause(now, last / 1e6, p.until_step_s(), now, p.sample_interval_s())
        now = max(now + pause, arrive[k])
    return late


@settings(
    max_examples=20, derandomize=True
)  # a simulation, not a proof: the same examples each run
@given(
    hz=st.sampled_from([100.0, 1000.0, 2000.0]),
    jitter_ms=st.floats(0.0, 15.0),
    prompt=st.floats(0.05, 1.0),
    seed=st.integers(0, 2**31),
)
def test_paced_reads_never_read_a_step_closing_frame_late(
    hz: float, jitter_ms: float, prompt: float, seed: int
) -> None:
    """Bursty delivery (each frame late by up to jitter_ms, a fraction `prompt` on time): the
    pacer's pauses end before any step-closing frame arrives, so each is read on arrival."""
    rng = np.random.default_rng(seed)
    n = int(hz * 12)
    delays = np.where(rng.random(n) < prompt, 0.0, rng.uniform(0, jitter_ms / 1e3, n))
    pacer = ReadPacer(max_pause_s=0.02, guard_s=0.002)
    late = simulate_reader(hz, 12.0, delays, pacer)
    assert len(late) >= 10
    assert max(late[2:]) == 0.0  # the first steps come before the delay is known
    assert pacer.lag_s >= 5.0 - 1e-6  # never below the true delay (device times in whole us)


def test_paced_reads_at_the_wires_limit() -> None:
    """18,750 frames/s (3 Mbaud), delivery late by up to 3 ms for half the frames."""
    rng = np.random.default_rng(1)
    n = 18750 * 5
    delays = np.where(rng.random(n) < 0.5, 0.0, rng.uniform(0, 0.003, n))
    late = simulate_reader(18750.0, 5.0, delays, ReadPacer())
    assert len(late) == 4 and max(late[1:]) == 0.0


def test_pacing_batches_reads_and_gives_up_nothing_on_steady_delivery() -> None:
    pacer = ReadPacer(max_pause_s=0.02, guard_s=0.002)
    assert pacer.pause(10.0, 5.0, None, 10.0) == 0.0  # unknown: read now
    assert pacer.lag_s == 5.0
    assert pacer.pause(10.01, 5.01, 0.5, 10.0101) == 0.02  # far from the step: the longest pause
    assert pacer.pause(10.9, 5.9, 0.0025, 10.9) == 0.0  # the closing frame is 2.5 ms away
    assert pacer.pause(10.9, 5.9, 0.0035, 10.9) == pytest.approx(0.0015)
    # A late batch (lag 5.1 s) does not raise the estimate beyond its drift allowance.
    pacer.pause(11.5, 6.4, 0.1, 11.5)
    assert pacer.lag_s == pytest.approx(5.0 + 2e-4 * 0.6)
    pacer.pause(11.6, 6.6, 0.1, 11.6)  # a device clock running fast: followed at once
    assert pacer.lag_s == pytest.approx(5.0)
    pacer.reset()
    assert pacer.lag_s == math.inf and pacer.pause(20.0, 1.0, 0.5, 20.0) == 0.02
    # At 18,750 frames/s (a 3 Mbaud link's limit) no more than 128 frames gather: 6.8 ms.
    assert pacer.pause(20.1, 1.1, 0.5, 20.1, 1 / 18750) == pytest.approx(128 / 18750)
    assert pacer.pause(20.2, 1.2, 0.5, 20.2, 1 / 1000) == 0.02
    with pytest.raises(ValueError):
        ReadPacer(guard_s=-1.0)
