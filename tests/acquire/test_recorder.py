"""accellog.acquire.recorder on the emulated chip: guided holds labelled inside the true static holds, timeouts,
every sample written or accounted for, and `accellog record` surviving Ctrl-C and kill -9.

In-process tests use the SimClock (a guided six-pose session takes about a second); the signal tests
run `accellog record --sim` as a real subprocess.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from accellog.acquire.driver import Mpu9250
from accellog.acquire.emulator.chip import EmulatedMpu9250
from accellog.acquire.emulator.clock import SimClock
from accellog.acquire.emulator.sensor_model import AccelErrors, GyroErrors, SensorModel
from accellog.acquire.recorder import Recorder
from accellog.core.kinematics import Kinematics
from accellog.core.protocol import parse_protocol
from accellog.core.rotations import quat_from_axis_angle, rotate_inverse
from accellog.core.session import Session, SessionMeta
from accellog.flows.simulate import Scenario, build_sensor_model
from accellog.store.reader import read_session
from accellog.store.writer import SessionWriter

RATE_HZ = 200.0
PACKET_BYTES = 14


class Rig:
    """Emulated chip on a SimClock -> Mpu9250 driver -> Recorder -> SessionWriter, like `record --sim --fast`."""

    def __init__(self, path: Path, model: SensorModel, motion=None, *, i2c_error_rate: float = 0.0) -> None:
        self.path, self.motion = path, motion
        self.clock = SimClock()
        self.chip = EmulatedMpu9250(model, self.clock, seed=3, i2c_error_rate=i2c_error_rate)
        self.driver = Mpu9250(self.chip, clock_ns=self.clock.now_ns)
        self.driver.probe()
        cfg = self.driver.configure(sample_rate_div=round(1000.0 / RATE_HZ) - 1)
        self.meta = SessionMeta(
            source="emulator",
            accel_lsb_per_g=cfg.accel_lsb_per_g,
            gyro_lsb_per_dps=cfg.gyro_lsb_per_dps,
            sample_rate_hz=cfg.sample_rate_hz,
        )

    def run(self, protocol: str, hold_s: float, **kw):
        with SessionWriter(self.path, self.meta) as w:
            self.driver.start()
            rec = Recorder(self.driver, w, sleep=self.clock.sleep)
            summary = rec.run(parse_protocol(protocol, hold_s), **kw)
        return summary, read_session(self.path)

    def true_holds_s(self) -> list[tuple[float, float]]:
        """The motion's static holds on the session's time axis (s)."""
        a = self.chip.session_time_s(self.motion.hold_start_s)
        b = self.chip.session_time_s(self.motion.hold_end_s)
        return [(float(x), float(y)) for x, y in zip(a, b, strict=True)]

    def produced(self) -> int:
        """Samples the chip put in its FIFO since the stream started that have left it (read or lost)."""
        return self.chip.fifo_samples_pushed - self.chip.fifo_count // PACKET_BYTES


def guided_rig(path: Path, hold_s: float, extra_s: float = 6.0, **kw) -> Rig:
    """The operator holds every pose extra_s longer than the recorder needs (as `record --sim` does)."""
    sc = Scenario(protocol="six", hold_s=hold_s + extra_s, sample_rate_hz=RATE_HZ, seed=1)
    model, motion = build_sensor_model(sc)
    return Rig(path, model, motion, **kw)


def check_accounting(s: Session, summary, rig: Rig) -> None:
    """recorded + lost == produced, and every gap in sample_index is an event's lost_samples."""
    assert s.n == summary.samples
    assert s.n + s.lost_samples() == rig.produced()
    assert int(s.sample_index[-1]) + 1 == s.n + s.lost_samples()
    np.testing.assert_allclose(s.t_s, s.sample_index / RATE_HZ, atol=1e-9)
    assert np.all(np.diff(s.sample_index) >= 1)  # indices only ever move forward
    missing = np.setdiff1d(np.arange(int(s.sample_index[-1]) + 1), s.sample_index)
    said = [np.arange(e.sample_index, e.sample_index + e.lost_samples) for e in s.events if e.lost_samples]
    said_lost = np.sort(np.concatenate(said)) if said else np.zeros(0, int)
    assert np.array_equal(said_lost, missing)  # the events name exactly the missing indices, once each


# ------------------------------------------------------------------------------------------ guided run


