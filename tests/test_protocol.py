"""hdrd.io.wire.protocol: the wire's field table and the message schema in one place. hdr-bin's struct
formats, numpy dtype, the firmware's C header and docs/protocol.md's layout all follow the
table; what the pipeline and the GPS aiding publish uses only the schema's keys, in its order,
with its class, version and statuses; docs/protocol.md's table lists the same keys."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from hdrd.core.calibrate import given_bias
from hdrd.core.methods import MethodSetup
from hdrd.daemon.aiding import AidingConfig, GpsAiding
from hdrd.daemon.pipeline import Pipeline
from hdrd.daemon.stepper import PipelineConfig
from hdrd.io.net.gpsdjson import Fix
from hdrd.io.wire import protocol
from hdrd.io.wire.codec import BIN_BODY, FRAME_DTYPE, Frame, encode_bin
from tests.test_aiding import on_message
from tools.gen_header import HEADER, c_header

DOC = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"


def frames(n: int, hz: float = 10.0, rate: int = 33000, gap_at: int | None = None) -> Any:
    """n frames at hz, one ADC count level (a standstill a little off the null), with a 5 s
    hole before frame gap_at and temperatures on every second frame."""
    arr = np.zeros(n, FRAME_DTYPE)
    t = np.arange(n, dtype=np.int64) * int(1e6 / hz)
    if gap_at is not None:
        t[gap_at:] += 5_000_000
    arr["seq"] = np.arange(n) & 0xFFFF
    arr["t_us"] = t
    arr["rate"] = rate
    arr["temp"] = np.where(np.arange(n) % 2 == 0, 2500, protocol.TEMP_NOT_FITTED)
    return arr


def published() -> list[dict[str, Any]]:
    """Messages of every kind: calibrating, steps of hdr and hdr+ (with a standstill), a step
    after a gap, saturated samples, a stale report, and GPS-aided steps."""
    out: list[dict[str, Any]] = []
    for method in ("hdr", "hdr+"):
        p = Pipeline(PipelineConfig(startup_s=1.0, setup=MethodSetup(method=method)))
        p.set_speed(0.0)  # standing: HDR+ makes zero-rate updates
        arr = frames(400, gap_at=200)
        arr["rate"][300:310] = 65535  # at the rail: saturated
        out += p.feed_array(arr)
        out += p.finish()
        out.append(p.stale_message(1.0e9, 4.0, 0))
    a = GpsAiding(AidingConfig())
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.0))))
    for k, m in enumerate(p.feed_array(frames(300))):
        a.on_fix(Fix(mode=3, track_deg=90.0, speed_mps=15.0, epd=2.0), float(k))
        out.append(on_message(a, m, k + 0.5)[0])
    return out


def test_messages_use_the_schema() -> None:
    msgs = published()
    known = set(protocol.STEP_KEYS) | set(protocol.ADDED_KEYS)
    seen: set[str] = set()
    for m in msgs:
        assert m["class"] == protocol.MESSAGE_CLASS and m["v"] == protocol.SCHEMA_VERSION
        assert set(m) <= known, set(m) - known
        assert m["status"] in protocol.STATUSES
        in_table = [k for k in m if k in protocol.STEP_KEYS]
        assert in_table == sorted(in_table, key=protocol.STEP_KEYS.index)
        seen |= set(m)
    # The test reaches every kind of message it claims to.
    assert {"status", "zupt", "gap_s", "saturated", "stale_s", "mode", "gps_course"} <= seen
    assert {m["status"] for m in msgs} >= {"calibrating", "ok", "standstill", "stale"}


def doc_table_keys() -> list[str]:
    section = DOC.read_text().split("\n### JSON lines\n", 1)[1].split("\n### ", 1)[0]
    return re.findall(r"^\| `([^`]+)` \|", section, flags=re.MULTILINE)


def test_the_docs_table_lists_the_step_keys_in_order() -> None:
    assert doc_table_keys() == list(protocol.STEP_KEYS)


def test_the_docs_name_every_added_key_and_the_valid_statuses() -> None:
    text = DOC.read_text()
    for key in protocol.ADDED_KEYS:
        assert f"`{key}`" in text, key
    for status in protocol.RATE_VALID_STATUSES:
        assert f"`{status}`" in text, status


def doc_bin_layout() -> list[tuple[int, int, str]]:
    """docs/protocol.md's hdr-bin table: (offset, size, field name) per row."""
    section = DOC.read_text().split("\n### hdr-bin (default)\n", 1)[1].split("\n### ", 1)[0]
    rows = re.findall(r"^\| (\d+) \| (\d+) \| (?:sync bytes|(\w+):)", section, re.MULTILINE)
    return [(int(o), int(n), name or "sync") for o, n, name in rows]


def test_the_wire_follows_the_one_field_table() -> None:
    sizes = [protocol.WIRE_TYPES[f.type].size for f in protocol.BIN_FIELDS]
    offsets = [protocol.BIN_PAYLOAD_AT + sum(sizes[:i]) for i in range(len(sizes))]
    names = [f.name for f in protocol.BIN_FIELDS]
    # the numpy dtype of the vectorised decoder: the payload, packed
    assert FRAME_DTYPE.names == tuple(names) and FRAME_DTYPE.itemsize == protocol.BIN_PAYLOAD_LEN
    assert FRAME_DTYPE.fields is not None
    assert [FRAME_DTYPE.fields[n][1] + protocol.BIN_PAYLOAD_AT for n in names] == offsets
    # the struct format: the payload then the CRC, to the frame's end
    assert BIN_BODY.size == protocol.BIN_FRAME_LEN - protocol.BIN_PAYLOAD_AT
    wire = encode_bin(Frame(258, 1_000_000, 33554, 32768, 2512))
    assert BIN_BODY.unpack_from(wire, protocol.BIN_PAYLOAD_AT)[:-1] == (
        258,
        1_000_000,
        33554,
        32768,
        2512,
    )
    assert (
        wire[protocol.BIN_PAYLOAD_AT :]
        == np.array([(258, 1_000_000, 33554, 32768, 2512)], FRAME_DTYPE).tobytes()
        + wire[protocol.BIN_CRC_AT :]
    )
    # the docs' layout
    assert doc_bin_layout() == [
        (0, len(protocol.SYNC), "sync"),
        *zip(offsets, sizes, names),
        (protocol.BIN_CRC_AT, 2, "crc"),
    ]
    assert protocol.BIN_CRC_AT + 2 == protocol.BIN_FRAME_LEN


def test_the_firmwares_header_is_what_the_field_table_makes() -> None:
    """firmware/src/wire.h is generated (``python -m tools.gen_header``): the committed one
    is the table's, and it declares each field of the table, in order, with its C type."""
    text = HEADER.read_text()
    assert text == c_header()
    struct = text.split("typedef struct {", 1)[1].split("} hdr_sample_t;", 1)[0]
    members = re.findall(r"^\s+(\w+)\s+(\w+);", struct, re.MULTILINE)
    assert members == [(protocol.WIRE_TYPES[f.type].c, f.name) for f in protocol.BIN_FIELDS]
