"""A long random byte stream through both parsers: every intact frame back, every bad one counted.

    python -m tools.fuzz --surface stream [--bytes 10000000] [--seed 0] [--protocol hdr-bin|hdr-text|both]
    python -m tools.fuzz.stream [--bytes 10000000] [--seed 0] [--protocol ...] [--json FILE]

A seeded generator writes a stream of ``--bytes`` bytes made of

- intact frames whose sequence numbers and device times carry every irregularity the wire can
  show: sequence skips, repeats, reorderings (a few behind), restarts; clock jumps forward,
  repeated times, small steps back, resets, and the 2**32 us wrap; ADC counts at the rails
  (0 and 65535) and beyond the CRS03-04's +/-200 deg/s;
- corrupted frames (one bit flipped in hdr-bin, one digit changed in hdr-text);
- truncated frames (cut anywhere after the sync pattern);
- random garbage (any byte values, so also stray sync patterns), and garbage that starts
  with a sync pattern.

It is fed to the push parser (:class:`hdrd.io.wire.parser.Parser`) in random chunks of 1..4096 bytes
and, whole, to the vectorised decoder (:func:`hdrd.io.wire.capture.decode_capture`); the recovered
frames then go through the pipeline (:meth:`hdrd.daemon.pipeline.Pipeline.feed_array`).

What is expected is known from the construction: the frames recovered are exactly the intact
frames sent that the sequence and clock rule keeps (:class:`hdrd.io.wire.tracker.FrameTracker`, run
over the list of them at once: a repeat, a frame whose clock disagrees with its sequence
number are dropped; docs/protocol.md, "Sequence and clock"); the bad frames counted are exactly the sync patterns outside the intact frames
(the parser's documented rule: every sync pattern that does not start a good frame is one bad
frame, and the scan moves on by one byte), except those in the last bytes of the stream,
whose frame never completes. Candidates that pass the CRC-16 by coincidence (about 1 in
65536) are counted and reported: those hiding a real frame are set aside by the parsers'
coincidence rule (docs/protocol.md), which the reference scan applies too; garbage that forms
a valid frame overlapping no real one is the exception no receiver can avoid. Saturation: every recovered sample at a
rail or beyond +/-200 deg/s that the device clock accepts is flagged in its step's
``saturated`` count, unless its supply reading is a fault: then in ``supply_faults``
(docs/protocol.md, "What is not a rate").

Exit status 1 if any expectation fails. Results: bench/RESULTS.md, "Fuzz: a byte stream through both parsers".
"""

from __future__ import annotations

import argparse
import itertools
import json
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.core.calibrate import given_bias
from hdrd.core.methods import MethodSetup
from hdrd.core.sensor import SensorModel
from hdrd.daemon.pipeline import Pipeline
from hdrd.daemon.stepper import PipelineConfig
from hdrd.io.wire.capture import crc16_ccitt_false_rows, decode_capture, encode_array
from hdrd.io.wire.clocks import unwrap_us
from hdrd.io.wire.codec import FRAME_DTYPE, array_to_frames, encode_text
from hdrd.io.wire.parser import Parser
from hdrd.io.wire.protocol import BIN_FRAME_LEN
from hdrd.io.wire.tracker import FrameTracker, ParserStats

TEXT_SYNC = b"$HDRG,"


