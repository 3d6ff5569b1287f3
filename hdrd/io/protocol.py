"""What docs/protocol.md specifies, as data: the ADC's frame formats and the published messages.

No code and no numpy here (the command line reads the format names for its choices): the
codecs are in :mod:`hdrd.io.frames` and :mod:`hdrd.io.capture`, the device clock's unwrapping in
:mod:`hdrd.io.clocks`, the messages are built by :mod:`hdrd.daemon.pipeline` (and :mod:`hdrd.daemon.aiding`)
and sent by :mod:`hdrd.io.publish`.

Units and signs of the message fields: yaw rates deg/s, + = counter-clockwise seen from above
(a left turn); yaw deg CCW since start; heading compass deg, clockwise from north, [0, 360).
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "ADDED_KEYS",
    "BIAS_SOURCES",
    "BIN_FRAME_LEN",
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
    "Message",
]

# -- the wire: the ADC's frames ("Wire protocol") --------------------------------------------

PROTOCOLS = ("hdr-bin", "hdr-text")
"""The frame formats (``device.protocol``, ``--protocol``)."""
SYNC = b"\xa5\x5a"
"""hdr-bin's first two bytes."""
BIN_FRAME_LEN = 16
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
