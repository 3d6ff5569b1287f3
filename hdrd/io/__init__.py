"""Input and output: bytes, files and sockets in and out, on top of the core.

Four rooms, each importing only the rooms before it (tests/test_layout.py): the wire
(:mod:`hdrd.io.wire`: frames from the serial port), files (:mod:`hdrd.io.files.access`: file access,
drive logs, the unit's files), the network (:mod:`hdrd.io.net`: the published messages out and
back, gpsd) and the web page (:mod:`hdrd.io.web`). Beside them, two modules every room may use:
logging (:mod:`~hdrd.io.logs`) and host names looked up without waiting
(:mod:`~hdrd.io.resolve`).
"""
