"""accellog: record, calibrate and inspect cheap MEMS accelerometers (MPU-9250).

Data flows one way: device -> recorder -> MCAP -> stages -> calibration / reports / .rrd.
See docs/architecture.md for the layers.
"""

from accellog.core.version import __version__

__all__ = ["__version__"]
