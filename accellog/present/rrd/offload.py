"""A .rrd file written by a child process: ``import rerun`` and the writing run on a second core.

In-process, ``accellog replay --rrd`` (1 h at 1 kHz) spent ~0.45 s importing rerun (pyarrow,
rerun_bindings, rerun.blueprint) and ~0.2 s logging on top of the replay itself; importing on a
thread gives nothing (the import holds the GIL). Here a child process (``offload_child``), started
with the command, imports rerun while the parent reads the MCAP file and integrates, and runs the
recording's calls on a real ``RunRecording``: the same code writes the same file. What needs no
rerun stays in the parent (``SeriesLogs``: checks, display envelopes, track reduction), so that only
the rows that go into the file cross the pipe (pickle protocol 5, arrays as out-of-band buffers):
~2 MB for that replay instead of ~320 MB of samples, whose sending cost the parent more (0.5-0.7 s)
than building the envelopes (0.13-0.2 s).

Measured with ``python benchmarks/run_all.py --rows replay --repeat 5``, six runs each in one session
(2 cores, a load of 0.8-1.4 from other jobs): ``replay --rrd`` 1 h: 1.63-1.97 s in-process = 1.33-1.43x
the replay alone, 1.51-1.84 s with the child = 1.17-1.26x (one run 1.40x); CPU +0.1-0.3 s (the
child's interpreter and imports); peak memory 185 -> 123 MB (rerun lives in the child). Other commands, medians of 5 interleaved runs, in-process ->
child: fit 1 h 2.79 -> 2.49 s, fit 1 min 1.27 -> 1.03 s, drift 1 h 4.18 -> 3.83 s, evaluate 1 h
4.37 -> 3.76 s, track 64 s 0.81 -> 0.75 s, run six_position 14.6 -> 13.2 s. ``diagnose`` (which
builds rerun objects itself) showed no steady gain and stays in-process, as do the commands that
pass a Blueprint or use the stream directly (demo, doctor, magcal, noise, workbench, fleet).

The parent keeps the output: ``AtomicOutput.begin`` checks and locks the path before anything runs
(the same one-line errors as in-process, the lock holding the parent's PID), the child writes the
parent's temporary file, and the parent renames it on ``close`` once the child has flushed it. When
the child fails or dies, the parent raises one ``AccellogError`` line (an ``AccellogError`` of the
child as it is) and removes the temporary file; when the parent dies, the child reads the end of its
stdin, removes the temporary file and exits (a kill of both leaves a temporary file named with the
parent's PID, which the next writer removes: ``store.atomic``).

A command opts in with ``offload_process.prestart()`` (the command line, for the commands measured to
gain: the child starts with the process), and its flow opens the recording with ``open_recording``,
which hands out the started child for the first file sink and a plain ``RunRecording`` otherwise.
With one core (or ACCELLOG_RRD_CHILD=0) ``prestart`` starts nothing and every recording stays
in-process.
"""

from __future__ import annotations

import contextlib
import functools
import pickle
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

from accellog.core.errors import AccellogError
from accellog.present.rrd import offload_process
from accellog.present.rrd.recording import RunRecording
from accellog.present.rrd.series import SeriesLogs
from accellog.present.rrd.sinks import parse_sink
from accellog.store.atomic import AtomicOutput


class RecordingWriterError(AccellogError):
    """The child process writing a .rrd file failed or died (nothing was written)."""


def _forward(name: str) -> Callable[..., None]:
    """A method that sends the call to the child (the RunRecording method's name and docstring)."""
    method = getattr(RunRecording, name)

    @functools.wraps(method)
    def call(self: OffloadedRecording, *args: Any, **kw: Any) -> None:
        self._call(name, args, kw)

    return call


