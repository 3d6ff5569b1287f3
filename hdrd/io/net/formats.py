"""The published formats: a message as one line of compact JSON (:func:`format_json`) and as
NMEA 0183 sentences (:func:`nmea_sentences`: $HNHDT, $HNROT, optional $HNTHS), and an NMEA
sentence read back (:func:`parse_nmea`). Pure: the sinks that send them are
:mod:`hdrd.io.net.publish`'s.

Yaw rates are deg/s, positive counter-clockwise seen from above (a left turn); heading is
compass degrees, clockwise from north, in [0, 360). A value that is not known is absent.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from hdrd.core.angles import compass
from hdrd.io.wire.protocol import NMEA_TALKER, RATE_VALID_STATUSES

__all__ = [
    "format_json",
    "heading_field",
    "nmea_checksum",
    "nmea_sentence",
    "nmea_sentences",
    "parse_nmea",
]


# -- JSON ---------------------------------------------------------------------------------

_DROP = object()


def _clean(value: Any) -> Any:
    """A JSON-safe copy of *value*, or ``_DROP`` when it has no valid JSON form.

    None, NaN and +-inf are dropped (an unknown value is absent, never null); a dict loses
    such keys; a list holding one is dropped whole (positions would shift otherwise).
    numpy scalars become Python numbers.
    """
    if value is None:
        return _DROP
    if isinstance(value, (str, bool, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else _DROP
    if isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            c = _clean(v)
            if c is not _DROP:
                out[str(k)] = c
        return out
    if isinstance(value, (list, tuple)):
        items = [_clean(v) for v in value]
        return _DROP if any(c is _DROP for c in items) else items
    item = getattr(value, "item", None)  # numpy scalar (float32, int64, bool_)
    if callable(item):
        try:
            return _clean(item())
        except (TypeError, ValueError):
            return _DROP
    return _DROP


_ENCODE = json.JSONEncoder(separators=(",", ":"), ensure_ascii=False, allow_nan=False).encode
"""Compact JSON, made once (json.dumps with arguments builds an encoder per call)."""


def _plain(msg: Mapping[str, Any]) -> bool:
    """True if ``msg`` is a flat dict of str keys and str, int, bool or finite float values
    (what the pipeline builds): then ``_clean(msg)`` would be an equal copy of it."""
    if type(msg) is not dict:
        return False
    for k, v in msg.items():
        t = type(v)
        if type(k) is not str or not (
            t is str or t is int or t is bool or (t is float and math.isfinite(v))
        ):
            return False
    return True


def format_json(msg: Mapping[str, Any]) -> bytes:
    """One message -> one line of compact JSON, UTF-8, ending in ``\\n``.

    Keys keep the order given. Keys whose value is None, NaN or infinite are left out, so
    the output is always valid JSON (RFC 8259 has no NaN) and never says null.
    """
    if _plain(msg):
        # Fast path (hdrd replay writes thousands of lines): nothing to clean, the same text.
        return _ENCODE(msg).encode("utf-8", "replace") + b"\n"
    return _format_clean(msg)


def _format_clean(msg: Mapping[str, Any]) -> bytes:
    """:func:`format_json` for any mapping: values cleaned by :func:`_clean` first."""
    clean = _clean(msg)
    if clean is _DROP or not isinstance(clean, dict):
        raise TypeError(f"a message must be a mapping, not {type(msg).__name__}")
    text = _ENCODE(clean)
    # json escapes control characters, so the line has exactly one \n: the terminator.
    return text.encode("utf-8", "replace") + b"\n"


# -- NMEA 0183 ----------------------------------------------------------------------------


def nmea_checksum(body: str) -> str:
    """NMEA 0183 checksum of the characters between ``$`` and ``*``: XOR of their bytes,
    as two uppercase hex digits."""
    x = 0
    for b in body.encode("ascii"):
        x ^= b
    return f"{x:02X}"


def nmea_sentence(body: str) -> bytes:
    """``body`` (without ``$`` and ``*hh``) -> ``$body*hh\\r\\n``."""
    return f"${body}*{nmea_checksum(body)}\r\n".encode("ascii")


def _finite(msg: Mapping[str, Any], key: str) -> float | None:
    v = msg.get(key)
    if isinstance(v, bool) or v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def heading_field(heading: float) -> str:
    """A compass heading (deg) as NMEA writes it: 2 decimals, in [0, 360)."""
    # Wrap, round, wrap again: 359.996 rounds to 360.00, outside [0, 360).
    return f"{compass(round(compass(heading), 2)):.2f}"


def nmea_sentences(
    msg: Mapping[str, Any], ths: bool = False, talker: str = NMEA_TALKER
) -> list[bytes]:
    """One message -> NMEA 0183 sentences, each ``$...*hh\\r\\n``.

    - ``$HNHDT,<heading>,T``: heading, degrees true (compass, 2 decimals). Sent only when
      the heading is known and current (status in :data:`RATE_VALID_STATUSES`): HDT has no
      validity flag, so a receiver takes every HDT as a fresh heading, and a heading held
      while the gyro is silent (``stale``) must not look like one.
    - ``$HNROT,<rate>,A|V``: rate of turn in deg/min, negative = turning to port (left).
      Our omega is + CCW = left turn, so ROT = -omega * 60 (1 decimal). A when the status is
      one of :data:`RATE_VALID_STATUSES`, V (invalid) otherwise or when omega is unknown.
    - with *ths*: ``$HNTHS,<heading>,A|E|V``: true heading with mode A (autonomous) while
      GPS-aided (``"mode": "aided"``, :mod:`hdrd.daemon.aiding`), E (estimated, dead reckoning)
      otherwise, V when the status is not valid (the held heading while ``stale``).

    *talker*: the two-letter talker ID (default HN, non-north-seeking gyro). gpsd 3.22
    drops sentences from talkers its packet lexer does not know, HN among them
    (docs/protocol.md, "NMEA 0183 and gpsd").
    """
    out: list[bytes] = []
    status = msg.get("status")
    valid = status in RATE_VALID_STATUSES
    heading = _finite(msg, "heading")
    if heading is not None and valid:
        out.append(nmea_sentence(f"{talker}HDT,{heading_field(heading)},T"))
    omega = _finite(msg, "omega")
    if omega is None:
        out.append(nmea_sentence(f"{talker}ROT,,V"))
    else:
        rot = round(-omega * 60.0, 1) + 0.0  # + 0.0 turns -0.0 into 0.0
        out.append(nmea_sentence(f"{talker}ROT,{rot:.1f},{'A' if valid else 'V'}"))
    if ths and heading is not None:
        mode = ("A" if msg.get("mode") == "aided" else "E") if valid else "V"
        out.append(nmea_sentence(f"{talker}THS,{heading_field(heading)},{mode}"))
    return out


def parse_nmea(line: bytes | str) -> tuple[str, list[str]]:
    """``$TTSSS,f1,f2*hh`` -> (``"TTSSS"``, [``"f1"``, ``"f2"``]); checks the checksum.

    Raises ValueError with the reason for anything else (no ``$``/``!``, no ``*hh``,
    a wrong checksum, non-ASCII bytes, control characters: NMEA 0183 is printable ASCII).
    """
    text = line.decode("ascii") if isinstance(line, bytes) else line
    text = text.strip("\r\n")
    if not text or text[0] not in "$!":
        raise ValueError("an NMEA sentence starts with $ or !")
    if not all(" " <= c <= "~" for c in text):
        raise ValueError("an NMEA sentence is printable ASCII")
    body, star, cs = text[1:].rpartition("*")
    if not star or len(cs) != 2:
        raise ValueError("no *hh checksum")
    if cs.upper() != nmea_checksum(body):
        raise ValueError(f"checksum {cs}, computed {nmea_checksum(body)}")
    fields_ = body.split(",")
    return fields_[0], fields_[1:]


# -- UDP ----------------------------------------------------------------------------------

# Linux: IP_RECVERR / IPV6_RECVERR queue ICMP errors (port unreachable, ...) on the socket's
# error queue together with the destination that caused them. Without it Linux reports no