def make_frames(n: int, rng: np.random.Generator) -> npt.NDArray[np.void]:
    """n frames at 100 Hz with irregular sequence numbers and device times (see module doc)."""
    u = rng.random(n)
    dseq = np.ones(n, np.int64)
    dseq[u < 0.02] = rng.integers(2, 300, int((u < 0.02).sum()))  # skips
    m = (u >= 0.02) & (u < 0.025)
    dseq[m] = 0  # repeats
    m = (u >= 0.025) & (u < 0.03)
    dseq[m] = -rng.integers(1, 65, int(m.sum()))  # reordered, a few behind
    m = (u >= 0.03) & (u < 0.0303)
    dseq[m] = -rng.integers(65, 0x8000, int(m.sum()))  # device restarts
    v = rng.random(n)
    dt = np.full(n, 10_000, np.int64)
    dt += rng.integers(-500, 501, n)  # jitter
    m = v < 0.003
    dt[m] = rng.integers(20_000, 30_000_000, int(m.sum()))  # jumps forward (gaps)
    m = (v >= 0.003) & (v < 0.006)
    dt[m] = 0  # repeated time
    m = (v >= 0.006) & (v < 0.009)
    dt[m] = -rng.integers(1, 1_000_000, int(m.sum()))  # small steps back
    m = (v >= 0.009) & (v < 0.0093)
    dt[m] = -rng.integers(1_000_001, 2**31, int(m.sum()))  # clock resets
    arr = np.zeros(n, FRAME_DTYPE)
    arr["seq"] = (int(rng.integers(0, 65536)) + np.cumsum(dseq)) & 0xFFFF
    t0 = 2**32 - 60_000_000  # the clock wraps a minute in
    arr["t_us"] = (t0 + np.cumsum(dt)) % 2**32
    rate = np.rint(32768 + rng.normal(0, 300, n)).astype(np.int64)
    w = rng.random(n)
    rate[w < 0.002] = 0
    rate[(w >= 0.002) & (w < 0.004)] = 65535
    m = (w >= 0.004) & (w < 0.006)
    rate[m] = rng.integers(58983, 65535, int(m.sum()))  # beyond +200 deg/s, not at the rail
    arr["rate"] = np.clip(rate, 0, 65535)
    arr["ref"] = np.where(rng.random(n) < 0.5, 0, rng.integers(30000, 36000, n))
    arr["temp"] = np.where(rng.random(n) < 0.1, -32768, rng.integers(-4000, 8500, n))
    return arr


def _wires(protocol: str, frames: Any, n: int) -> list[bytes]:
    """Each frame as the wire carries it."""
    if protocol == "hdr-bin":
        wire_all = np.frombuffer(encode_array(frames, "hdr-bin"), np.uint8).reshape(
            -1, BIN_FRAME_LEN
        )
        return [wire_all[i].tobytes() for i in range(n)]
    return [encode_text(f) for f in array_to_frames(frames)]


def _corrupted(protocol: str, w: bytes, rng: np.random.Generator) -> bytes:
    """A frame with one bit flipped (hdr-bin) or one digit changed (hdr-text)."""
    bb = bytearray(w)
    if protocol == "hdr-bin":
        bb[int(rng.integers(2, 16))] ^= 1 << int(rng.integers(0, 8))
    else:
        star = bb.rindex(b"*")
        digits = [j for j in range(6, star) if 0x30 <= bb[j] <= 0x39]
        j = digits[int(rng.integers(0, len(digits)))]
        bb[j] = 0x30 + (bb[j] - 0x30 + int(rng.integers(1, 10))) % 10
    return bytes(bb)


def _truncated(protocol: str, w: bytes, rng: np.random.Generator) -> bytes:
    """Cut after the sync pattern's first bytes and before the end of the payload (a text
    line cut just before its line end would be made whole by a junk "\\r\\n")."""
    end = len(w) - 1 if protocol == "hdr-bin" else w.rindex(b"*")
    return w[: int(rng.integers(2, end))]


def _garbage(protocol: str, w: bytes, rng: np.random.Generator) -> bytes:
    b = rng.integers(0, 256, int(rng.integers(1, 41)), dtype=np.uint8).tobytes()
    if protocol == "hdr-text":
        b = b.replace(b"$", b"#")  # text sync patterns are injected explicitly below
    return b


def _sync_garbage(protocol: str, w: bytes, rng: np.random.Generator) -> bytes:
    tail = rng.integers(0, 256, int(rng.integers(0, 21)), dtype=np.uint8).tobytes()
    if protocol == "hdr-bin":
        return b"\xa5\x5a" + tail
    return TEXT_SYNC + tail.replace(b"$", b"#")


def _intact(protocol: str, w: bytes, rng: np.random.Generator) -> bytes:
    return w


# By kind: a piece of the stream made from the next frame's wire bytes.
_PIECES: tuple[tuple[str, Callable[[str, bytes, np.random.Generator], bytes]], ...] = (
    ("intact", _intact),
    ("corrupted", _corrupted),
    ("truncated", _truncated),
    ("garbage", _garbage),
    ("sync_garbage", _sync_garbage),
)


