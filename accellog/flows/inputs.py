"""Any supported input file -> Session or ObsTable (what every batch stage reads first).

.mcap (accellog, salvaged when truncated), ROS 2 bags (their only sensor_msgs/Imu topic), capstone and
imucal CSV, any logger's CSV -> Session; capstone pose tables and observation JSON -> ObsTable.
"""

from __future__ import annotations

import os
from pathlib import Path

from accellog.calibrate.calfile.calibration import read_json
from accellog.calibrate.observe.label_check import check_timestamps
from accellog.calibrate.observe.obs_file import OBS_FORMAT, obs_from_dict
from accellog.calibrate.observe.segment import obs_from_pose_means
from accellog.core.errors import InputError
from accellog.core.session import ObsTable, Session
from accellog.store import importers
from accellog.store.importers.csv_checks import UnitsError
from accellog.store.importers.ros2 import import_ros2, is_ros2_bag
from accellog.store.importers.text import check_text_file
from accellog.store.reader import read_session
from accellog.store.recovery import announce


def load_input(
    path: str | os.PathLike, *, n_per_pose: int | None = None, check_times: bool = True
) -> Session | ObsTable:
    """Read any supported input: a Session (accellog MCAP, a ROS 2 bag, CSV), or an ObsTable for pose
    tables / observation files. A degenerate session (< 2 samples, zero duration, duplicated or
    decreasing times) is refused unless check_times=False (tools that report such defects, e.g. doctor)."""
    data = _read_input(path, n_per_pose=n_per_pose)
    if check_times and isinstance(data, Session):
        check_timestamps(data, where=str(path))
    return data


def _read_input(path: str | os.PathLike, *, n_per_pose: int | None = None) -> Session | ObsTable:
    p = Path(path)
    if not p.exists():
        raise InputError("no such file", where=str(p))
    suffix = p.suffix.lower()
    if is_ros2_bag(p):  # a ROS 2 bag's only sensor_msgs/Imu topic (import ros2 for the options)
        return import_ros2(p)
    if suffix == ".mcap":
        session = read_session(p)
        announce(session)  # a truncated file: say what was recovered (stderr)
        return session
    if suffix == ".json":
        d = read_json(p)
        if isinstance(d, dict) and d.get("format") == OBS_FORMAT:
            return obs_from_dict(d, where=str(p))
        raise InputError(
            f"JSON input must be an observations file ('{OBS_FORMAT}', written by `accellog segment -o`)",
            where=str(p),
        )
    if suffix in (".csv", ".txt"):
        check_text_file(p)  # not a CSV at all (binary, zero-filled): refused within the first KiB
        try:
            with open(p, encoding="utf-8", errors="replace") as f:
                first = f.readline(65536).replace(" ", "").lower()
        except OSError as exc:
            raise InputError(f"cannot read: {exc.strerror}", where=str(p)) from None
        if first.startswith("x_true"):
            pt = importers.load_capstone_pose_table(p)
            if n_per_pose is None:
                n_per_pose = 5400  # 30 s at ~180 Hz: the capstone protocol (the table has no count)
            return obs_from_pose_means(
                pt.truth_g, pt.mean_g, pt.std_g, n_per_pose, names=pt.names, session=str(p)
            )
        if first.startswith("part,samples") or first.startswith("n_samples"):
            return importers.import_imucal(p)
        if "," not in first or first.startswith("acceleration") or not first[:1].isalpha():
            return importers.import_capstone(p)
        try:
            return importers.import_csv(p)
        except UnitsError as exc:  # its fix names import csv's options: say where they go
            raise UnitsError(
                f"{exc} (an option of `accellog import csv FILE -o S.mcap`: import the file, then give S.mcap)"
            ) from None
    raise InputError(
        f"unknown input type {suffix or '(no suffix)'!r}: give .mcap, .csv or observations .json",
        where=str(p),
    )