def test_guided_run_labels_inside_true_holds(tmp_path):
    rig = guided_rig(tmp_path / "g.mcap", hold_s=5.0)
    summary, s = rig.run("six", 5.0)
    assert (
        [p.name for p in s.poses] == ["+z", "-z", "+y", "-y", "+x", "-x"] == [p.name for p in summary.poses]
    )
    holds = rig.true_holds_s()
    for p, (h0, h1) in zip(s.poses, holds, strict=True):
        assert h0 <= p.start_s and p.end_s <= h1, (p, h0, h1)
        assert 5.0 - 1e-9 <= p.end_s - p.start_s < 5.0 + 0.05  # the pose's hold time, to one FIFO read
    # after each prompt the recorder waited for the move, then for stillness: settle_s (1 s) counted
    # from the start of the first still 0.5 s window, which may reach back into the move's tail
    for p, (h0, _) in zip(s.poses[1:], holds[1:], strict=True):
        assert h0 + 0.5 <= p.start_s < h0 + 1.5
    prompts = [e for e in s.events if e.kind == "pose_prompt"]
    assert len(prompts) == 6
    assert all(pr.t_s <= p.start_s for pr, p in zip(prompts, s.poses, strict=True))
    # the labelled samples are static in the truth: the chip's up vector, no rotation
    for p in s.poses:
        tr = rig.chip.truth_for_session(np.linspace(p.start_s, p.end_s, 50))
        assert np.all(tr.omega_dps == 0.0)
        np.testing.assert_allclose(tr.specific_force_g, np.tile(p.up_sensor, (50, 1)), atol=1e-12)


def test_clean_run_writes_every_sample(tmp_path):
    rig = guided_rig(tmp_path / "c.mcap", hold_s=3.0)
    summary, s = rig.run("+z,-z", 3.0)
    assert summary.lost_samples == 0 and s.lost_samples() == 0
    assert np.array_equal(s.sample_index, np.arange(s.n))  # contiguous from 0
    assert not [e for e in s.events if e.kind not in ("pose_prompt",)]
    check_accounting(s, summary, rig)


def test_i2c_errors_every_lost_sample_accounted(tmp_path):
    rig = guided_rig(tmp_path / "e.mcap", hold_s=4.0, i2c_error_rate=0.08)
    summary, s = rig.run("six", 4.0)
    kinds = Counter(e.kind for e in s.events)
    assert kinds["retry"] > 20 and kinds["i2c_error"] > 0 and s.lost_samples() > 0
    assert rig.chip.errors_injected >= kinds["retry"]
    check_accounting(s, summary, rig)
    assert summary.lost_samples == s.lost_samples()
    # labels still inside the true holds: the index (and time) moves on over every gap
    for p, (h0, h1) in zip(s.poses, rig.true_holds_s(), strict=True):
        assert h0 <= p.start_s and p.end_s <= h1


class Wobble:
    """Never still: '+z' up, rocking +-10 deg about x at 1.5 Hz (a hand that cannot hold the sensor)."""

    duration_s = 600.0
    local_gravity_mps2 = 9.80665

    def kinematics(self, t_s) -> Kinematics:
        t = np.asarray(t_s, float).reshape(-1)
        w = 2 * np.pi * 1.5
        ang = np.deg2rad(10.0) * np.sin(w * t)
        q = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), ang)
        f = rotate_inverse(q, np.tile([0.0, 0.0, 1.0], (t.size, 1)))
        omega = np.zeros((t.size, 3))
        omega[:, 0] = np.rad2deg(np.deg2rad(10.0) * w * np.cos(w * t))
        z = np.zeros((t.size, 3))
        return Kinematics(t, f, omega, z, z.copy(), q)

    def labels(self):
        return []


def test_pose_never_still_times_out_with_event(tmp_path):
    model = SensorModel(Wobble(), AccelErrors.datasheet(7), GyroErrors.datasheet(7), seed=1)
    rig = Rig(tmp_path / "w.mcap", model)
    summary, s = rig.run("+z,-z", 3.0, timeout_s=6.0)
    assert summary.poses == [] and s.poses == []
    notes = [e for e in s.events if e.kind == "note"]
    assert [n.detail for n in notes] == [
        "pose +z: not still within 6 s, skipped",
        "pose -z: not still within 6 s, skipped",
    ]
    assert 6.0 <= notes[0].t_s < 6.1 and 12.0 <= notes[1].t_s < 12.1  # each waited its timeout
    assert s.t_s[-1] >= 12.0 and s.lost_samples() == 0  # and the stream was recorded all along


