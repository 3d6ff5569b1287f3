"""Golden capture: a recorded drive with faults and the exact output `hdrd replay` gives.

As gpsd keeps ``test/daemon/*.log`` with their ``*.log.chk``: tests/data/golden/ holds a
capture recorded by ``hdrd record`` from a fake gyro on a pty (tools/golden_capture.py says
what it holds: garbage, CRC errors, dropped frames, a cable pull, a device reset, clock and
sequence wraps, a supply monitor, temperatures) and, for each method, the JSON lines
``hdrd replay`` printed for it. Every other test generates its input from seeds at run time,
so a change that moves all outputs together (a constant, a rounding, a default) passes
them; here it shows as a changed line.

A change of output that is meant: ``python -m pytest tests/test_golden.py --regen-golden``
rewrites the expected files; review their diff and commit it with the change.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from hdrd.cli import main as cli
from hdrd.io.wire.capture import decode_capture
from hdrd.io.wire.clocks import DeviceClock

GOLDEN = Path(__file__).resolve().parent / "data" / "golden"
CAPTURE = GOLDEN / "drive-faults.bin"
CONFIG = GOLDEN / "hdrd.yaml"  # the built-in defaults, named so /etc/hdrd/hdrd.yaml is not read
REPLAY_ARGS = ["--config", str(CONFIG), "--calibrate-seconds", "20"]


def expected_path(method: str) -> Path:
    return GOLDEN / f"drive-faults.{method}.jsonl"


@pytest.mark.parametrize("method", ["hdr", "hdr+"])
def test_replay_of_the_golden_capture_is_the_expected_output(
    capsysbinary: pytest.CaptureFixture[bytes], regen_golden: bool, method: str
) -> None:
    rc = cli(["replay", str(CAPTURE), "--method", method, *REPLAY_ARGS])
    out, err = capsysbinary.readouterr()
    assert rc == 0 and err == b"", err
    path = expected_path(method)
    if regen_golden:
        path.write_bytes(out)
        pytest.skip(f"regenerated {path.relative_to(GOLDEN.parents[2])}")
    want = path.read_bytes().splitlines()
    got = out.splitlines()
    for i, (g, w) in enumerate(zip(got, want), 1):
        assert g == w, f"{path.name} line {i} differs:\n  got  {g.decode()}\n  want {w.decode()}"
    assert len(got) == len(want), f"{len(got)} lines, {path.name} has {len(want)}"
    assert out == path.read_bytes()  # and byte for byte (line ends, final newline)


def test_the_golden_capture_holds_its_faults() -> None:
    """The capture still has what it is kept for (if it is ever re-recorded)."""
    data = CAPTURE.read_bytes()
    assert len(data) < 64 * 1024
    frames, st = decode_capture(data)
    assert st.garbage_bytes > st.bad_frames * 16 > 0  # garbage and corrupted frames
    assert st.seq_gaps > st.bad_frames  # drops and a pull, besides the bad frames' gaps
    assert st.seq_resets == 1 and st.clock_wraps == 1  # the re-powered device; a clock wrap
    clock = DeviceClock()
    t_us, ok = clock.unwrap_many(frames["t_us"])
    assert ok.all() and clock.resets == 1 and clock.wraps == 1
    steps_us = t_us[1:] - t_us[:-1]
    assert steps_us.max() > 2_000_000  # the cable pull: 2 s without frames
    assert (frames["ref"] > 0).any() and (frames["ref"] == 0).any()  # supply monitor, then none
    assert (frames["temp"] != -32768).any() and (frames["temp"] == -32768).any()
    seq = frames["seq"].astype(int)
    assert (seq[1:] < seq[:-1]).sum() == 2  # the sequence wrap and the reset
