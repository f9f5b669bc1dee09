"""``LiveView``: the live recording panels (raw data, pose prompt, stillness, running calibration) on a guarded sink."""

from __future__ import annotations

import contextlib
from collections.abc import Sequence

import numpy as np

from accellog.core.session import PoseLabel
from accellog.core.units import temp_counts_to_degC
from accellog.navigate.online import OnlineIntegrator
from accellog.present.rrd.entities import AXES, LIVE, TRACKS
from accellog.present.rrd.recording import RunRecording

LIVE_BUCKET_S = 0.02
"""The live sample streams (raw, calibrated, temperature, track) are shown as min/max envelopes of
buckets this wide (s): 100 rows per second and stream whatever the sample rate, spikes kept; a
bucket reaches the view when the next one starts. Every sample on demand: a ``full_rate``
RunRecording (ACCELLOG_RRD_FULL=1); the MCAP file always has them all."""


class LiveView:
    """Live panels for a guided recording, on top of a guarded RunRecording.

    Implements the recorder's ``RecorderUI`` (prompt/waiting/holding/finished_pose) and its
    ``on_batch(batch, accel_g)`` callback. Every call is guarded: a closed or unreachable viewer
    is counted (``failures``) and reported once, never raised into the recording loop.
    """

    def __init__(self, recording: RunRecording | str, *, integrate: bool = False) -> None:
        self.run = recording if isinstance(recording, RunRecording) else RunRecording(recording, guard=True)
        self.run.guard = True
        self.run.begin_stream(LIVE_BUCKET_S)
        self._t_s = 0.0
        self._integrator = None
        if integrate:
            self._integrator = OnlineIntegrator()

    @classmethod
    def from_option(cls, option: str, *, integrate: bool = False) -> LiveView:
        """From a CLI option: 'spawn', 'connect', 'connect URL', 'connect:URL', 'save FILE.rrd',
        'save:FILE.rrd' or a path ending in .rrd."""
        opt = option.strip()
        head, _, rest = opt.partition(" ")
        if head in ("connect", "save") and rest.strip():
            opt = f"{head}:{rest.strip()}"
        elif opt.endswith(".rrd") and not opt.startswith(("save:", "connect:")):
            opt = f"save:{opt}"
        return cls(RunRecording(opt, guard=True), integrate=integrate)

    def wrap_ui(self, ui):
        """A RecorderUI that forwards every call to ``ui`` (the terminal) and then to this view."""
        return _TeeUI(ui, self)

    @property
    def failures(self) -> int:
        return self.run.failures

    def pose_prompt(
        self, name: str, up: Sequence[float], *, index: int | None = None, total: int | None = None
    ) -> None:
        """Show the next pose to set (markdown panel + a log line)."""
        head = f"pose {index + 1}/{total}: " if index is not None and total else "next pose: "
        md = f"## {head}**{name}**\n\nturn the sensor so that ({up[0]:+.0f}, {up[1]:+.0f}, {up[2]:+.0f}) points up"
        self.run._guarded(self.run._log_document_at, f"{LIVE}/prompt", md)
        self.run.log_text(f"{LIVE}/log", self._t_s, head + name)

    def stillness(self, t_s: float, still: bool, stat: float) -> None:
        """Stillness detector state at sensor time t_s: still (0/1) and its statistic."""
        self._t_s = max(self._t_s, float(t_s))
        self.run.log_series(
            f"{LIVE}/stillness",
            np.array([t_s], dtype=np.float64),
            np.array([[1.0 if still else 0.0, float(stat)]]),
            ["still (0/1)", "motion statistic"],
            role="live",
            decimate=False,  # one row per call
        )

    def running_calibration(self, text: str) -> None:
        """Markdown of the calibration fitted so far."""
        self.run._guarded(self.run._log_document_at, f"{LIVE}/calibration", text)

    def log_batch(
        self,
        t_s: np.ndarray,
        sample_index: np.ndarray | None,
        accel_g: np.ndarray,
        *,
        temp_degC: np.ndarray | None = None,
        calibrated_g: np.ndarray | None = None,
    ) -> None:
        """One batch of samples as they arrive (columnar, sensor time; envelopes: LIVE_BUCKET_S)."""
        t = np.asarray(t_s, dtype=np.float64)
        if t.size:
            self._t_s = max(self._t_s, float(t[-1]))
        self.run.log_samples("raw", t, sample_index, accel_g, "g")
        if calibrated_g is not None:
            self.run.log_samples("calibrated", t, sample_index, calibrated_g, "g")
        if temp_degC is not None:
            self.run.log_temperature(t, temp_degC)
        if self._integrator is not None and t.size:
            step = self._integrator.push(t, calibrated_g if calibrated_g is not None else accel_g)
            self.run.log_series(
                f"{TRACKS}/live", t, step.disp_m, [f"live {a} (m)" for a in AXES], role="track"
            )

    # RecorderUI + on_batch --------------------------------------------------------------------------
    def prompt(self, index: int, total: int, pose) -> None:
        self.pose_prompt(pose.name, pose.up_sensor, index=index, total=total)

    def waiting(self, moving: bool, still_for_s: float) -> None:
        self.stillness(self._t_s, not moving, still_for_s)

    def holding(self, pose, done_s: float) -> None:
        pass

    def finished_pose(self, label: PoseLabel) -> None:
        self.run.log_poses([label])

    def on_batch(self, batch, accel_g: np.ndarray) -> None:
        """Recorder callback: batch has t_ns (int64 ns), first_index, optional temp_counts."""
        try:
            t = np.asarray(batch.t_ns, dtype=np.int64) / 1e9
            idx = int(batch.first_index) + np.arange(t.shape[0])
            temp = getattr(batch, "temp_counts", None)
            if temp is not None:
                temp = temp_counts_to_degC(np.asarray(temp, dtype=np.float64))
        except Exception as exc:
            self.run._fail(f"live view: bad batch: {exc}")
            return
        self.log_batch(t, idx, accel_g, temp_degC=temp)

    def close(self) -> None:
        self.run.close()
        msg = self.run.report()
        if msg:
            with contextlib.suppress(Exception):
                self.run._on_failure(msg)


class _TeeUI:
    """RecorderUI calling the operator's UI first, then the (guarded) live view."""

    def __init__(self, ui, live: LiveView) -> None:
        self.ui, self.live = ui, live

    def _both(self, name: str, *args) -> None:
        if self.ui is not None:
            getattr(self.ui, name)(*args)
        try:
            getattr(self.live, name)(*args)
        except Exception as exc:  # the live view never stops the recorder
            self.live.run._fail(f"live view: {name}: {exc}")

    def prompt(self, index: int, total: int, pose) -> None:
        self._both("prompt", index, total, pose)

    def waiting(self, moving: bool, still_for_s: float) -> None:
        self._both("waiting", moving, still_for_s)

    def holding(self, pose, done_s: float) -> None:
        self._both("holding", pose, done_s)

    def finished_pose(self, label: PoseLabel) -> None:
        self._both("finished_pose", label)
