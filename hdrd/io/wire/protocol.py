"""What docs/protocol.md specifies, as data: the ADC's frame formats and the published messages.

Data only, and no numpy (the command line reads the format names for its choices): the codecs
are :mod:`hdrd.io.wire.codec`, :mod:`hdrd.io.wire.parser` and :mod:`hdrd.io.wire.capture`,
the device clock's unwrapping :mod:`hdrd.io.wire.clocks`; the messages are built by
:mod:`hdrd.daemon.pipeline` (and :mod:`hdrd.daemon.aiding`) formatted by
:mod:`hdrd.io.net.formats` and sent by :mod:`hdrd.io.net.publish`.

Units and signs of the message fields: yaw rates deg/s, + = counter-clockwise seen from above
(a left turn); yaw deg CCW since start; heading compass deg, clockwise from north, [0, 360).
"""

from __future__ import annotations

from typing import Any, NamedTuple

__all__ = [
    "ADDED_KEYS",
    "BIAS_SOURCES",
    "BIN_CRC_AT",
    "BIN_FIELDS",
    "BIN_FRAME_LEN",
    "BIN_PAYLOAD_AT",
    "BIN_PAYLOAD_LEN",
    "BREAK_CONFIRM_FRAMES",
    "BREAK_REBASE_FRAMES",
    "CLOCK_WRAP_US",
    "MESSAGE_CLASS",
    "NMEA_TALKER",
    "PROTOCOLS",
    "REBASE_RATIO",
    "RATE_VALID_STATUSES",
    "RESET_THRESHOLD_US",
    "SCHEMA_VERSION",
    "SEQ_CLOCK_RATIO",
    "SEQ_GAP_WINDOW",
    "SEQ_REORDER_WINDOW",
    "STATUSES",
    "STEP_KEYS",
    "SYNC",
    "TEMP_NOT_FITTED",
    "TEXT_MAX_LINE",
    "TEXT_SYNC",
    "WIRE_TYPES",
    "Message",
    "WireField",
    "WireType",
]

# -- the wire: the ADC's frames ("Wire protocol") --------------------------------------------

PROTOCOLS = ("hdr-bin", "hdr-text")
"""The frame formats (``device.protocol``, ``--protocol``)."""
SYNC = b"\xa5\x5a"
"""hdr-bin's first two bytes."""


class WireType(NamedTuple):
    """A field type of the wire, as each reader of the table spells it."""

    size: int
    """bytes"""
    struct: str
    """the :mod:`struct` code (the formats are little-endian)"""
    numpy: str
    """the numpy dtype, little-endian"""
    c: str
    """the C type (firmware/src/wire.h)"""


WIRE_TYPES = {
    "u16": WireType(2, "H", "<u2", "uint16_t"),
    "u32": WireType(4, "I", "<u4", "uint32_t"),
    "i16": WireType(2, "h", "<i2", "int16_t"),
}
"""The field types of hdr-bin, by name."""


class WireField(NamedTuple):
    """One field of hdr-bin's payload."""

    name: str
    """the column of the frames' numpy array and the member of the firmware's struct"""
    type: str
    """a key of :data:`WIRE_TYPES`"""
    meaning: str
    """what it holds, with its unit"""


