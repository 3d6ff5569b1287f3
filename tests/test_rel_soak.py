"""Soak: the short version of bench/soak.py in the test suite.

Ten minutes of device time of a simulated drive at 100 Hz, played 100 times faster to a real
`hdrd run` process on a fake-gyro pty, with garbage, CRC errors and dropped frames throughout
and two cable pulls. Counts are asserted, never timings: every step the delivered frames make
is published once (numbers in order, skipping only across reconnects), every delivered frame is in one step, every damaged
frame is counted, every pull is a reconnect, the daemon exits 0 without a traceback. The
long run (6 hours of device time) and its figures are in bench/RESULTS.md, "Soak".
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench" / "soak.py"


def load_soak() -> ModuleType:
    spec = importlib.util.spec_from_file_location("hdrd_bench_soak", BENCH)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up by name
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_short_soak_counts(tmp_path: Path) -> None:
    soak = load_soak()
    r = soak.soak(
        hours=10 / 60,
        speedup=100.0,
        hz=100.0,
        drive="mixed",
        seed=3,
        garbage=0.002,
        crc_errors=0.002,
        drop=0.002,
        pull_every_min=4.0,
        pull_for_s=1.0,
        workdir=tmp_path,
    )
    print(soak.report(r))
    assert r.exit_code == 0 and not r.traceback
    assert r.pulls == 2 and r.reconnects == 2 and r.device_lost_events == 2
    assert r.stale_reports > 0  # while each cable was out
    assert r.steps_published == r.steps_expected and r.steps_in_order
    assert r.samples_published == r.frames_delivered
    assert r.bad_injected > 0 and r.bad_counted == r.bad_injected
    assert r.dropped > 0 and r.garbage_events > 0
    assert r.bias_dps is not None  # measured at start, no bias file
    assert r.events.get("calibrated") == 1 and r.events.get("stop") == 1
    # Memory: the daemon does not keep what it has published. Ten minutes cannot show a slow
    # leak (the 6-hour run in RESULTS.md does); this catches a gross one, e.g. every message kept.
    assert 0 < r.rss_start_kb and r.rss_end_kb - r.rss_start_kb < 16 * 1024
    assert r.ok