def test_hold_cut_short_by_a_move_is_noted(tmp_path):
    """The operator turns the sensor before the hold is over: the label is written with a note."""
    rig = guided_rig(tmp_path / "m.mcap", hold_s=5.0, extra_s=-1.5)
    _, s = rig.run("+z,-z", 5.0)
    moved = [e for e in s.events if e.kind == "note" and "moved during the hold" in e.detail]
    assert moved and moved[0].detail.startswith("pose +z")


def test_enter_key_labels_where_the_operator_pressed(tmp_path):
    class Presses:
        """The operator presses Enter on the n-th check after each prompt."""

        def __init__(self, n: int) -> None:
            self.n, self.calls = n, 0

        def pressed(self) -> bool:
            self.calls += 1
            if self.calls == self.n:
                self.calls = 0
                return True
            return False

    rig = guided_rig(tmp_path / "k.mcap", hold_s=3.0)
    _, s = rig.run("+z,-z", 3.0, wait="enter", enter=Presses(40))  # 40 reads of 20 ms = 0.8 s
    assert [p.name for p in s.poses] == ["+z", "-z"]
    assert abs(s.poses[0].start_s - 0.8) < 0.05
    assert abs(s.poses[1].start_s - (s.poses[0].end_s + 0.8)) < 0.05


# ------------------------------------------------------------------------------------------ signals

CLI = [sys.executable, "-c", "import sys; from accellog.cli import main; sys.exit(main())", "record"]


class RecordProcess:
    """`accellog record --sim ...` in a subprocess; stderr read by a thread, lines in a queue."""

    def __init__(self, out: Path, *args: str) -> None:
        env = dict(os.environ, RERUN_ANALYTICS="0")
        self.p = subprocess.Popen(
            [*CLI, "-o", str(out), "--sim", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self.stderr: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.p.stderr:
            self.stderr.append(line)
            self.lines.put(line)
        self.lines.put("")

    def wait_started(self, timeout_s: float = 120.0) -> float:
        """Block until the first pose prompt (the FIFO stream and the file are open); its time."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                break
            if "pose 1/" in line:
                return time.monotonic()
            if line == "":
                break
        self.p.kill()
        pytest.fail("recorder did not start: " + "".join(self.stderr))

    def finish(self, timeout_s: float = 120.0) -> int:
        rc = self.p.wait(timeout=timeout_s)
        time.sleep(0.1)  # let the reader thread drain stderr
        return rc


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_interrupt_finishes_the_file_cleanly(tmp_path, sig):
    out = tmp_path / "i.mcap"
    rp = RecordProcess(out, "--fast", "--hold", "1000", "--rate", "200")
    rp.wait_started()
    time.sleep(0.7)
    rp.p.send_signal(sig)
    rc = rp.finish()
    err = "".join(rp.stderr)
    assert rc in (0, 130) and "Traceback" not in err, err
    assert "(interrupted)" in err
    s = read_session(out)  # a finished file: the normal reader, nothing salvaged
    assert not [e for e in s.events if e.kind == "recovered"]
    assert [e for e in s.events if e.kind == "note" and "interrupted" in e.detail]
    assert s.n > 100 and np.array_equal(s.sample_index, np.arange(s.n))


def test_kill_9_loses_at_most_about_a_second(tmp_path):
    out = tmp_path / "k.mcap"
    rp = RecordProcess(out, "--hold", "30", "--no-mag")
    t_start = rp.wait_started()
    # the file is being written (schemas on disk at the first data) ...
    deadline = time.monotonic() + 30.0
    while (not out.exists() or out.stat().st_size == 0) and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(max(0.0, 3.0 - (time.monotonic() - t_start)))
    rp.p.kill()
    t_kill = time.monotonic()
    rp.finish()
    elapsed = t_kill - t_start  # <= the real recording time (the stream starts before the prompt)
    s = read_session(out)
    recovered = [e for e in s.events if e.kind == "recovered"]
    assert recovered, "a killed recorder cannot have finished its file"
    assert s.t_s[-1] >= elapsed - 1.2, (s.t_s[-1], elapsed, recovered[0].detail)
    # what was salvaged is consistent: every gap accounted by an event
    assert int(s.sample_index[-1]) + 1 == s.n + sum(e.lost_samples for e in s.events)
