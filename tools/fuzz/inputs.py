"""The fuzzed inputs of tools/fuzz, one generator per input surface (tools/fuzz/surfaces.py
names them all).

``surfaces.generate(surface, seed, i) -> bytes`` is input *i* of a surface's sequence: a valid input
(what hdrd or gpsd would really send or write) mutated by :mod:`tools.fuzz.mutate`, or random
bytes. Each input comes from its own :class:`random.Random` seeded with (seed, surface, i),
so any input can be made again on its own (``python -m tools.fuzz --show SURFACE:I``).

Surfaces: ``serial`` (bytes from the gyro's ADC, hdr-bin or hdr-text, as the daemon reads
them), ``gpsd`` (what a gpsd peer sends, one or more lines), ``tail`` (one UDP datagram for
``hdrd tail``), ``config`` (a configuration file), ``bias`` (a bias file), ``capture`` (a
capture file for ``hdrd replay``/``convert``), ``drivecsv`` and ``driveparquet`` (drive logs
for ``hdrd evaluate``/``tune``/``gap``: tools/fuzz/driveinputs.py), ``clock`` (a healthy
frame stream whose sequence numbers and device clock are broken now and then, with the host
time each frame arrives: tools/fuzz/clockinputs.py). A serial or capture input starts with one byte
naming its protocol (``B`` hdr-bin, ``T`` hdr-text); the rest is the stream.
"""

from __future__ import annotations

import copy
import json
import random
from dataclasses import fields
from functools import cache
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.core.calibrate import given_bias
from hdrd.core.methods import MethodSetup
from hdrd.io.wire.capture import encode_array
from hdrd.io.wire.codec import FRAME_DTYPE
from hdrd.io.wire.protocol import SYNC

from .mutate import Tok, emit_json, emit_yaml, hostile_value, mutate_bytes, mutate_tree

__all__ = ["rng_for"]

MAX_DATAGRAM = 65507
"""Largest UDP payload over IPv4."""


def rng_for(seed: int, surface: str, i: int) -> random.Random:
    """The generator of input *i* (str seeds are hashed with SHA-512: the same everywhere)."""
    return random.Random(f"{seed}:{surface}:{i}")


def _enc(text: str) -> bytes:
    return text.encode("utf-8", "surrogatepass")


# -- frames (serial, capture) -----------------------------------------------------------------


