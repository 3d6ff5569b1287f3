"""The core: what hdrd computes, pure (no port, socket, file or clock).

The drift reducers (:mod:`~hdrd.core.hdr`, the paper's HDR; :mod:`~hdrd.core.hdrplus`, HDR+,
one estimator of heading and bias over a bank of Kalman filters :mod:`~hdrd.core.kalman`, its
settings :mod:`~hdrd.core.plusparams`, its self-check :mod:`~hdrd.core.selfcheck` and stop
detection :mod:`~hdrd.core.standstill`), the method registry (:mod:`~hdrd.core.methods`) and what a step
sees (:mod:`~hdrd.core.steps`); counts to deg/s (:mod:`~hdrd.core.sensor`), block means
(:mod:`~hdrd.core.resample`), the static bias and the standstill test
(:mod:`~hdrd.core.calibrate`); the gyro's error model (:mod:`~hdrd.core.gyronoise`), the grade
table (:mod:`~hdrd.core.grades`), the Allan deviation (:mod:`~hdrd.core.allan`), angles
(:mod:`~hdrd.core.angles`) and the one rate limit of logged events (:mod:`~hdrd.core.throttle`).
It imports nothing of hdrd's other layers (tests/test_layout.py).
"""