BIN_FIELDS = (
    WireField("seq", "u16", "frame counter, +1 per frame, wraps at 2**16"),
    WireField("t_us", "u32", "device clock, microseconds, wraps at 2**32"),
    WireField("rate", "u16", "ADC counts of the gyro output (16-bit scale)"),
    WireField("ref", "u16", "ADC counts of the supply monitor, 0 = not wired"),
    WireField("temp", "i16", "board temperature, 0.01 degC, -32768 = not fitted"),
)
"""hdr-bin's payload, in the order sent, each field little-endian: the one table the frame's
struct formats, the numpy dtype of the vectorised decoder and the firmware's C header
(``python -m tools.gen_header``) are made from. A frame is :data:`SYNC`, these fields, and
the CRC-16/CCITT-FALSE of them (u16)."""
BIN_PAYLOAD_AT = len(SYNC)
"""Offset of the payload (the first field) in a frame, bytes."""
BIN_PAYLOAD_LEN = sum(WIRE_TYPES[f.type].size for f in BIN_FIELDS)
"""Bytes of the payload: what the CRC covers."""
BIN_CRC_AT = BIN_PAYLOAD_AT + BIN_PAYLOAD_LEN
"""Offset of the CRC (u16) in a frame, bytes."""
BIN_FRAME_LEN = BIN_CRC_AT + 2
"""Bytes in an hdr-bin frame."""
TEMP_NOT_FITTED = -32768
"""hdr-bin temp value meaning "no temperature sensor fitted" (``Frame.temp_cc is None``)."""
TEXT_SYNC = b"$HDRG,"
"""The start of an hdr-text line."""
TEXT_MAX_LINE = 96
"""Longest hdr-text line the parser waits for, bytes (a valid line has at most 47)."""
SEQ_REORDER_WINDOW = 64
"""A sequence number at most this far behind the last one is a repeat or reordering (the
frame is kept, the counter not moved back); further behind is a device restart."""
CLOCK_WRAP_US = 1 << 32
"""The device clock ``t_us`` is a 32-bit microsecond counter: it wraps every 2**32 us
(71.6 min)."""
RESET_THRESHOLD_US = 1_000_000
"""A device clock that goes back by more than this (1 s) was reset, not merely reordered."""
SEQ_GAP_WINDOW = 64
"""A sequence number at most this far ahead of the last one kept, its clock agreeing, is a gap
(the frames between lost); further ahead, a break in the sequence, believed only once the
frames after it continue it (a random frame that passed the CRC is not a gap)."""
SEQ_CLOCK_RATIO = 2
"""A frame's device time per sequence step may differ from the interval before it by at most
this factor (docs/protocol.md, "Sequence and clock"); beyond, its clock disagrees with its
sequence number."""
BREAK_CONFIRM_FRAMES = 3
"""After a break in the sequence or the clock (a device restart, a jump), the frames are believed
once this many in a row continue one another at the sample interval agreed on before it."""
BREAK_REBASE_FRAMES = 16
"""... or once this many in a row continue one another at a new interval within a factor
:data:`REBASE_RATIO` of it (the interval agreed on was off); a clock 100x slow or fast is never
taken."""
REBASE_RATIO = 4
"""How far from the interval agreed on a new one may be, to be taken after BREAK_REBASE_FRAMES."""

# -- published messages ("Published messages") -------------------------------------------------

MESSAGE_CLASS = "HDR"
"""The ``"class"`` of a per-step message (gpsd style: every object names its class)."""
SCHEMA_VERSION = 1
"""The ``"v"`` of a per-step message; raised only for an incompatible change."""
Message = dict[str, Any]
"""One published message: the keys below, in that order; an unknown value is absent."""
STEP_KEYS = (
    "class",
    "v",
    "time",
    "t",
    "step",
    "omega_raw",
    "omega",
    "yaw",
    "heading",
    "I",
    "W",
    "R",
    "r",
    "bias",
    "samples",
    "bad_frames",
    "status",
    "temp",
)
"""The keys of a step's message, in the order they are sent (the docs' table)."""
ADDED_KEYS = (
    "zupt",
    "model",
    "bias_sd",
    "motion_offset",
    "outage_policy",
    "outage_trials",
    "heading_sd",
    "gap_s",
    "saturated",
    "supply_faults",
    "supply_v",
    "stale_s",
    "mode",
    "heading_offset",
    "gps_course",
    "gps_speed",
    "gps_age_s",
    "bias_source",
    "calib_age_s",
    "frames",
    "reconnects",
)
"""Keys added without changing ``v`` (docs: "known additions"); readers ignore keys they do
not know."""
BIAS_SOURCES = ("calibration", "stops", "driving", "gps")
"""The ``bias_source`` values hdrd sends: what last changed the published bias."""
STATUSES = ("ok", "turning", "standstill", "calibrating", "stale", "supply_fault", "saturated")
"""The ``status`` values hdrd sends; a reader treats any other as "rate not trusted"."""
RATE_VALID_STATUSES = frozenset({"ok", "turning", "standstill", "aided", "dead-reckoning"})
"""Statuses of a live step, whose rate and heading are current: $HNHDT is sent, $HNROT says
A (valid) and $HNTHS A or E. In any other status (``stale``: no data, the heading held;
``supply_fault``, ``saturated``: no usable sample in the step, the heading held;
``calibrating``; a status this version does not know) no $HNHDT is sent and $HNROT and
$HNTHS say V. ``standstill`` (HDR+'s zero-rate update) is valid: the rate is known to be 0."""
NMEA_TALKER = "HN"
"""NMEA 0183 talker of the sentences sent (``output.nmea_talker``): heading, non-north-seeking
gyro."""