def stress_frames(rng: random.Random, n: int) -> npt.NDArray[np.void]:
    """*n* frames whose fields stress every stage: rates at the rails and beyond the gyro's
    range, a supply monitor at its extremes, temperatures absent or extreme, and a device
    clock and counter that jump, repeat, step back, reset and wrap."""
    g = np.random.default_rng(rng.getrandbits(64))
    dt_base = rng.choice((1, 100, 1000, 10_000, 100_000, 1_000_000))
    dt = np.full(n, dt_base, np.int64) + g.integers(-dt_base // 10, dt_base // 10 + 1, n)
    u = g.random(n)
    p = rng.choice((0.0, 0.001, 0.02, 0.2))
    dt[u < p] = g.choice(
        np.array([0, -1, -(2**31), 2**31 - 1, 2**31, 2**32 - 1, 30_000_000, -1_000_000]),
        int((u < p).sum()),
    )
    arr = np.zeros(n, FRAME_DTYPE)
    arr["t_us"] = (rng.getrandbits(32) + np.cumsum(dt)) % 2**32
    seq = np.cumsum(np.where(g.random(n) < p, g.integers(-40000, 40000, n), 1))
    arr["seq"] = (rng.getrandbits(16) + seq) % 2**16
    style = rng.randrange(5)
    rate: npt.NDArray[Any]
    if style == 0:  # a drive around the null
        rate = 32768 + g.normal(0, rng.choice((5, 300, 3000)), n)
    elif style == 1:  # rails
        rate = g.choice(np.array([0, 1, 65534, 65535]), n)
    elif style == 2:  # a long same-sign stretch (the attenuator's repetition count)
        rate = np.full(n, 32768 + rng.choice((-1, 1)) * rng.choice((1, 10, 200, 30000)))
    elif style == 3:
        rate = g.integers(0, 65536, n)
    else:  # a step: still, then turning hard
        rate = np.where(np.arange(n) < n // 2, 32768, rng.choice((0, 65535, 50000)))
    arr["rate"] = np.clip(np.rint(rate), 0, 65535)
    ref_style = rng.randrange(4)
    if ref_style == 0:
        arr["ref"] = 0
    elif ref_style == 1:
        arr["ref"] = g.choice(np.array([0, 1, 65535]), n)
    else:
        arr["ref"] = np.clip(g.normal(rng.choice((1, 20000, 32768, 60000)), 50, n), 0, 65535)
    temp_style = rng.randrange(3)
    arr["temp"] = (
        -32768
        if temp_style == 0
        else g.choice(np.array([-32768, -32767, 32767, 0, 2500]), n)
        if temp_style == 1
        else g.integers(-32767, 32768, n)
    )
    return arr


def _text_line(rng: random.Random, f: Any) -> bytes:
    """An hdr-text line with odd fields and a *correct* checksum (so decode_text's field
    checks, not its checksum, judge it)."""
    fields_ = [
        str(int(f["seq"])),
        str(int(f["t_us"])),
        str(int(f["rate"])),
        str(int(f["ref"]) or ""),
        "" if int(f["temp"]) == -32768 else f"{int(f['temp']) / 100:.2f}",
    ]
    k = rng.randrange(len(fields_))
    fields_[k] = rng.choice(
        (
            "9" * rng.choice((6, 11, 40, 5000)),
            "-1",
            "+5",
            " 5",
            "0x10",
            "1e3",
            "",
            "999999.999999",
            "-327.68",
            "327.675",
            "nan",
            "inf",
            "\x1b",
            "\u00e9".encode().decode("latin-1"),
            "1.",
            ".5",
        )
    )
    if rng.random() < 0.2:
        fields_.append("extra")
    body = ("HDRG," + ",".join(fields_)).encode("latin-1")
    x = 0
    for c in body:
        x ^= c
    cs = f"{x:02X}" if rng.random() < 0.8 else f"{x:02x}"
    return b"$" + body + b"*" + cs.encode() + rng.choice((b"\r\n", b"\n", b"\r", b""))


def frame_stream(rng: random.Random, protocol: str, max_frames: int) -> bytes:
    n = rng.choice((1, 2, 10, 100, rng.randint(1, max_frames)))
    arr = stress_frames(rng, n)
    data = encode_array(arr, protocol)
    if protocol == "hdr-text" and rng.random() < 0.3:
        lines = data.split(b"\r\n")
        for _ in range(rng.randint(1, 4)):
            j = rng.randrange(len(lines))
            lines[j] = _text_line(rng, arr[min(j, n - 1)]).rstrip(b"\r\n")
        data = b"\r\n".join(lines)
    return data


def serial_input(rng: random.Random, max_frames: int = 400) -> bytes:
    protocol = rng.choice(("hdr-bin", "hdr-text"))
    r = rng.random()
    if r < 0.08:
        data = rng.randbytes(rng.randint(0, 4096))
    elif r < 0.12:
        unit = rng.choice((SYNC, b"$HDRG,", b"\xa5", b"\n", b"\x00"))
        data = unit * rng.randint(1, 20_000)
    else:
        data = frame_stream(rng, protocol, max_frames)
        if rng.random() < 0.6:
            extra = (SYNC, b"$HDRG,", b"*", b"\r\n", b",")
            data = mutate_bytes(data, rng, extra)
    return (b"B" if protocol == "hdr-bin" else b"T") + data


def capture_input(rng: random.Random) -> bytes:
    if rng.random() < 0.02:  # a larger capture, now and then (up to ~1 MB)
        return serial_input(rng, max_frames=60_000)
    return serial_input(rng, max_frames=4000)


# -- gpsd ---------------------------------------------------------------------------------------


def _gpsd_templates(rng: random.Random) -> dict[str, Any]:
    t = f"2026-0{rng.randint(1, 9)}-1{rng.randint(0, 9)}T1{rng.randint(0, 9)}:34:56.{rng.randint(0, 999):03d}Z"
    sats = [
        {
            "PRN": rng.randint(1, 200),
            "el": rng.uniform(0, 90),
            "az": rng.uniform(0, 360),
            "ss": rng.uniform(10, 50),
            "used": rng.random() < 0.5,
            "gnssid": 0,
            "svid": 3,
        }
        for _ in range(rng.randint(0, 12))
    ]
    tpv = _gpsd_tpv(rng, t)
    sky = {
        "class": "SKY",
        "device": "/dev/ttyACM0",
        "time": t,
        "hdop": 0.9,
        "pdop": 1.5,
        "nSat": len(sats),
        "uSat": 4,
        "satellites": sats,
    }
    att = {
        "class": "ATT",
        "device": "/dev/ttyACM0",
        "time": t,
        "heading": rng.uniform(0, 360),
        "pitch": 1.0,
        "roll": -2.0,
    }
    return {"TPV": tpv, "SKY": sky, "ATT": att, **_gpsd_fixed(t)}


def _gpsd_tpv(rng: random.Random, t: str) -> dict[str, Any]:
    """A TPV report at time ``t``: a random mode, position, track (compass deg) and speed (m/s)."""
    return {
        "class": "TPV",
        "device": "/dev/ttyACM0",
        "mode": rng.choice((0, 1, 2, 3)),
        "status": 1,
        "time": t,
        "ept": 0.005,
        "lat": rng.uniform(-90, 90),
        "lon": rng.uniform(-180, 180),
        "altMSL": 30.1,
        "alt": 31.2,
        "epx": 3.2,
        "track": rng.uniform(0, 360),
        "speed": rng.uniform(0, 40),
        "climb": 0.1,
        "epd": rng.uniform(0, 30),
        "eps": 0.4,
    }


def _gpsd_fixed(t: str) -> dict[str, Any]:
    """The reports without a random field: VERSION, DEVICES, DEVICE, WATCH, ERROR, PPS."""
    return {
        "VERSION": {
            "class": "VERSION",
            "release": "3.25",
            "rev": "3.25",
            "proto_major": 3,
            "proto_minor": 15,
        },
        "DEVICES": {
            "class": "DEVICES",
            "devices": [
                {
                    "class": "DEVICE",
                    "path": "/dev/ttyACM0",
                    "driver": "u-blox",
                    "activated": t,
                    "bps": 115200,
                }
            ],
        },
        "DEVICE": {"class": "DEVICE", "path": "/dev/ttyACM0", "activated": 0},
        "WATCH": {"class": "WATCH", "enable": True, "json": True},
        "ERROR": {"class": "ERROR", "message": "Unrecognized request"},
        "PPS": {"class": "PPS", "device": "/dev/pps0", "real_sec": 1, "real_nsec": 0},
    }


def gpsd_line(rng: random.Random) -> bytes:
    temps = _gpsd_templates(rng)
    name = rng.choice(
        ("TPV", "TPV", "TPV", "SKY", "ATT", "VERSION", "DEVICES", "DEVICE", "WATCH", "ERROR", "PPS")
    )
    obj = copy.deepcopy(temps[name])
    r = rng.random()
    if r < 0.15:
        return _enc(emit_json(obj, rng))  # valid
    if r < 0.85:
        if rng.random() < 0.15:
            obj["class"] = hostile_value(rng, "json")
        mutate_tree(obj, rng, "json")
        text = emit_json(obj, rng)
        if rng.random() < 0.2:
            return mutate_bytes(_enc(text), rng, (b"\n", b"{", b"}", b'"', b"\\"))
        return _enc(text)
    if r < 0.93:
        return _enc(emit_json(hostile_value(rng, "json"), rng))
    return rng.randbytes(rng.randint(0, 300))


def gpsd_input(rng: random.Random) -> bytes:
    """One to a few lines as a gpsd peer would send them (newline-terminated, mostly)."""
    lines = [gpsd_line(rng) for _ in range(rng.choice((1, 1, 1, 2, 5)))]
    sep = rng.choice((b"\n", b"\n", b"\r\n", b"\r"))
    data = sep.join(lines) + (sep if rng.random() < 0.9 else b"")
    if rng.random() < 0.01:  # a line longer than the client keeps
        data = b'{"class":"TPV","x":"' + b"A" * rng.randint(65_000, 140_000) + b'"}\n' + data
    return data


# -- tail ---------------------------------------------------------------------------------------


@cache
def _hdr_messages() -> tuple[str, ...]:
    """Real per-step messages (JSON lines) of the daemon's pipeline, and a stale report."""
    from hdrd.daemon.pipeline import Pipeline
    from hdrd.daemon.stepper import PipelineConfig
    from hdrd.io.net.formats import format_json

    arr = stress_frames(random.Random(1), 3000)
    arr["t_us"] = np.arange(3000) * 10_000
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.1))))
    msgs = p.feed_array(arr) + p.finish(3)
    msgs.append(p.stale_message(1.7e9, 4.0, 3))
    return tuple(format_json(m).decode() for m in msgs)


