"""Stage 'apply': a calibrated copy of a session (/derived/accel_calibrated, /derived/mag_calibrated),
optionally a ROS 2 bag, refusing (or warning about) a calibration of another device."""

from __future__ import annotations

import itertools
import os
import warnings
from pathlib import Path

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration, as_calibration
from accellog.calibrate.mag.magnetometer import MagCalibration
from accellog.core.errors import InputError
from accellog.core.jsonio import dumps
from accellog.core.session import Session
from accellog.store.atomic import AtomicOutput
from accellog.store.layout import NS_PER_S
from accellog.store.reader import read_session
from accellog.store.source import announce
from accellog.store.writer import DEFAULT_COMPRESSION, SessionWriter, check_compression


def _write_mag_calibrated(w, t_s: np.ndarray, mag_uT: np.ndarray, mc: MagCalibration) -> None:
    """/derived/mag_calibrated: A (m - h) in uT, AK8963 axes (accellog.calibrate.mag.magnetometer);
    t_s (M,) s and mag_uT (M, 3): the session's magnetometer samples."""
    t_ns = np.round(t_s * NS_PER_S).astype(np.int64)
    w.write_vector3("mag_calibrated", t_ns, mc.correct(mag_uT), "uT", frame="AK8963")


class OtherDeviceWarning(UserWarning):
    """A calibration of another device was applied (run_apply(other_device='warn'))."""


OTHER_DEVICE_MODES = ("refuse", "warn")


def check_device(session: Session, cal: Calibration, other_device: str = "refuse", where: str = "") -> str:
    """'' when the calibration's device key matches the session's (or either is unknown); else the
    one-line mismatch, raised as InputError ('refuse') or issued as OtherDeviceWarning ('warn')."""
    if other_device not in OTHER_DEVICE_MODES:
        raise InputError(f"other_device={other_device!r}: use 'refuse' or 'warn'")
    diff = cal.device_conflicts(session.meta.device)
    if not diff:
        return ""
    cal_id = cal.device.id or "?"
    msg = f"calibration is for device {cal_id}, session is from {session.meta.device.id} ({'; '.join(diff)})"
    if other_device == "refuse":
        raise InputError(msg + ": use --other-device warn to apply it anyway", where=where)
    warnings.warn(msg, OtherDeviceWarning, stacklevel=2)
    return msg


def run_apply(
    session_path: str | os.PathLike,
    cal: Calibration | str | os.PathLike,
    out: str | os.PathLike,
    *,
    ros2: str | os.PathLike | None = None,
    other_device: str = "refuse",
    compression: str = DEFAULT_COMPRESSION,
    ros2_topic: str | None = None,
    ros2_frame_id: str | None = None,
    progress=None,
) -> Path:
    """Copy an MCAP session to `out`, adding /derived/accel_calibrated (calibrated units, g) and
    /derived/accel_calibrated_mps2 (and /derived/mag_calibrated, uT, when the calibration has a magnetometer
    section and the session magnetometer samples), and attaching the calibration JSON. Atomic (temp + rename).
    ros2: also write the calibrated data as a ROS 2 bag (accellog.flows.ros2_out.write_ros2) on
    ros2_topic with ros2_frame_id (default: the input bag's); progress(done, total) per ROS 2 chunk.
    A calibration of another device (device keys differ) is refused, or warned about with
    other_device='warn' (see check_device). compression: of the copy's MCAP chunks."""

    check_compression(compression)
    src = Path(session_path)
    if src.suffix.lower() != ".mcap":
        raise InputError(
            "apply copies an MCAP session: convert other files with `accellog import` first", where=str(src)
        )
    s = read_session(src)
    announce(s)  # a truncated input: what was recovered (a note on stderr)
    c = as_calibration(cal)
    check_device(s, c, other_device, where=str(src))
    f = c.correct(s)
    out = Path(out)
    ao = AtomicOutput(out, inputs=(src, getattr(c, "path", None)))
    tmp = ao.begin()
    t_ns = np.round(s.t_s * NS_PER_S).astype(np.int64)
    si = np.asarray(s.sample_index, np.int64)
    cuts = np.flatnonzero(np.diff(si) != 1) + 1
    bounds = np.unique(np.concatenate([[0], cuts, np.arange(0, s.n, 500), [s.n]]))
    try:
        with SessionWriter(tmp, s.meta, compression=compression) as w:
            for a, b in itertools.pairwise(bounds):  # batches of <= 500 samples
                w.write_imu(
                    int(si[a]),
                    t_ns[a:b],
                    accel_counts=None if s.accel_counts is None else s.accel_counts[a:b],
                    gyro_counts=None if s.gyro_counts is None else s.gyro_counts[a:b],
                    temp_counts=None if s.temp_counts is None else s.temp_counts[a:b],
                    host_time_ns=0 if s.host_time_s is None else round(s.host_time_s[b - 1] * NS_PER_S),
                    accel_g=s.accel_g[a:b] if s.accel_counts is None or not s.meta.accel_lsb_per_g else None,
                    gyro_dps=None if s.gyro_dps is None or s.gyro_counts is not None else s.gyro_dps[a:b],
                    temp_degC=None if s.temp_degC is None or s.temp_counts is not None else s.temp_degC[a:b],
                )
                w.write_vector3("accel_calibrated", t_ns[a:b], f[a:b], "g")
                w.write_vector3("accel_calibrated_mps2", t_ns[a:b], f[a:b] * c.mps2_per_unit, "m/s^2")
            if s.mag_t_s is not None and s.mag_t_s.shape[0]:
                w.write_mag(
                    np.round(s.mag_t_s * NS_PER_S).astype(np.int64),
                    mag_counts=s.mag_counts,
                    st2=s.mag_st2,
                    mag_uT=s.mag_uT,
                    first_index=0,
                )
                if c.magnetometer is not None and s.mag_uT is not None and s.mag_t_s is not None:
                    _write_mag_calibrated(w, s.mag_t_s, s.mag_uT, c.magnetometer)
            for p in s.poses:
                w.write_pose(p)
            for e in s.events:
                w.write_event(e)
            if s.truth is not None:
                w.write_truth(s.truth)
            w.attach("calibration/accel.json", "application/json", dumps(c.to_dict()).encode())
        if ros2 is not None:  # before the copy is renamed into place: a bag that fails leaves neither
            from accellog.flows.ros2_out import write_ros2

            write_ros2(s, c, Path(ros2), topic=ros2_topic, frame_id=ros2_frame_id, progress=progress)
    except BaseException:
        ao.abort()
        raise
    ao.commit()
    return out