class OffloadedRecording(SeriesLogs):
    """A ``RunRecording`` of a file sink ('save:PATH') running in a child process, with the same
    methods: series are checked and reduced to their display envelopes here (``SeriesLogs``, the
    code RunRecording runs) and their rows sent; every other call is forwarded as it is (the logging
    calls return nothing; ``entities``, ``extents`` and ``report`` ask the child). The path is
    checked and locked here, at once; a failure of the child is raised at the next call or at
    ``close`` (its ``AccellogError`` as it is, else a ``RecordingWriterError``), and no file is
    left. Not guarded (a file sink raises its failures)."""

    def __init__(
        self,
        sink: str,
        *,
        app_id: str = "accellog",
        recording_id: str | None = None,
        blueprint: str | None = "auto",
        full_rate: bool | None = None,
        writer: offload_process.Writer | None = None,
    ) -> None:
        self.kind, self.target = parse_sink(sink)
        if self.kind != "save":
            raise ValueError(f"OffloadedRecording writes files ('save:PATH'), not {sink!r}")
        if blueprint is not None and not isinstance(blueprint, str):
            raise TypeError("OffloadedRecording takes blueprint 'auto' or None (a Blueprint: RunRecording)")
        self.full_rate = bool(RunRecording.DEFAULT_FULL_RATE if full_rate is None else full_rate)
        self.guard = False
        self._init_series()
        self.failures = 0
        self.first_failure: str | None = None
        self.down = False
        self._closed = False
        self._w = writer
        self._out = AtomicOutput(Path(self.target), what="--rrd output")
        try:
            self._out.begin()  # the path checked and locked before anything else: the same errors
            if self._w is None:
                self._w = offload_process.Writer()
            kw = {"sink": sink, "app_id": app_id, "recording_id": recording_id, "blueprint": blueprint,
                  "full_rate": self.full_rate}  # fmt: skip
            self._send(("open", kw, str(self._out.tmp)), flush=True)
        except BaseException:
            self.abort()
            raise

    @property
    def pid(self) -> int | None:
        """The child's process id (None once stopped)."""
        return None if self._w is None or self._w.proc.returncode is not None else self._w.proc.pid

    # -- the calls -----------------------------------------------------------------------------------
    def _send(self, msg: tuple, *, flush: bool = False) -> None:
        assert self._w is not None
        try:
            self._w.send(msg, flush=flush)
        except OSError:  # the child is gone (a broken pipe): why, then no file
            self._failed()

    def _call(self, name: str, args: tuple, kw: dict) -> None:
        if not self._closed:  # as RunRecording: a closed recording ignores calls
            self._send(("call", name, args, kw))

    def _guarded(self, fn: Callable[..., Any], *args: Any, **kw: Any) -> Any:
        return None if self._closed else fn(*args, **kw)

    def _write_series(self, *args: Any) -> None:  # SeriesLogs: the rows go to the child's RunRecording
        self._call("_write_series", args, {})

    def _end_rows(self) -> None:  # SeriesLogs.end_batches: the child sends what it gathered
        self._call("end_batches", (), {})

    def _write_track(self, *args: Any) -> None:  # SeriesLogs.log_track: the reduced track
        self._call("_write_track", args, {})

    def _write_track_3d(self, *args: Any) -> None:
        self._call("_write_track_3d", args, {})

    def _ask(self, name: str) -> Any:
        if self._closed:
            raise RuntimeError(f"{name}: the recording is closed")
        self._send(("get", name), flush=True)
        return self._reply()

    def _reply(self) -> Any:
        assert self._w is not None
        try:
            status, *rest = self._w.recv()
        except (EOFError, OSError):
            self._failed()
        if status != "ok":
            self._failed((status, *rest))
        return rest[0]

    def _failed(self, reply: tuple | None = None) -> NoReturn:
        """Raise what went wrong in the child, after stopping it and removing the temporary file."""
        w = self._w
        assert w is not None
        if reply is None:
            with contextlib.suppress(EOFError, OSError, pickle.UnpicklingError):
                reply = w.recv()  # the child's last word, if it said one before exiting
        self._closed = True
        w.stop(timeout_s=5.0)
        self._out.abort()
        if reply is not None and reply[0] == "error":
            _, blob, text = reply
            exc = None
            with contextlib.suppress(Exception):
                exc = pickle.loads(blob) if blob is not None else None
            if isinstance(exc, AccellogError):
                raise exc
            raise RecordingWriterError(f"the process writing the recording failed: {text}", where=self.target)
        raise RecordingWriterError(
            f"the process writing the recording (pid {w.proc.pid}) {w.how_it_ended()}; nothing written",
            where=self.target,
        )

    log_text = _forward("log_text")
    log_static = _forward("log_static")
    log_poses = _forward("log_poses")
    log_events = _forward("log_events")
    log_residuals = _forward("log_residuals")
    log_curve = _forward("log_curve")
    log_document = _forward("log_document")
    log_ladder = _forward("log_ladder")

    @property
    def entities(self) -> dict[str, str]:
        """Entity paths logged so far -> role (asked of the child)."""
        return self._ask("entities")

    @property
    def extents(self) -> dict[str, tuple[float, float]]:
        """Entity paths of the series logged on sensor_time -> (first, last) time (s)."""
        return self._ask("extents")

    def report(self) -> str | None:
        """One line describing logging failures (guard=True), or None when there were none."""
        if not self._closed:
            return self._ask("report")
        if not self.failures:
            return None
        return f"live view: {self.failures} logging calls dropped ({self.first_failure})"

    # -- finish --------------------------------------------------------------------------------------
    def close(self) -> None:
        """The child sends the blueprint, flushes and closes the file; then it is renamed into place."""
        if self._closed:
            return
        try:
            self.end_batches()  # the last buckets of the envelopes built here
            self._send(("close",), flush=True)
            state = self._reply()
        except BaseException:
            self.abort()
            raise
        self._closed = True
        self.failures = int(state["failures"])
        self.first_failure = state["first_failure"]
        self.down = bool(state["down"])
        assert self._w is not None
        try:
            self._out.commit()  # while the child exits
        finally:
            self._w.stop(timeout_s=5.0)

    def abort(self) -> None:
        """Stop the child (at once) without producing a file (the temporary file is removed)."""
        self._closed = True
        if self._w is not None:
            self._w.stop()
        self._out.abort()

    def __enter__(self) -> OffloadedRecording:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


Recording = RunRecording | OffloadedRecording
"""What ``open_recording`` returns: the same methods either way."""


def open_recording(sink: str, **kw: Any) -> Recording:
    """The recording of a sink (the arguments of ``RunRecording``): the started child's
    (``offload_process.prestart``) for the first file sink with blueprint 'auto' or None (not
    guarded, no on_failure), else a RunRecording in this process."""
    bp = kw.get("blueprint", "auto")
    if (
        offload_process.started()
        and sink.startswith("save:")
        and (bp is None or isinstance(bp, str))
        and not kw.get("guard")
        and kw.get("on_failure") is None
        and kw.get("output") is None
    ):
        kw = {k: v for k, v in kw.items() if k not in ("guard", "on_failure", "output")}
        return OffloadedRecording(sink, writer=offload_process.claim(), **kw)
    return RunRecording(sink, **kw)
