"""Input and output: bytes, files and sockets in and out, on top of the core.

The wire format (:mod:`~hdrd.io.protocol`), frames and captures (:mod:`~hdrd.io.codec`,
:mod:`~hdrd.io.tracker`, :mod:`~hdrd.io.parser`, :mod:`~hdrd.io.capture`), the serial port and the sources built on it
(:mod:`~hdrd.io.serialport`, :mod:`~hdrd.io.sources`), the outputs (:mod:`~hdrd.io.publish`,
:mod:`~hdrd.io.display`), their readers (:mod:`~hdrd.io.datagrams`: validation and ``hdrd
tail``'s table; :mod:`~hdrd.io.webstate`, :mod:`~hdrd.io.webserver`: ``hdrd web``), the gpsd client (:mod:`~hdrd.io.gpsd`), drive logs
(:mod:`~hdrd.io.drivelog`, :mod:`~hdrd.io.parquetlog`, :mod:`~hdrd.io.drivefiles`,
:mod:`~hdrd.io.csvimport`), the bias file (:mod:`~hdrd.io.biasfile`) and bounded, atomic file
access (:mod:`~hdrd.io.files`).
"""
