"""One session input as every stage reads it: ``open_source(path | Session)`` decides once how.

A finished accellog MCAP file streams chunk by chunk (``store.stream.iter_imu``: memory bounded by
one chunk group, whatever the session length); anything else is read whole and handed out as one
block: a damaged or unfinished MCAP file (``read_session`` salvages it and says what it kept), a
ROS 2 bag, a CSV of any supported logger, a Session already in memory. The caller never asks which:
it gets the metadata, the pose labels and events up front and a new pass over the samples from
``blocks()`` (``Source`` is also the pass factory ``calibrate.gyro`` takes), and runs its one pass
with ``run``::

    src = open_source("cal.mcap")
    table = src.run(lambda s: segment_blocks(s.meta, s.poses, s.blocks(), where=s.where))

Time stamps are checked once (``TimestampCheck``: < 2 samples, zero duration, non-finite,
duplicated or decreasing stamps, one InputError line naming the first bad sample): a file read
whole at opening, a streamed file along the first pass of ``run`` (no pass of its own). A streamed
pass that meets damaged chunks (``DataIntegrityWarning``) is not trusted: the file is read whole
(the salvaging reader names what it skips) and the pass runs again on that one block, so a stage
sees either every readable sample or a refusal. ``whole=True`` asks for the samples in memory (a
stage that needs the whole series at once, e.g. a centred slope over block edges).

Pose tables and observation files are observation tables, not sessions: ``calibrate.observe.obs_file``
reads them; here they are refused with a line that says so.

What was recovered from a truncated or unfinished recording is stated so that users see it:
``read_session`` salvages the complete chunks and appends an Event('recovered'); ``recovery_info``
turns that into numbers (seconds and samples kept, complete holds) that commands print on stderr
(``announce``, when a file is read whole), put in ``--json`` and store in every artifact's provenance.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np

from accellog.core.errors import DataIntegrityWarning, InputError
from accellog.core.notices import note
from accellog.core.session import Event, PoseLabel, Session, SessionMeta
from accellog.store.stream import ImuBlock, iter_imu, read_labels

T = TypeVar("T")
_MCAP_MAGIC = b"\x89MCAP0\r\n"


class Source:
    """One session's samples and labels (module doc). ``session`` is set once the samples are in
    memory (read whole at opening, or after a streamed pass met damaged chunks)."""

    def __init__(
        self,
        where: str,
        meta: SessionMeta,
        poses: list[PoseLabel],
        events: list[Event],
        *,
        session: Session | None = None,
        path: Path | None = None,
        what: str = "this command",
        check_times: bool = True,
    ) -> None:
        self.where, self.meta, self.poses, self.events = where, meta, list(poses), list(events)
        self.session = session
        self.path = path
        self.what = what
        self.check_times = check_times  # False: bad stamps are not refused (doctor reports them)
        self._checked = session is not None  # a Session's stamps: checked when it was read
        self._first: _Checked | None = None  # the checked first pass, inside run
        self._running = False  # inside run: a nested run (a stage calling a stage) is the same pass

    @property
    def in_memory(self) -> bool:
        """The samples are one block in memory (series may be kept for plots)."""
        return self.session is not None

    def blocks(self) -> Iterator[ImuBlock]:
        """A new pass over the samples in time order (inside run's first pass: the checked one)."""
        first, self._first = self._first, None
        if first is not None:
            return iter(first)
        s = self.session
        if s is not None:
            block = ImuBlock(s.meta, s.t_s, s.sample_index, s.accel_g, s.gyro_dps, s.temp_degC, s.host_time_s,
                             s.accel_counts, s.gyro_counts)  # fmt: skip
            return iter([block])
        return iter_imu(self._file())

    def _file(self) -> Path:
        """The file a streamed source reads (an in-memory one has none)."""
        if self.path is None:
            raise RuntimeError("an in-memory source has no file to read")
        return self.path

    __call__ = blocks  # a pass factory: calibrate.gyro.stream.calibrate_blocks(src, ...)

    def whole(self) -> Session:
        """The samples in memory (a streamed file is read whole now, its stamps checked)."""
        if self.session is None:
            s = read_whole(self._file(), what=self.what, check_times=self.check_times)
            self.session, self.meta, self.poses, self.events = s, s.meta, list(s.poses), list(s.events)
            self._checked = True
        return self.session

    def run(self, fn: Callable[[Source], T], *, whole: bool = False) -> T:
        """fn(self), which makes its passes with blocks(); the stamps are checked along its first
        pass; damaged chunks met there, or whole: fn runs again on the whole session (module doc),
        so fn must start afresh at each call. A run inside fn is part of it."""
        if whole and not self._running:
            self.whole()
        if self._checked or self._running:
            return fn(self)
        self._running = True
        try:
            return self._checked_run(fn)
        finally:
            self._running = False

    def _checked_run(self, fn: Callable[[Source], T]) -> T:
        check = TimestampCheck()
        first = self._first = _Checked(iter_imu(self._file()), check)
        out: list[T] = []  # fn's value, unless it raised
        err = None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                out.append(fn(self))
            except InputError as e:  # the stamps' refusal comes first, as from a pass of its own
                err = e
            finally:
                self._first = None
            if first.failed is not None:  # the reader refused the file: its error first
                raise first.failed
            first.drain()
        if any(issubclass(w.category, DataIntegrityWarning) for w in caught):
            self.whole()
            return fn(self)
        for w in caught:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        if self.check_times:
            check.finish(self.where)
        self._checked = True
        if err is not None:
            raise err
        return out[0]

    def extent(self) -> tuple[int, float, float]:
        """(samples, first time s, span s): exact in memory, estimated for a streamed file from its
        first block and the MCAP summary (for sizing display buckets and strides only)."""
        s = self.session
        if s is not None:
            return (s.n, float(s.t_s[0]), float(s.t_s[-1] - s.t_s[0])) if s.n else (0, 0.0, 0.0)
        from accellog.store.reader import session_summary

        blocks = iter_imu(self._file())
        try:
            first = next(blocks)
        finally:
            blocks.close()
        t0 = float(first.t_s[0])
        span = max(float(session_summary(self._file()).get("duration_s") or 0.0), float(first.t_s[-1]) - t0)
        rate = float(self.meta.sample_rate_hz or 0.0) or (first.n - 1) / max(float(first.t_s[-1]) - t0, 1e-9)
        return round(span * rate) + 1, t0, span

    def check(self) -> None:
        """The time-stamp check in a pass of its own, for a stage that cannot make a pass twice
        (replay shows its samples as it goes); damaged chunks: the file is read whole."""
        self.run(lambda s: None)


class _Checked:
    """A pass's blocks, each block's stamps fed to a TimestampCheck on the way; drain() feeds the
    blocks the pass did not take (a cut or an error) and closes the reader."""

    def __init__(self, blocks: Iterator[ImuBlock], check: TimestampCheck) -> None:
        self.blocks, self.check = blocks, check
        self.failed: Exception | None = None  # the reader's own refusal of the file

    def __iter__(self) -> Iterator[ImuBlock]:
        while True:
            try:
                b = next(self.blocks)
            except StopIteration:
                return
            except Exception as e:
                self.failed = e
                raise
            self.check.add(b.t_s)
            yield b

    def close(self) -> None:
        """Nothing: drain() reads the rest for the check, then closes the reader."""

    def drain(self) -> None:
        for _ in self:
            pass
        close = getattr(self.blocks, "close", None)
        if close is not None:
            close()


# ------------------------------------------------------------------------------------------ opening


def open_source(
    x: Session | Source | str | os.PathLike, *, what: str = "this command", check_times: bool = True
) -> Source:
    """The Source of a session file or of a Session in memory (module doc). what names the stage in
    refusals; check_times False: bad stamps are not refused, read whole or streamed (doctor reports them)."""
    if isinstance(x, Source):
        return x
    if isinstance(x, Session):
        where = x.path or f"session ({x.meta.source})"
        return Source(str(where), x.meta, x.poses, x.events, session=x, what=what)
    p = Path(x)
    if not p.exists():
        raise InputError("no such file", where=str(p))
    if _streams(p):
        meta, poses, events = read_labels(p)
        return Source(str(p), meta, poses, events, path=p, what=what, check_times=check_times)
    s = read_whole(p, what=what, check_times=check_times)
    return Source(str(p), s.meta, s.poses, s.events, session=s, path=p, what=what, check_times=check_times)


def _streams(p: Path) -> bool:
    """A finished accellog MCAP file (ends with the MCAP magic; not a ROS 2 bag)."""
    from accellog.store.importers.ros2 import is_ros2_bag

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


def read_whole(path: str | os.PathLike, *, what: str = "this command", check_times: bool = True) -> Session:
    """Any session file whole (accellog MCAP, salvaged when truncated; ROS 2 bag; capstone, imucal
    or any logger's CSV), its stamps checked unless check_times is False."""
    s = _read(Path(path), what)
    if check_times:
        check_timestamps(s, where=str(path))
    return s


def _read(p: Path, what: str) -> Session:
    """The Session of a file, by the reader of its kind (session_kind): accellog's MCAP or an importer."""
    if not p.exists():
        raise InputError("no such file", where=str(p))
    kind = session_kind(p)
    if kind in ("pose_table", "observations"):
        raise _not_a_session(p, what)
    from accellog.store.importers import IMPORTERS, import_file
    from accellog.store.importers.csv_checks import UnitsError

    if kind != "mcap" and kind not in IMPORTERS:
        raise InputError(
            f"unknown input type {p.suffix.lower() or '(no suffix)'!r}: give .mcap, .csv, .ulg, .bin or "
            "observations .json",
            where=str(p),
        )
    try:
        if kind == "mcap":  # accellog's own: salvaged when truncated (announced below)
            from accellog.store.reader import read_session

            session = read_session(p)
        else:
            session = import_file(kind, p)  # the importer of its kind (IMPORTERS)
    except UnitsError as exc:  # its fix names import csv's options: say where they go
        raise UnitsError(
            f"{exc} (an option of `accellog import csv FILE -o S.mcap`: import the file, then give S.mcap)"
        ) from None
    announce(session)  # a truncated MCAP file: say what was recovered (stderr)
    return session


def session_kind(p: Path) -> str:
    """What a file holds: 'ros2' (a bag's only sensor_msgs/Imu topic), 'mcap' (accellog's), a text
    kind (text_kind), 'ulog' (PX4 .ulg), 'dataflash' (ArduPilot .bin), 'observations' (.json) or
    'unknown'."""
    from accellog.store.importers.ros2 import is_ros2_bag

    suffix = p.suffix.lower()
    if is_ros2_bag(p):
        return "ros2"
    if suffix == ".mcap":
        return "mcap"
    if suffix in (".csv", ".txt"):
        return text_kind(p)
    if suffix == ".ulg":
        return "ulog"
    if suffix == ".bin":
        return "dataflash"
    return "observations" if suffix == ".json" else "unknown"


def text_kind(p: Path) -> str:
    """What a .csv/.txt file holds, from its first line: 'pose_table' (capstone six_position_data),
    'imucal', 'capstone' (the seed's raw log) or 'csv' (any logger's)."""
    from accellog.store.importers.text import check_text_file

    check_text_file(p)  # not a CSV at all (binary, zero-filled): refused within the first KiB
    try:
        with open(p, encoding="utf-8", errors="replace") as f:
            first = f.readline(65536).replace(" ", "").lower()
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", where=str(p)) from None
    if first.startswith("x_true"):
        return "pose_table"
    if first.startswith("part,samples") or first.startswith("n_samples"):
        return "imucal"
    if "," not in first or first.startswith("acceleration") or not first[:1].isalpha():
        return "capstone"
    return "csv"


def _not_a_session(p: Path, what: str) -> InputError:
    return InputError(
        f"{what} needs a recorded session (samples), not a pose table / observations", where=str(p)
    )


# ------------------------------------------------------------------------------------------ recovery


@dataclass(frozen=True)
class RecoveryInfo:
    """A recovered session: duration_s and samples kept, holds (complete labelled poses), detail."""

    path: str
    duration_s: float
    samples: int
    holds: int
    detail: str

    def to_dict(self) -> dict:
        return asdict(self)

    def line(self) -> str:
        return (
            f"{self.path}: truncated file recovered: {self.duration_s:.1f} s, {self.samples} samples, "
            f"{self.holds} holds kept ({self.detail})"
        )


def recovery_info(session: Session) -> RecoveryInfo | None:
    """RecoveryInfo of a session read from an unfinished file, None for a finished one."""
    notes = [e.detail for e in session.events if e.kind == "recovered"]
    if not notes:
        return None
    dur = float(session.t_s[-1] - session.t_s[0]) if session.n else 0.0
    return RecoveryInfo(str(session.path or ""), dur, int(session.n), len(session.poses), "; ".join(notes))


def announce(session: Session) -> RecoveryInfo | None:
    """recovery_info, also queued as a user note (accellog.core.notices; the CLI prints it on
    stderr when the command succeeds)."""
    info = recovery_info(session)
    if info is not None:
        note(info.line())
    return info


# ------------------------------------------------------------------------------------------ time stamps


def check_timestamps(session: Session, where: str | None = None) -> None:
    """InputError for a degenerate session: < 2 samples, zero duration, duplicated or decreasing
    sample times (the first offending sample is named by index and time)."""
    t = np.asarray(session.t_s, float)
    if t.size < 2:
        raise InputError(f"session has {t.size} sample(s): nothing to calibrate", where=where)
    bad_t = ~np.isfinite(t)
    if bad_t.any():
        i = int(np.argmax(bad_t))
        raise InputError(f"sample {i} has a non-finite time stamp", where=where)
    if not t[-1] > t[0]:
        raise InputError(f"session has zero duration ({t.size} samples at t = {t[0]:g} s)", where=where)
    dt = np.diff(t)
    bad = dt <= 0
    if bad.any():
        i = int(np.argmax(bad)) + 1
        kind = "duplicated" if dt[i - 1] == 0 else "decreasing"
        raise InputError(
            f"{kind} time stamp at sample {i}: t = {t[i]:.6f} s after {t[i - 1]:.6f} s "
            f"({int(bad.sum())} non-increasing steps)",
            where=where,
        )


class TimestampCheck:
    """check_timestamps fed block by block (a pass that reads the samples anyway runs it)."""

    def __init__(self) -> None:
        self.n, self.t0, self.t_last, self.bad_n = 0, np.nan, np.nan, 0
        self.nonfinite: int | None = None  # index of the first non-finite stamp
        self.first_bad: tuple[int, float, float] | None = None  # (i, t_i s, t_i-1 s) of the first step back

    def add(self, t_s: np.ndarray) -> None:
        t, n = np.asarray(t_s, float), self.n
        fin = ~np.isfinite(t)
        if self.nonfinite is None and fin.any():
            self.nonfinite = n + int(np.argmax(fin))
        if n and t.size and not t[0] > self.t_last:  # the step from the previous block (NaN: not bad)
            self.bad_n += int(t[0] <= self.t_last)
            if self.first_bad is None and t[0] <= self.t_last:
                self.first_bad = (n, t[0], self.t_last)
        bad = t[1:] <= t[:-1]
        nb = int(np.count_nonzero(bad))
        if nb:
            self.bad_n += nb
            if self.first_bad is None:
                j = int(np.argmax(bad)) + 1
                self.first_bad = (n + j, t[j], t[j - 1])
        if not n and t.size:
            self.t0 = t[0]
        self.n += t.size
        if t.size:
            self.t_last = t[-1]

    def finish(self, path: str | Path) -> None:
        """InputError (one line) when the stamps fed are not a session's; else nothing."""
        where, n, t0 = str(path), self.n, self.t0
        if n < 2:  # no samples to hold: read_session names a file that is not a session at all
            from accellog.store.reader import read_session

            read_session(path)
            raise InputError(f"session has {n} sample(s): nothing to calibrate", where=where)
        if self.nonfinite is not None:
            raise InputError(f"sample {self.nonfinite} has a non-finite time stamp", where=where)
        if not self.t_last > t0:
            raise InputError(f"session has zero duration ({n} samples at t = {t0:g} s)", where=where)
        if self.first_bad is not None:
            i, ti, tp = self.first_bad
            kind = "duplicated" if ti == tp else "decreasing"
            raise InputError(
                f"{kind} time stamp at sample {i}: t = {ti:.6f} s after {tp:.6f} s "
                f"({self.bad_n} non-increasing steps)",
                where=where,
            )