def _nmea(rng: random.Random) -> str:
    from hdrd.io.net.formats import nmea_checksum

    kind = rng.choice(("HNHDT", "HNROT", "HNTHS", "HCHDT", "GPRMC", "IIHDT"))
    fields_ = rng.choice((["123.45", "T"], ["-12.3", "A"], ["", "V"], ["359.99", "E"]))
    if rng.random() < 0.7:
        k = rng.randrange(len(fields_))
        v = hostile_value(rng, "json")
        fields_[k] = v.text if isinstance(v, Tok) else str(v)
    body = kind + "," + ",".join(fields_)
    try:
        cs = nmea_checksum(body)
    except UnicodeEncodeError:  # a non-ASCII field: any two hex digits
        cs = f"{rng.getrandbits(8):02X}"
    return rng.choice(("$", "!", "$")) + body + "*" + (cs if rng.random() < 0.9 else "ZZ")


def tail_input(rng: random.Random) -> bytes:
    msgs = _hdr_messages()
    parts: list[bytes] = []
    for _ in range(rng.choice((1, 1, 1, 2, 3, 20))):
        r = rng.random()
        if r < 0.1:
            parts.append(rng.choice(msgs).encode())
        elif r < 0.6:
            obj = json.loads(rng.choice(msgs))
            mutate_tree(obj, rng, "json")
            parts.append(_enc(emit_json(obj, rng)))
        elif r < 0.8:
            parts.append(_enc(_nmea(rng)))
        elif r < 0.9:
            parts.append(_enc(emit_json(hostile_value(rng, "json"), rng)))
        else:
            parts.append(rng.randbytes(rng.randint(0, 200)))
    data = rng.choice((b"\n", b"\r\n")).join(parts)
    if rng.random() < 0.2:
        data = mutate_bytes(data, rng, (b"\n", b"$", b"*", b"{"))
    return data[:MAX_DATAGRAM]