def build_stream(protocol: str, nbytes: int, seed: int) -> dict[str, Any]:
    """The stream, the intact frames in it (and where they start), and what was injected."""
    rng = np.random.default_rng(seed)
    n_pieces = nbytes // (10 if protocol == "hdr-bin" else 25) + 16  # more than enough
    frames = make_frames(n_pieces, rng)
    wires = _wires(protocol, frames, n_pieces)
    kinds = rng.choice(
        5, n_pieces, p=[0.80, 0.06, 0.04, 0.06, 0.04]
    )  # good, corrupt, truncated, junk, sync junk
    parts: list[bytes] = []
    good_idx: list[int] = []
    good_pos: list[int] = []
    injected = {name: 0 for name, _ in _PIECES}
    pos = 0
    for i in range(n_pieces):
        if pos >= nbytes:
            break
        name, piece = _PIECES[int(kinds[i])]
        if name == "intact":
            good_idx.append(i)
            good_pos.append(pos)
        b = piece(protocol, wires[i], rng)
        injected[name] += 1
        parts.append(b)
        pos += len(b)
    data = b"".join(parts)
    return {
        "data": data,
        "sent": frames[np.asarray(good_idx, np.int64)],
        "good_pos": np.asarray(good_pos, np.int64),
        "injected": injected,
    }


def reference_bin(data: bytes, good_pos: npt.NDArray[np.int64]) -> dict[str, Any]:
    """What the documented scan must give, from the positions alone: every sync candidate
    whose 16 bytes pass the CRC is a frame start (the intact frames, and any coincidence in
    garbage); left to right, a start inside a frame already taken is skipped; every other
    complete candidate outside the frames taken is one bad frame."""
    a = np.frombuffer(data, np.uint8)
    n = a.shape[0]
    cand = np.flatnonzero((a[:-1] == 0xA5) & (a[1:] == 0x5A))
    cand = cand[cand + BIN_FRAME_LEN <= n]
    rows = np.lib.stride_tricks.sliding_window_view(a, BIN_FRAME_LEN)[cand]
    crc = rows[:, 14].astype(np.uint16) | (rows[:, 15].astype(np.uint16) << 8)
    valid = crc16_ccitt_false_rows(rows[:, 2:14]) == crc

    # A CRC coincidence is not a frame: a valid candidate with another valid one starting
    # 2..14 bytes on that is followed by a sync pattern 16 bytes on while it is not.
    def sync_at(k: int) -> bool:
        return k + 2 <= n and a[k] == 0xA5 and a[k + 1] == 0x5A

    valid_pos = cand[valid].tolist()
    valid_set = set(valid_pos)
    coincidence = {
        p
        for p in valid_pos
        if not sync_at(p + BIN_FRAME_LEN)
        and any(q in valid_set and sync_at(q + BIN_FRAME_LEN) for q in range(p + 2, p + 15))
    }
    crc_valid = valid.copy()
    valid &= ~np.isin(cand, np.fromiter(coincidence, np.int64, len(coincidence)))
    taken: list[int] = []
    end = 0
    for p in cand[valid].tolist():
        if p >= end:
            taken.append(p)
            end = p + BIN_FRAME_LEN
    taken_a = np.asarray(taken, np.int64)
    covered = np.zeros(n + 1, np.int64)
    np.add.at(covered, taken_a, 1)
    np.add.at(covered, taken_a + BIN_FRAME_LEN, -1)
    inside = np.cumsum(covered)[:n] > 0
    bad = int(np.count_nonzero(~valid & ~inside[cand]))
    frames = (
        rows[valid][np.isin(cand[valid], taken_a)][:, 2:14].copy().view(FRAME_DTYPE).reshape(-1)
    )
    good_set = np.isin(taken_a, good_pos)
    return {
        "frames": frames,
        "bad": bad,
        "coincidences": int(np.count_nonzero(~np.isin(cand[crc_valid], good_pos))),
        "coincidences_set_aside": len(coincidence),
        "intact_recovered": int(np.count_nonzero(good_set)),
    }


def expected_bad_text(data: bytes, good_pos: npt.NDArray[np.int64]) -> tuple[int, int]:
    """(sync patterns outside the intact lines, those near the end that may still wait)."""
    inside = set(good_pos.tolist())
    syncs = []
    i = data.find(TEXT_SYNC)
    while i >= 0:
        if i not in inside:
            syncs.append(i)
        i = data.find(TEXT_SYNC, i + 1)
    pending = sum(1 for i in syncs if len(data) - i < 96)
    return len(syncs), pending


