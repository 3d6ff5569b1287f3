"""A short, seeded fuzz of every input surface (the long runs: ``python -m tools.fuzz``,
bench/RESULTS.md).

Two kinds: hypothesis draws structured hostile inputs (documents of any shape whose leaves
may be 5,000-digit numbers, NaN, nesting thousands deep, control characters) for each
surface's public entry point, derandomized so that every run tries the same examples; and
the fuzz harness itself runs a few hundred inputs per surface through the daemon's code
paths, with a check that it does report a traceback and a hang when there is one.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hdrd.core.calibrate import given_bias
from hdrd.core.methods import MethodSetup
from tests.test_aiding import on_message
from tools.fuzz import harness as fuzz
from tools.fuzz.contract import one_line
from tools.fuzz.mutate import Tok, emit_json, emit_yaml
from tools.fuzz.surfaces import SURFACES, generate
from tools.fuzz.targets import check_messages

ROOT = Path(__file__).resolve().parent.parent

FUZZ = settings(
    max_examples=100,
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

HOSTILE = st.sampled_from(
    [
        Tok("1" + "0" * 5000),  # more digits than Python converts
        Tok("1" + "0" * 400),  # an integer beyond float range
        Tok("-1e400"),
        Tok("NaN"),
        Tok("Infinity"),
        Tok("[" * 3000 + "]" * 3000),
        Tok('"\\ud800"'),
        Tok('"\\u001b[2J\\u0007"'),
    ]
)
SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=30),
    HOSTILE,
)
TREES = st.recursive(
    SCALARS,
    lambda kids: st.one_of(
        st.lists(kids, max_size=4),
        st.dictionaries(
            st.one_of(st.text(max_size=8), st.sampled_from(["class", "mode", "track", "speed"])),
            kids,
            max_size=5,
        ),
    ),
    max_leaves=12,
)
GPSD_CLASSES = st.sampled_from(
    ["TPV", "SKY", "ATT", "VERSION", "DEVICES", "DEVICE", "WATCH", "ERROR"]
)


# -- gpsd: the parser, and the aiding the daemon feeds --------------------------------------------


@FUZZ
@given(
    cls=GPSD_CLASSES,
    body=st.dictionaries(st.text(max_size=10), TREES, max_size=6),
    tail=st.binary(max_size=8),
)
def test_gpsd_lines_are_reports_or_protocol_errors(
    cls: str, body: dict[str, Any], tail: bytes
) -> None:
    from hdrd.daemon.aiding import GpsAiding
    from hdrd.io.net.gpsdjson import Fix, GpsdProtocolError, parse_line

    for key in ("mode", "track", "speed", "epd"):  # the fields aiding reads, made hostile too
        body.setdefault(key, body.get(key))
    line = emit_json({"class": cls, **body}).encode("utf-8", "surrogatepass") + tail
    try:
        rep = parse_line(line)
    except GpsdProtocolError as e:
        one_line(str(e), "gpsd protocol error")
        return
    if isinstance(rep, Fix):
        aiding = GpsAiding()
        aiding.on_fix(rep, 10.0)
        msg = {
            "class": "HDR",
            "heading": 12.5,
            "omega": 0.5,
            "omega_raw": 0.6,
            "bias": 0.1,
            "t": 1.0,
        }
        out, delta = on_message(aiding, msg, 10.5)
        assert math.isfinite(delta)
        check_messages([{**out, "status": "ok"}])


# -- tail -----------------------------------------------------------------------------------------


@FUZZ
@given(
    parts=st.lists(
        st.one_of(
            TREES.map(lambda t: emit_json(t).encode("utf-8", "surrogatepass")),
            st.binary(max_size=40),
        ),
        min_size=1,
        max_size=4,
    ),
    raw=st.booleans(),
)
def test_tail_prints_only_printable_lines(parts: list[bytes], raw: bool) -> None:
    from hdrd.io.net.datagrams import TailFormatter

    out, notes, n = TailFormatter(raw=raw).lines(b"\n".join(parts), "127.0.0.1:9")
    assert n >= 0
    for line in out + notes:
        assert line.isprintable(), line


# -- config and bias files ------------------------------------------------------------------------

SECTIONS = st.sampled_from(
    ["device", "sensor", "hdr", "calibration", "output", "log", "gpsd", "standstill"]
)
KEYS = st.sampled_from(
    ["port", "baud", "c1", "c2", "T", "startup_s", "udp", "nmea_talker", "host", "x"]
)


@settings(FUZZ, max_examples=60)  # a file and a replay per example
@given(
    doc=st.dictionaries(SECTIONS, st.dictionaries(KEYS, TREES, max_size=4), max_size=3),
    block=st.integers(0, 2),
    raw=st.binary(max_size=3),
    at=st.integers(0, 200),
)
def test_a_config_is_valid_or_one_config_error(
    tmp_path_factory: pytest.TempPathFactory,
    doc: dict[str, Any],
    block: int,
    raw: bytes,
    at: int,
) -> None:
    from hdrd.config import ConfigError
    from hdrd.configload import load_config
    from hdrd.daemon.replay import replay_capture

    p = tmp_path_factory.mktemp("cfg") / "hdrd.yaml"
    text = emit_yaml(doc, block_depth=block).encode("utf-8", "surrogatepass")
    p.write_bytes(text[:at] + raw + text[at:])  # raw bytes anywhere: control characters
    try:
        cfg, _ = load_config(p)
    except ConfigError as e:
        one_line(str(e), "config error")
        return
    check_messages(replay_capture(_CAPTURE, cfg, 0.1), talker=cfg.output.nmea_talker)


@settings(FUZZ, max_examples=60)
@given(
    fields=st.dictionaries(
        st.sampled_from(["bias_dps", "std_dps", "n", "duration_s", "temp_c", "time", "x"]),
        TREES,
        max_size=7,
    ),
    end=st.booleans(),
    raw=st.binary(max_size=3),
    at=st.integers(0, 200),
)
def test_a_bias_file_is_valid_or_one_bias_file_error(
    tmp_path_factory: pytest.TempPathFactory,
    fields: dict[str, Any],
    end: bool,
    raw: bytes,
    at: int,
) -> None:
    from hdrd.io.files.biasfile import BiasFileError, load_bias

    p = tmp_path_factory.mktemp("bias") / "bias.yaml"
    text = ("# hdrd static bias\n" + emit_yaml(fields)).encode("utf-8", "surrogatepass")
    p.write_bytes(text[:at] + raw + text[at:] + (b"# end\n" if end else b""))
    try:
        rec = load_bias(p, 3.0)
    except BiasFileError as e:
        one_line(str(e), "bias file error")
        return
    assert math.isfinite(rec.bias_dps) and abs(rec.bias_dps) <= 3.0 and rec.n >= 1


# -- serial bytes and captures --------------------------------------------------------------------


def _capture() -> bytes:
    from tools.fuzz.filetargets import stress_capture

    return stress_capture(0)


_CAPTURE = _capture()


@FUZZ
@given(
    data=st.binary(max_size=600),
    splice=st.integers(0, 9000),
    protocol=st.sampled_from(["hdr-bin", "hdr-text"]),
)
def test_serial_bytes_through_the_live_path(data: bytes, splice: int, protocol: str) -> None:
    from hdrd.daemon.pipeline import Pipeline
    from hdrd.daemon.stepper import PipelineConfig
    from hdrd.io.wire.parser import Parser

    stream = _CAPTURE[:splice] + data + _CAPTURE[splice:]
    parser, p = Parser(protocol), Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.1))))
    msgs = []
    for i in range(0, len(stream), 97):
        for f in parser.feed(stream[i : i + 97]):
            msgs += p.feed(f, parser.stats.bad_frames, 1.7e9)
    msgs += p.finish(parser.stats.bad_frames)
    check_messages(msgs)


@FUZZ
@given(data=st.binary(max_size=2000), protocol=st.sampled_from(["hdr-bin", "hdr-text"]))
def test_a_capture_replays_or_has_no_frames(data: bytes, protocol: str) -> None:
    from hdrd.config import Config
    from hdrd.configload import apply_overrides
    from hdrd.daemon.replay import replay_capture

    cfg = apply_overrides(Config(), {"device.protocol": protocol, "hdr.method": "hdr+"})
    check_messages(replay_capture(_CAPTURE[:3000] + data, cfg, None, startup_s=1.0))


# -- drive logs and the names in them ------------------------------------------------------------

CELLS = st.one_of(
    st.sampled_from(["", "nan", "inf", "1_000", "\u0661", "1e309", "725", "-1e200", "0", "1"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(max_size=8),
)


@FUZZ
@given(
    header=st.lists(
        st.sampled_from(["t", "omega", "heading_truth", "speed", "valid", "x", "", "\ufefft"]),
        min_size=1,
        max_size=5,
    ),
    rows=st.lists(st.lists(CELLS, max_size=6), max_size=12),
    meta=st.text(max_size=30),
)
def test_a_drive_log_csv_is_read_or_one_drive_log_error(
    header: list[str], rows: list[list[str]], meta: str
) -> None:
    import io

    from hdrd.io.files.drivecolumns import DriveLogError
    from hdrd.io.files.drivelog import read_drive

    text = f"# {meta}\n" + ",".join(header) + "\n" + "\n".join(",".join(r) for r in rows)
    try:
        log = read_drive(io.StringIO(text))
    except DriveLogError as e:
        one_line(str(e), "drive log error")
        return
    assert len(log) >= 1 and all(math.isfinite(v) for v in log.t.tolist())
    assert bool((abs(log.omega) <= 1000).all())
    if log.heading_truth is not None:
        h = log.heading_truth[~(log.heading_truth != log.heading_truth)]
        assert bool((abs(h) <= 360).all())


@FUZZ
@given(name=st.text(max_size=300), suffix=st.sampled_from(["", ".yaml"]))
def test_a_name_from_data_is_a_path_inside_or_refused(
    tmp_path_factory: pytest.TempPathFactory, name: str, suffix: str
) -> None:
    import os

    from hdrd.io.files.access import UnsafeNameError, path_inside
    from hdrd.io.files.drivefiles import drive_name

    root = tmp_path_factory.mktemp("out")
    shown = drive_name(name)
    assert shown.isprintable() and len(shown) <= 100
    for candidate in (name, shown):
        try:
            p = path_inside(root, candidate, suffix)
        except UnsafeNameError as e:
            one_line(str(e), "unsafe name")
            continue
        real = os.path.realpath(p)
        assert real.startswith(str(root.resolve()) + os.sep), (candidate, real)


@pytest.mark.parametrize(
    "path", sorted((ROOT / "tests" / "data" / "fuzz").glob("*.bin")), ids=lambda p: p.stem
)
def test_the_drive_logs_that_once_found_a_defect_keep_every_promise(
    path: Path, tmp_path: Path
) -> None:
    """Inputs of the drive-log surfaces that found a defect (bench/RESULTS.md, "Fuzz: drive
    logs"), kept as bytes: evaluate, tune and gap on each, as tools/fuzz runs them."""
    from tools.fuzz.drivelog import DriveLogTarget

    target = DriveLogTarget(path.name.split("-")[0], 0, tmp_path)
    target.every_command = True
    assert target.run(path.read_bytes()) in ("scored", "refused")


# -- the fuzz harness -----------------------------------------------------------------------------


def test_inputs_are_reproducible_from_seed_surface_and_index() -> None:
    for s in SURFACES:
        assert generate(s, 3, 17) == generate(s, 3, 17)
        assert generate(s, 3, 17) != generate(s, 4, 17)
    shown = subprocess.run(
        [sys.executable, "-m", "tools.fuzz", "--show", "config:17", "--seed", "3"],
        cwd=ROOT,
        capture_output=True,
        check=True,
        timeout=60,
    ).stdout
    assert shown == generate("config", 3, 17)


@pytest.mark.slow
@pytest.mark.parametrize("surface", SURFACES)
def test_a_short_seeded_run_of_each_surface(surface: str) -> None:
    n = {"config": 40, "drivecsv": 48, "driveparquet": 48}.get(surface, 120)  # evaluate, tune, gap
    r = fuzz.run_surface(surface, n, seconds=120, seed=7, hang_s=60, quiet=True)
    assert r.inputs == n
    assert r.ok, fuzz.describe(r)
    assert sum(r.outcomes.values()) == n


class _Faulty:
    """A target with a defect: raises on every 5th input, breaks a promise on every 7th
    (counted across the new targets the harness makes after each defect)."""

    calls = 0

    def run(self, data: bytes) -> str:
        _Faulty.calls += 1
        if _Faulty.calls % 5 == 0:
            json.loads(b"{" + data)
        if _Faulty.calls % 7 == 0:
            one_line("two\nlines", "refusal")
        return "fine"

    def close(self) -> None:
        pass


class _Hangs(_Faulty):
    def run(self, data: bytes) -> str:
        import time

        if data == generate("tail", 0, 2):  # input 2 of the run below: a loop
            end = time.monotonic() + 60
            while time.monotonic() < end:
                pass
        return "fine"


def test_the_harness_reports_tracebacks_and_broken_promises(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(fuzz, "make_target", lambda *a: _Faulty())
    monkeypatch.setattr(_Faulty, "calls", 0)
    r = fuzz.run_surface("tail", 20, seconds=60, seed=0, quiet=True)
    assert not r.ok and r.inputs == 20
    kinds = {d.kind for d in r.defects}
    assert kinds == {"traceback", "broken"}, fuzz.describe(r)
    assert "--show tail:" in fuzz.describe(r)


@pytest.mark.slow
def test_the_harness_reports_a_hang_and_goes_on(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(fuzz, "make_target", lambda *a: _Hangs())
    r = fuzz.run_surface("tail", 10, seconds=60, seed=0, hang_s=1.0, quiet=True)
    assert r.hangs == 1 and r.inputs == 10, fuzz.describe(r)
    assert r.defects[0].kind == "hang" and r.defects[0].first_input == 2


def test_the_process_runs_skip_the_surfaces_fuzzed_only_in_process() -> None:
    """``--process-only`` over every surface: the surfaces without a process-level run (the
    clock, the drive logs) are skipped, not an "unknown surface" traceback."""
    from tools.fuzz import process

    assert set(process.PROCESS_SURFACES) < set(SURFACES)
    for s in set(SURFACES) - set(process.PROCESS_SURFACES):
        with pytest.raises(ValueError, match="unknown surface"):
            process.run(s, 0, 1, 0.1)
    ns = fuzz._parser().parse_args(["--process-only"])  # every surface, as a user runs it
    doc: dict[str, Any] = {"process": []}
    skipped = tuple(s for s in SURFACES if s not in process.PROCESS_SURFACES)
    assert fuzz._as_processes(ns, skipped, doc) and doc["process"] == []