# -- config and bias files ----------------------------------------------------------------------


@cache
def _config_tree() -> dict[str, Any]:
    from hdrd.config import Config

    cfg = Config()
    tree: dict[str, Any] = {}
    for sec in fields(cfg):
        section = getattr(cfg, sec.name)
        d: dict[str, Any] = {}
        for f in fields(section):
            v = getattr(section, f.name)
            if f.name == "params":
                d.update({p.name: getattr(v, p.name) for p in fields(v)})
            elif isinstance(v, tuple):
                d[f.name] = list(v)
            elif hasattr(v, "__dataclass_fields__"):
                continue
            else:
                d[f.name] = v
        tree[sec.name] = d
    return tree


def _valid_config(rng: random.Random) -> dict[str, Any]:
    """Some sections of the defaults, a few values moved within their allowed range."""
    full = copy.deepcopy(_config_tree())
    keep = [s for s in full if rng.random() < 0.5] or [rng.choice(list(full))]
    tree = {s: {k: v for k, v in full[s].items() if rng.random() < 0.6} for s in keep}
    moves = {
        ("hdr", "method"): ("none", "hdr", "hdr+"),
        ("hdr", "c2"): (0.0, 10.0),
        ("hdr", "c1"): (0.0, 1000.0),
        ("hdr", "i_c"): (0.0, 10.0),
        ("hdr", "T"): (0.01, 0.5, 60.0),
        ("hdr", "tau"): (0.0, 3600.0),
        ("sensor", "adc_bits"): (8, 32),
        ("sensor", "vref_v"): (0.01, 100.0),
        ("sensor", "scale_v_per_dps"): (1e-6, 100.0),
        ("calibration", "startup_s"): (1e-9, 600.0),
        ("output", "udp"): (["127.0.0.1:9"], ["[::1]:9", "localhost:9"]),
        ("output", "nmea_talker"): ("II", "HC"),
        ("gpsd", "enabled"): (True, False),
        ("gpsd", "host"): ("127.0.0.1", "::1"),
        ("standstill", "from_gyro"): (True,),
    }
    for (s, k), options in moves.items():
        if s in tree and rng.random() < 0.3:
            tree[s][k] = rng.choice(options)
    return tree


