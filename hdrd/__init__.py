"""hdrd: Heuristic Drift Reduction for a vehicle yaw-rate gyro.

Borenstein & Ojeda, "Heuristic Drift Reduction for Gyroscopes in Vehicle Tracking
Applications", Proc. SPIE 7305, 2009. Conventions everywhere in this package: yaw rate in
deg/s, positive counter-clockwise seen from above (a left turn); yaw in degrees, CCW;
heading in compass degrees (clockwise from north, [0, 360)).
"""

__version__ = "0.1.0"