def kept(arr: npt.NDArray[np.void]) -> npt.NDArray[np.void]:
    """The frames of ``arr`` the sequence and clock rule keeps, judged all at once."""
    tracker = FrameTracker()
    keep = tracker.run_array(arr)
    tracker.flush()
    return arr[keep]


def push(
    protocol: str, data: bytes, rng: np.random.Generator
) -> tuple[list[Any], ParserStats, float]:
    p = Parser(protocol)
    out: list[Any] = []
    cuts = np.cumsum(rng.integers(1, 4097, len(data) // 2048 + 2))
    edges = [0, *cuts[cuts < len(data)].tolist(), len(data)]
    t0 = time.perf_counter()
    for a, b in itertools.pairwise(edges):
        out += p.feed(data[a:b])
    out += p.flush()
    return out, p.stats, time.perf_counter() - t0


def _against_reference(
    protocol: str, s: dict[str, Any], arr: Any, stats: Any, frames: list[Any], sent: list[Any]
) -> tuple[int, int, int, int, int, bool]:
    """The push parser's result against the reference: bad frames expected (and how many of
    them still pending at the end), CRC coincidences (and those set aside), intact frames
    recovered, and whether it is the reference's."""
    if protocol == "hdr-bin":
        ref = reference_bin(s["data"], s["good_pos"])
        as_reference = np.array_equal(arr, kept(ref["frames"])) and stats.bad_frames == ref["bad"]
        return (
            ref["bad"], 0, ref["coincidences"], ref["coincidences_set_aside"],
            ref["intact_recovered"], as_reference,
        )  # fmt: skip
    # Text: garbage cannot form a line (no '$' in it; a cut line keeps no checksum).
    want_bad, pending = expected_bad_text(s["data"], s["good_pos"])
    intact = len(sent) if frames == sent else 0
    as_reference = intact == len(sent) and want_bad - pending <= stats.bad_frames <= want_bad
    return want_bad, pending, 0, 0, intact, as_reference


def _through_the_pipeline(arr: Any, vstats: Any) -> tuple[list[Any], float, int, int, int, int]:
    """The pipeline on what was recovered (rails and out-of-range samples flagged, no crash):
    its messages, its seconds, the saturated samples sent and flagged, the supply faults sent
    and flagged."""
    t0 = time.perf_counter()
    pipe = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.0))))
    msgs = pipe.feed_array(arr, vstats.bad_before) + pipe.finish(vstats.bad_frames)
    t_pipe = time.perf_counter() - t0
    sensor = SensorModel()
    _, accepted = unwrap_us(arr["t_us"])
    rate = arr["rate"][accepted].astype(np.int64)
    monitor = arr["ref"][accepted].astype(np.int64)
    omega = sensor.to_dps_array(rate, monitor)
    fault = sensor.supply_faults(sensor.supply_readings(monitor))
    sat_sent = int(np.count_nonzero(~fault & np.asarray(sensor.saturated(rate, omega))))
    sat_flagged = sum(int(m.get("saturated", 0)) for m in msgs)
    faults_flagged = sum(int(m.get("supply_faults", 0)) for m in msgs)
    return msgs, t_pipe, sat_sent, sat_flagged, int(np.count_nonzero(fault)), faults_flagged