_YAML_SPECIALS = (
    # anchors and aliases: a small "billion laughs" and a recursive alias
    'a: &a ["x","x","x","x","x","x","x","x","x"]\nb: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]\n'
    "c: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]\nd: [*c,*c,*c,*c,*c,*c,*c,*c,*c]\n",
    "hdr: &h\n  c1: 1\n  <<: *h\n",
    "hdr:\n  <<: {c1: 2, c2: 1}\n  i_c: 0.1\n",
    "? [hdr]\n: {c1: 1}\n",
    "--- {}\n--- {}\n",
    "%YAML 1.1\n---\nhdr: {}\n",
    "%TAG ! tag:evil.com,2000:\n---\nhdr: !foo {}\n",
    "!!python/object/apply:os.system ['touch /tmp/hdrd-fuzz-pwned']\n",
    "hdr: !!python/object:hdrd.config.Config {}\n",
    "hdr: !!binary |\n  R0lGODlhDAAMAIQAAP//9/X17unp5WZmZgAAAOfn515eXvPz7Y6OjuDg4J+fn5\n",
    "\t hdr: 1\n",
    "\ufeffhdr: {c1: 1}\n",
    "hdr: {c1: 1, c1: 2}\n",
    "1: 2\nnull: 3\n[1, 2]: 4\n",
)


def config_input(rng: random.Random) -> bytes:
    r = rng.random()
    if r < 0.08:
        return _enc(emit_yaml(_valid_config(rng)))
    if r < 0.78:
        tree = _valid_config(rng)
        if rng.random() < 0.1:
            tree[rng.choice(list(tree))] = hostile_value(rng, "yaml")
        else:
            mutate_tree(tree, rng, "yaml")
        text = _enc(emit_yaml(tree, block_depth=rng.choice((0, 1, 2, 2))))
        if rng.random() < 0.2:
            text = mutate_bytes(text, rng, (b"\n", b": ", b"- ", b"  ", b"&a ", b"*a", b"!!"))
        return text
    if r < 0.86:
        return _enc(rng.choice(_YAML_SPECIALS))
    if r < 0.9:
        return _enc(emit_yaml(hostile_value(rng, "yaml")))
    if r < 0.998:
        return rng.randbytes(rng.randint(0, 2000))
    # near and beyond the 1 MiB limit
    n = rng.choice(((1 << 20) - 10, (1 << 20) + 1, 3 << 20))
    return (b"# " + b"x" * n)[:n] + b"\nhdr: {}\n"


def bias_input(rng: random.Random) -> bytes:
    header = "# hdrd static bias (eps0), written by `hdrd calibrate`; rates in deg/s, + = CCW\n"
    tree: dict[str, Any] = {
        "bias_dps": rng.uniform(-3, 3),
        "std_dps": rng.uniform(0, 0.5),
        "n": rng.randint(1, 10_000),
        "duration_s": rng.uniform(0, 60),
        "temp_c": rng.choice((None, 21.5, -40.0)),
        "time": 1.7e9 + rng.random(),
    }
    r = rng.random()
    if r < 0.1:
        body = emit_yaml(tree)
    elif r < 0.85:
        mutate_tree(tree, rng, "yaml")
        body = emit_yaml(tree, block_depth=rng.choice((0, 1, 1)))
    elif r < 0.9:
        body = rng.choice(_YAML_SPECIALS)
    else:
        body = emit_yaml(hostile_value(rng, "yaml"))
    data = _enc(header + body + ("# end\n" if rng.random() < 0.9 else ""))
    if rng.random() < 0.15:
        data = mutate_bytes(data, rng, (b"\n", b": ", b"# end\n", b"&a ", b"*a"))
    if rng.random() < 0.03:
        data = rng.randbytes(rng.randint(0, 70_000)) + b"\n# end\n"
    return data
