"""The wire: the ADC's frames from the serial port to numbers.

The frame formats and the published messages' schema as data (:mod:`~hdrd.io.wire.protocol`),
one frame <-> its bytes (:mod:`~hdrd.io.wire.codec`), which frames are new
(:mod:`~hdrd.io.wire.tracker`), bytes -> frames live (:mod:`~hdrd.io.wire.parser`) and for a
whole capture (:mod:`~hdrd.io.wire.capture`), host and device clocks
(:mod:`~hdrd.io.wire.clocks`), the serial port and the sources built on it
(:mod:`~hdrd.io.wire.serialport`, :mod:`~hdrd.io.wire.sources`), a port's bytes to a capture
(:mod:`~hdrd.io.wire.record`).
"""