def run(protocol: str, nbytes: int, seed: int) -> dict[str, Any]:
    t_gen = time.perf_counter()
    s = build_stream(protocol, nbytes, seed)
    t_gen = time.perf_counter() - t_gen
    data, sent = s["data"], s["sent"]
    frames, stats, t_push = push(protocol, data, np.random.default_rng(seed + 1))
    t0 = time.perf_counter()
    arr, vstats = decode_capture(data, protocol)
    t_vec = time.perf_counter() - t0
    got = array_to_frames(arr)
    same_push_vec = got == frames and vstats == stats
    sent_frames = array_to_frames(kept(sent))
    want_bad, pending, coincidences, set_aside, intact, as_reference = _against_reference(
        protocol, s, arr, stats, frames, sent_frames
    )
    exact = frames == sent_frames
    msgs, t_pipe, sat_sent, sat_flagged, faults_sent, faults_flagged = _through_the_pipeline(
        arr, vstats
    )
    steps = [m["step"] for m in msgs]
    steps_ok = steps == sorted(set(steps))
    ok = (
        same_push_vec
        and as_reference
        and steps_ok
        and sat_flagged == sat_sent
        and faults_flagged == faults_sent
    )
    return {
        "protocol": protocol,
        "bytes": len(data),
        "seed": seed,
        "injected": s["injected"],
        "frames_sent": len(sent_frames),
        "frames_recovered": len(frames),
        "intact_recovered": intact,
        "as_reference": as_reference,
        "recovered_exactly": exact,
        "bad_expected": want_bad,
        "bad_expected_pending_at_end": pending,
        "bad_counted": stats.bad_frames,
        "crc_coincidences": coincidences,
        "crc_coincidences_set_aside": set_aside,
        "push_equals_vectorised": same_push_vec,
        "counters": stats.as_dict(),
        "steps": len(msgs),
        "saturated_samples": sat_sent,
        "saturated_flagged": sat_flagged,
        "supply_faults_flagged": faults_flagged,
        "seconds": {"generate": t_gen, "push": t_push, "vectorised": t_vec, "pipeline": t_pipe},
        "ok": ok,
    }


def report(r: dict[str, Any]) -> str:
    c = r["counters"]
    inj = r["injected"]
    sec = r["seconds"]
    mb = r["bytes"] / 1e6
    pending = r["bad_expected_pending_at_end"]
    lines = [
        f"{r['protocol']}: {r['bytes']:,} bytes, seed {r['seed']}",
        (
            f"  injected: {inj['intact']:,} intact frames, {inj['corrupted']:,} corrupted, "
            f"{inj['truncated']:,} truncated, {inj['garbage']:,} garbage runs, "
            f"{inj['sync_garbage']:,} garbage runs headed by a sync pattern"
        ),
        (
            f"  intact frames recovered {r['intact_recovered']:,} of {r['frames_sent']:,} sent; "
            f"frames out {r['frames_recovered']:,} (exactly the frames sent: {r['recovered_exactly']})"
        ),
        (
            f"  bad frames counted {r['bad_counted']:,}, expected {r['bad_expected']:,}"
            + (f" (up to {pending} still pending at the end)" if pending else "")
            + f"; CRC-valid candidates formed by garbage {r['crc_coincidences']}"
            + f" ({r['crc_coincidences_set_aside']} set aside as coincidences)"
            + f"; as the reference scan: {r['as_reference']}"
        ),
        (
            f"  sequence: gaps {c['seq_gaps']:,} (lost {c['lost_frames']:,}), "
            f"restarts {c['seq_resets']:,}; "
            f"clock: wraps {c['clock_wraps']}; frames dropped as not new {c['seq_repeats']:,}, "
            f"whose clock disagreed {c['seq_clock_mismatch']:,}"
        ),
        (
            f"  push parser == vectorised decoder: {r['push_equals_vectorised']}; "
            f"pipeline: {r['steps']:,} steps, saturated samples flagged "
            f"{r['saturated_flagged']:,} of {r['saturated_samples']:,}, supply faults "
            f"{r['supply_faults_flagged']:,}"
        ),
        (
            f"  time: push {sec['push']:.2f} s ({mb / sec['push']:.1f} MB/s), "
            f"vectorised {sec['vectorised']:.2f} s ({mb / sec['vectorised']:.1f} MB/s), "
            f"pipeline {sec['pipeline']:.2f} s"
        ),
        f"  {'OK' if r['ok'] else 'FAILED'}",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bytes", type=int, default=10_000_000, help="stream length per protocol")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--protocol", choices=("hdr-bin", "hdr-text", "both"), default="both")
    ap.add_argument("--json", metavar="FILE", help="write the results as JSON")
    args = ap.parse_args(argv)
    protocols = ("hdr-bin", "hdr-text") if args.protocol == "both" else (args.protocol,)
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, {platform.machine()}",
        flush=True,
    )
    results = []
    for protocol in protocols:
        r = run(protocol, args.bytes, args.seed)
        results.append(r)
        print(report(r), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2) + "\n")
    return 0 if all(r["ok"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
