"""accellog: record, calibrate and inspect cheap MEMS accelerometers (MPU-9250).

Data flows one way: device -> recorder -> MCAP -> stages -> calibration / reports / .rrd.
See docs/architecture.md for the module map.
"""

__version__ = "0.1.0"
