"""The recorder's writes handed to a helper thread (issue 27, loss under load): the file is the one
the inline loop writes, calls run in order, the reading thread never waits for a slow write, and a
failed write stops the recording instead of being skipped."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from accellog.acquire.driver import Mpu9250
from accellog.acquire.emulator.chip import EmulatedMpu9250
from accellog.acquire.emulator.clock import SimClock
from accellog.acquire.handoff import Handoff
from accellog.acquire.recorder import Recorder
from accellog.core.protocol import parse_protocol
from accellog.core.session import SessionMeta
from accellog.flows.simulate import Scenario, build_sensor_model
from accellog.store.reader import read_session
from accellog.store.writer import SessionWriter

RATE_HZ = 200.0


def record(path: Path, *, write_thread: bool, i2c_error_rate: float = 0.0, calls: list | None = None):
    """A guided six-pose session (2 s holds, faults optional) on the SimClock; (summary, session)."""
    sc = Scenario(protocol="six", hold_s=8.0, sample_rate_hz=RATE_HZ, seed=1)
    model, _motion = build_sensor_model(sc)
    clock = SimClock()
    chip = EmulatedMpu9250(model, clock, seed=3, i2c_error_rate=i2c_error_rate)
    drv = Mpu9250(chip, clock_ns=clock.now_ns)
    drv.probe()
    cfg = drv.configure(sample_rate_div=round(1000.0 / RATE_HZ) - 1)
    meta = SessionMeta(source="emulator", accel_lsb_per_g=cfg.accel_lsb_per_g,
                       gyro_lsb_per_dps=cfg.gyro_lsb_per_dps, sample_rate_hz=cfg.sample_rate_hz)  # fmt: skip
    on_pose = None if calls is None else (lambda label, *_: calls.append((threading.get_ident(), label.name)))
    with SessionWriter(path, meta) as w:
        drv.start()
        rec = Recorder(drv, w, sleep=clock.sleep, write_thread=write_thread, on_pose=on_pose)
        try:
            summary = rec.run(parse_protocol("six", 2.0))
        finally:
            rec.close()
    return summary, read_session(path)


@pytest.mark.parametrize("i2c_error_rate", [0.0, 0.02])
def test_helper_thread_writes_the_file_the_inline_loop_writes(tmp_path, i2c_error_rate):
    _, inline = record(tmp_path / "inline.mcap", write_thread=False, i2c_error_rate=i2c_error_rate)
    calls: list = []
    summary, threaded = record(tmp_path / "thread.mcap", write_thread=True, i2c_error_rate=i2c_error_rate,
                               calls=calls)  # fmt: skip
    assert threaded.n == summary.samples == inline.n > 0
    for name in ("sample_index", "t_s", "accel_counts", "gyro_counts"):
        np.testing.assert_array_equal(getattr(threaded, name), getattr(inline, name))
    assert threaded.lost_samples() == inline.lost_samples() == summary.lost_samples
    assert (threaded.lost_samples() > 0) == (i2c_error_rate > 0)  # the faults really lost samples
    assert [(e.kind, e.sample_index, e.lost_samples) for e in threaded.events] == [
        (e.kind, e.sample_index, e.lost_samples) for e in inline.events
    ]
    assert [(p.name, p.start_s, p.end_s) for p in threaded.poses] == [
        (p.name, p.start_s, p.end_s) for p in inline.poses
    ]
    # on_pose ran on the helper thread, once per hold, in order
    assert [name for _, name in calls] == [p.name for p in inline.poses]
    assert {tid for tid, _ in calls} != {threading.get_ident()}


def test_handoff_runs_calls_in_order_and_post_does_not_wait():
    gate, done = threading.Event(), []
    h = Handoff()
    h.post(gate.wait, 30.0)  # a write stuck behind another process's fsync
    for k in range(5):
        h.post(done.append, k)
    assert done == [] and not gate.is_set()  # post returned while the first call still waits
    gate.set()
    h.close()
    assert done == [0, 1, 2, 3, 4]
    assert h.posted == 6 and h.peak_backlog >= 1


def test_a_failed_write_stops_what_follows_and_reaches_the_reading_thread():
    done: list = []

    def disk_full() -> None:
        raise OSError(28, "No space left on device")

    h = Handoff()
    h.post(done.append, 1)
    h.post(disk_full)
    h.post(done.append, 2)  # queued behind the failure: never run out of order
    with pytest.raises(OSError, match="No space"):
        h.close()
    assert done == [1]
    with pytest.raises(OSError, match="No space"):  # and no later post runs either
        h.post(done.append, 3)
    assert done == [1]


def test_inline_handoff_runs_at_once():
    done: list = []
    h = Handoff(threaded=False)
    h.post(done.append, 1)
    assert done == [1]
    h.close()


def test_running_calibration_imports_nothing_during_the_recording():
    """Its first refit used to import scipy.optimize on the reading thread (0.4 s: a FIFO overflow
    after the first hold of every `record --rerun`); the constructor now runs the fit once."""
    code = (
        "import sys, numpy as np\n"
        "from accellog.flows.record import RunningCalibration\n"
        "shown = []\n"
        "class View:\n"
        "    def running_calibration(self, text): shown.append(text)\n"
        "rc = RunningCalibration(View(), warn=sys.exit)\n"
        "before = set(sys.modules)\n"
        "class Label: name, up_sensor = '+z', (0.0, 0.0, 1.0)\n"
        "rc(Label(), np.array([0.0, 0.0, 1.0]), np.full(3, 1e-3), 1000)\n"
        "assert shown and 'running model1' in shown[0], shown\n"
        "print(sorted(set(sys.modules) - before))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def _scheduling() -> tuple:
    import os

    return os.sched_getscheduler(0), os.sched_getparam(0).sched_priority, os.nice(0)


def test_raised_priority_is_given_back():
    """The read loop's thread runs raised inside the block only: a recording made in-process (a
    notebook, the test suite) leaves the caller's thread, and the threads it starts later, as they
    were."""
    from accellog.acquire.recorder import raised_priority

    before = _scheduling()
    with raised_priority() as what:
        raised = _scheduling() != before  # SCHED_RR, else a lower nice value, unless not permitted
        assert raised == ("normal priority" not in what), what
    assert _scheduling() == before
    with pytest.raises(KeyError), raised_priority():
        raise KeyError("the loop failed")
    assert _scheduling() == before
