"""A recorded MCAP session as the fit and segment stages see it, read chunk by chunk: metadata, pose
labels and the observation table (``calibrate.stream_segment.stream_observations``), never the
whole sample arrays; the gyro calibration streams the file again (``calibrate.stream_gyro``).
Memory is bounded by one chunk group plus the longest hold, whatever the session length.

``can_stream`` says which inputs take this path: finished accellog MCAP files (a truncated file is
recovered by ``read_session``, which says what it kept; ROS 2 bags and CSV are imported whole).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

from accellog.calibrate.gyro.calibrate import gyro_full_scale_dps
from accellog.calibrate.gyro.model import GyroCalibration
from accellog.calibrate.gyro.stream import FirstPass, first_pass, stream_calibrate_gyro
from accellog.calibrate.observe.segment import PoseStats
from accellog.calibrate.observe.stream_segment import (
    TimestampCheck,
    stream_check_timestamps,
    stream_observations,
)
from accellog.core.errors import AccellogError, DataIntegrityWarning, InputError, ModelError
from accellog.core.notices import note
from accellog.core.session import ObsTable, PoseLabel, SessionMeta
from accellog.store.stream import HostClock, read_host_clock, read_labels

_MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass
class StreamedSession:
    """Labels and observations of a session file (module doc); ``path`` is the file."""

    meta: SessionMeta
    poses: list[PoseLabel]
    obs: ObsTable | None
    path: str
    stats: list[PoseStats] | None = None
    """Per-hold statistics (segment.pose_stats), when asked for."""
    host_clock: tuple | None = None
    """(sensor, host) times for calibrate.clock.clock_from_host_time (store.stream.read_host_clock)."""
    gyro_first: FirstPass | None = None
    """The gyro calibration's first pass, taken in the observation pass (open_streamed(gyro=True))."""

    def gyro_calibration(self) -> GyroCalibration | None:
        """Gyro calibration from the holds and the moves between them, as
        flows.stages._gyro_calibration on the whole session; None without gyro data or holds."""
        if len(self.poses) < 2:
            return None
        try:
            first, self.gyro_first = self.gyro_first, None
            cal = stream_calibrate_gyro(
                self.path, self.poses, full_scale_dps=gyro_full_scale_dps(self.meta), first=first
            )
        except ModelError as exc:  # e.g. a scale fit that did not converge: said, not silent
            note(f"gyro not calibrated: {exc}")
            return None
        except AccellogError:
            return None
        return cal


def _observe_checked(p: Path, window_s: float, trim_s: float, held: list | None, clock: HostClock | None,
                     gyro: bool = False):  # fmt: skip
    """(stream_observations, read_labels, the gyro's first pass or None) of p with the time-stamp
    checks of load_input taken in the same pass (TimestampCheck): one decompression pass fewer for a
    good file (open_streamed redoes a file that fails in two passes, so the refusals and their order
    are those of the two passes); clock, when given, is fed every block too (read_host_clock in the
    same pass), and so is the gyro calibration's first pass when gyro (a pass fewer for the fit; any
    error there drops it: the gyro calibration then makes that pass itself and says what it says)."""
    check = TimestampCheck()
    labels = read_labels(p)
    first = [_gyro_first(labels) if gyro else None]

    def on_block(b) -> None:
        check.add(b.t_s)
        if clock is not None:
            clock.add(b)
        if first[0] is not None:
            try:
                first[0].add(b)
            except Exception:
                first[0] = None

    obs = stream_observations(
        p,
        window_s=window_s,
        trim_s=trim_s,
        stats_out=held,
        labels=labels,
        on_block=on_block,
    )
    check.finish(p)
    return obs, labels, first[0]


def _gyro_first(labels) -> FirstPass | None:
    """An unfed first pass of StreamedSession.gyro_calibration's stream_calibrate_gyro, or None."""
    meta, poses, _events = labels
    if len(poses) < 2:
        return None
    try:
        return first_pass(poses, full_scale_dps=gyro_full_scale_dps(meta))
    except AccellogError:
        return None


def can_stream(path: str | os.PathLike) -> bool:
    """True for a finished accellog MCAP file (not a ROS 2 bag; ends with the MCAP magic)."""
    from accellog.store.importers.ros2 import is_ros2_bag

    p = Path(path)
    if p.suffix.lower() != ".mcap" or not p.is_file() or is_ros2_bag(p):
        return False
    try:
        with open(p, "rb") as f:
            if f.seek(0, os.SEEK_END) < 2 * len(_MCAP_MAGIC):
                return False
            f.seek(-len(_MCAP_MAGIC), os.SEEK_END)
            return f.read() == _MCAP_MAGIC
    except OSError:
        return False


def open_labelled(
    path: str | os.PathLike, *, window_s: float = 2.0, host: bool = False
) -> StreamedSession | None:
    """open_streamed for a labelled session (plus its host clock points when host), else None: not
    a finished MCAP file, damaged chunks or no pose labels (those take the whole-session path)."""
    if not can_stream(path):
        return None
    _meta, poses, _events = read_labels(path)
    if not poses:
        return None
    return open_streamed(path, window_s=window_s, host=host)


def open_streamed(
    path: str | os.PathLike,
    *,
    window_s: float = 2.0,
    trim_s: float = 0.5,
    observe: bool = True,
    stats: bool = False,
    check_times: bool = True,
    host: bool = False,
    gyro: bool = False,
) -> StreamedSession | None:
    """The session's labels (after the time-stamp checks of load_input) and, when observe, its
    observation table (segment.observations' defaults) and, with stats, its per-hold statistics
    (segment.pose_stats); InputError as load_input/observations. None for a file with damaged
    chunks: the whole-session reader (load_input) says what it skipped and how many samples.
    check_times False: the labels only (the caller's pass makes the check: navigate.blocks'
    Blocks.checked; None still when reading the labels meets a damaged chunk). host: also the host
    clock points (store.stream.read_host_clock), taken in the observation pass; gyro: the gyro
    calibration's first pass too (StreamedSession.gyro_calibration then reads the file once more,
    not twice)."""
    p = Path(path)
    if not p.exists():
        raise InputError("no such file", where=str(p))
    held: list[PoseStats] | None = [] if stats else None
    if observe and check_times:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                clock = HostClock() if host else None
                obs, (meta, poses, _events), first = _observe_checked(p, window_s, trim_s, held, clock, gyro)
                ok = True
            except Exception:
                ok = False
        if ok and not any(issubclass(w.category, DataIntegrityWarning) for w in caught):
            for w in caught:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
            return StreamedSession(meta, poses, obs, str(p), held, clock.result() if clock else None, first)
        held = [] if stats else None  # failed or damaged: the two passes say why, as before
    s = _open_two_passes(p, window_s, trim_s, observe, held, check_times)
    if s is not None and host:
        s.host_clock = read_host_clock(p)
    return s


def _open_two_passes(
    p: Path, window_s: float, trim_s: float, observe: bool, held: list | None, check_times: bool
):
    """open_streamed with the time-stamp checks in a pass of their own, then the observations."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if check_times:
            stream_check_timestamps(p)
        else:
            labels = read_labels(p)
    if any(issubclass(w.category, DataIntegrityWarning) for w in caught):
        return None
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if not check_times:
        return StreamedSession(*labels[:2], None, str(p), None)
    meta, poses, events = read_labels(p)
    obs = None
    if observe:
        obs = stream_observations(
            p, window_s=window_s, trim_s=trim_s, stats_out=held, labels=(meta, poses, events)
        )
    return StreamedSession(meta, poses, obs, str(p), held)
