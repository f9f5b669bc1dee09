"""Importers: other tools' recordings -> Session (-> MCAP with ``accellog.store.writer.write_session``).

One module per format: capstone, imucal, csv (any logger's CSV: csv_options, csv_blocks, csv_poses),
ros2 (rosbag2 bags via rosbags), ulog (PX4 ULog via pyulog) and dataflash (ArduPilot DataFlash via pymavlink),
the last two sharing autopilot_log. m/s^2 inputs are converted with g0 = 9.80665
(accel_g = a_mps2 / 9.80665); the source unit and the conversion are recorded in meta.extra, so nothing
is silently altered. Every bad input raises a one-line InputError naming the file and line.
"""

from __future__ import annotations

from importlib import import_module
from pathlib import Path
from typing import TYPE_CHECKING, Any

from accellog.core.errors import InputError

if TYPE_CHECKING:
    from accellog.core.session import Session
    from accellog.store.importers.capstone import PoseTable, import_capstone, load_capstone_pose_table
    from accellog.store.importers.csv import CsvOptions, import_csv, import_csv_to_mcap
    from accellog.store.importers.dataflash import import_dataflash
    from accellog.store.importers.imucal import import_imucal
    from accellog.store.importers.ros2 import import_ros2
    from accellog.store.importers.ulog import import_ulog

# each name loaded from its module on first use: a sibling module (ros2.is_ros2_bag, asked by every
# streamed command) is reached without loading the CSV/capstone/imucal importers
_WHERE = {
    "CsvOptions": "csv",
    "import_csv": "csv",
    "import_csv_to_mcap": "csv",
    "PoseTable": "capstone",
    "import_capstone": "capstone",
    "load_capstone_pose_table": "capstone",
    "import_imucal": "imucal",
    "import_ros2": "ros2",
    "import_ulog": "ulog",
    "import_dataflash": "dataflash",
}

__all__ = [
    "IMPORTERS",
    "CsvOptions",
    "PoseTable",
    "import_capstone",
    "import_csv",
    "import_csv_to_mcap",
    "import_dataflash",
    "import_file",
    "import_imucal",
    "import_ros2",
    "import_ulog",
    "load_capstone_pose_table",
]


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


IMPORTERS: dict[str, str] = {
    "capstone": "import_capstone",
    "imucal": "import_imucal",
    "csv": "import_csv",
    "ros2": "import_ros2",  # a bag's only sensor_msgs/Imu topic unless topic= is given
    "ulog": "import_ulog",  # PX4: sensor_accel instance imu= (0)
    "dataflash": "import_dataflash",  # ArduPilot: IMU instance imu= (0)
}
"""The importer of each kind (a function of the path in the module of that name): a new format is
one entry; its module (and its library) is loaded when a file of its kind is imported."""


def import_file(kind: str, path: str | Path, **options) -> Session:
    """The Session of a file of kind ``kind`` (IMPORTERS; options passed on)."""
    if kind not in IMPORTERS:
        raise InputError(f"unknown import kind {kind!r}: use {', '.join(IMPORTERS)}")
    return getattr(import_module(f"{__name__}.{kind}"), IMPORTERS[kind])(path, **options)
