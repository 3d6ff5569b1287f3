"""The network's outputs and inputs: the published messages sent and read back, and gpsd.

The outputs (:mod:`~hdrd.io.net.publish`: UDP JSON, NMEA, stdout) and their formats
(:mod:`~hdrd.io.net.formats`: a JSON line, NMEA sentences), numbers rounded for a
terminal (:mod:`~hdrd.io.net.display`), the readers of what the daemon publishes
(:mod:`~hdrd.io.net.datagrams`: validation and ``hdrd tail``'s table), gpsd's reports
(:mod:`~hdrd.io.net.gpsdjson`) and its client (:mod:`~hdrd.io.net.gpsd`), and who holds a UDP port (:mod:`~hdrd.io.net.portowner`).
"""
