"""The daemon: ``hdrd run``'s loop (:mod:`~hdrd.daemon.run`), which hands what it publishes to
its listeners (:mod:`~hdrd.daemon.listeners`), and what it wires.

The pipeline from frames to messages (:mod:`~hdrd.daemon.pipeline`, pure: replay and evaluate
run it too), paced reads (:mod:`~hdrd.daemon.pacing`), clocks (:mod:`~hdrd.io.wire.clocks`),
signals, systemd notification and logging (:mod:`~hdrd.daemon.signals`,
:mod:`~hdrd.daemon.sdnotify`, :mod:`~hdrd.io.logs`), and GPS aiding
(:mod:`~hdrd.daemon.aiding`, pure; :mod:`~hdrd.daemon.gpslink`, its wiring to gpsd).
"""
