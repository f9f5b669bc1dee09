"""`replay --rrd` written by a child process (present.rrd.offload): the same recording as in-process,
a failing or killed child is one line and no file, a bad output is refused before any work, and a
killed or interrupted parent leaves neither a running child nor a temporary file."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from accellog.cli import main
from accellog.core.errors import InputError
from accellog.core.session import Event, PoseLabel, Session, SessionMeta
from accellog.flows.stages import run_fit
from accellog.present.rrd import offload, offload_process
from accellog.present.rrd.recording import RunRecording
from accellog.store.atomic import OutputLock, pid_alive
from accellog.store.writer import write_session

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rrd_readback import load_rrd

ROOT = Path(__file__).resolve().parents[2]
LSB = 16384.0
UPS = [(0, 0, 1), (0, 0, -1), (0, 1, 0), (0, -1, 0), (1, 0, 0), (-1, 0, 0)]


def _session(f_g: np.ndarray, rate: float, rng, poses=(), events=(), temp=None) -> Session:
    n = f_g.shape[0]
    counts = np.round((f_g * 1.01 + 0.02 + rng.normal(0.0, 0.002, f_g.shape)) * LSB).astype(np.int32)
    meta = SessionMeta(source="emulator", accel_range_g=2.0, accel_lsb_per_g=LSB, sample_rate_hz=rate,
                       local_gravity_mps2=9.797)  # fmt: skip
    return Session(meta=meta, t_s=np.arange(n) / rate, sample_index=np.arange(n, dtype=np.int64),
                   accel_g=counts / LSB, accel_counts=counts, temp_degC=temp, poses=list(poses),
                   events=list(events))  # fmt: skip


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A model3 calibration (six poses), a 50 s session at 1 kHz (long enough for display envelopes:
    more than FULL_RATE_MAX_SAMPLES samples) with two holds, an event and temperature, and a 30 s
    static session without labels."""
    d = tmp_path_factory.mktemp("offload")
    rng = np.random.default_rng(7)
    per = 800
    f = np.concatenate([np.tile(np.array(u, float), (per, 1)) for u in UPS])
    poses = [PoseLabel(f"p{k}", k * 4 + 0.2, (k + 1) * 4 - 0.2, u, None, k) for k, u in enumerate(UPS)]
    write_session(d / "cal.mcap", _session(f, 200.0, rng, poses))
    run_fit(d / "cal.mcap", "model3", gravity="seed", weighted=False).cal.save(d / "model3.json")
    n = 50_000
    f = np.tile([0.0, 0.0, 1.0], (n, 1))
    f[31_000, 0] += 2.5  # a spike the envelope keeps
    holds = [PoseLabel("+z", 1.0, 20.0, (0, 0, 1), None, 0), PoseLabel("+z", 25.0, 45.0, (0, 0, 1), None, 1)]
    events = [Event(12.5, "note", "a note"), Event(30.0, "gap", "3 samples missing", 30_000, 3)]
    s = _session(f, 1000.0, rng, holds, events, temp=30.0 + np.linspace(0, 0.8, n))
    write_session(d / "test.mcap", s, batch_size=1000)
    n = 30_000  # a static test in one orientation (evaluate, drift, run)
    write_session(d / "still.mcap", _session(f[:n], 1000.0, rng, temp=30.0 + np.linspace(0, 0.3, n)))
    return {"test": d / "test.mcap", "still": d / "still.mcap", "model3": d / "model3.json"}


@pytest.fixture
def writers(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The process ids of the writer children started (the real ones: only counted)."""
    offload_process.stop_unclaimed()
    started: list[int] = []
    init = offload_process.Writer.__init__

    def counted(self) -> None:
        init(self)
        started.append(self.proc.pid)

    monkeypatch.setattr(offload_process.Writer, "__init__", counted)
    return started


def _cli(args: list[str], **kw) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "RERUN_ANALYTICS": "0", "ACCELLOG_RRD_CHILD": "1"}
    return subprocess.Popen([sys.executable, "-m", "accellog", *args], env=env, stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # a background job ignores it
                            **kw)  # fmt: skip


def _children(pid: int) -> list[int]:
    try:
        return [int(p) for p in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _child_of(pid: int, timeout_s: float = 30.0) -> int:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        kids = _children(pid)
        if kids:
            return kids[0]
        time.sleep(0.02)
    raise AssertionError("no writer child started")


def _gone(pid: int, timeout_s: float = 20.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if not pid_alive(pid) or "State:\tZ" in _status(pid):
            return True
        time.sleep(0.05)
    return False


def _status(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return ""


def _left(folder: Path) -> list[str]:
    """What an aborted write may leave: the output, temporary files (a lock file is not checked)."""
    return sorted(p.name for p in folder.iterdir() if not p.name.endswith(".lock"))


@pytest.mark.parametrize("command", ["replay", "compare"])
def test_child_writes_the_recording_in_process_writes(
    files, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, writers: list[int], command: str, capsys
) -> None:
    outs = {}
    for mode in ("0", "1"):
        monkeypatch.setenv("ACCELLOG_RRD_CHILD", mode)
        out = tmp_path / f"{command}_{mode}.rrd"
        args = [command, str(files["test"]), "--cal", str(files["model3"]), "--up", "+z", "--rrd", str(out)]
        assert main(args + (["--speed", "max"] if command == "replay" else [])) == 0
        assert len(writers) == (1 if mode == "1" else 0)
        outs[mode] = load_rrd(out)
    capsys.readouterr()
    a, b = outs["0"], outs["1"]
    assert a.entities == b.entities and len(a.entities) >= 12
    for ent in a.entities:
        assert a.components(ent) == b.components(ent), ent
        rows = [sum(c.num_rows for c in r.chunks[ent]) for r in (a, b)]
        assert rows[0] == rows[1], ent
        if "Scalars:scalars" in a.components(ent):
            for timeline in ("sensor_time", "sample") if ent.startswith("/accel/raw") else ("sensor_time",):
                (ta, va), (tb, vb) = a.series(ent, timeline), b.series(ent, timeline)
                np.testing.assert_array_equal(ta, tb)
                np.testing.assert_array_equal(va, vb)
    t, v = b.series("accel/raw")
    assert 1000 < len(t) < 20_000 and v[:, 0].max() > 2.5  # an envelope, with the spike
    assert a.texts("events") == b.texts("events") and len(a.texts("events")) == 2
    assert a.texts("poses/log") == b.texts("poses/log") and len(a.texts("poses/log")) == 2
    doc = "docs/replay/final_displacement"
    assert a.static(doc, "TextDocument:text") == b.static(doc, "TextDocument:text")
    assert sorted(map(repr, a.views())) == sorted(map(repr, b.views()))
    assert len(writers) == 1 and _gone(writers[0])


def test_a_failure_in_the_child_is_its_error_and_no_file(tmp_path: Path) -> None:
    """What RunRecording raises at once in-process, the child's recording raises at close: the same
    error; the temporary file is gone and the child has exited."""
    bad = ("m", ["a", "b"], np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(InputError) as here, RunRecording(f"save:{tmp_path / 'a.rrd'}") as rec:
        rec.log_residuals(*bad)
    rec = offload.OffloadedRecording(f"save:{tmp_path / 'b.rrd'}")
    pid = rec.pid
    rec.log_samples("raw", np.arange(10.0), None, np.zeros((10, 3)), "g")
    rec.log_residuals(*bad)
    with pytest.raises(InputError) as there:
        rec.close()
    assert str(there.value) == str(here.value)
    assert _left(tmp_path) == [] and rec.pid is None and pid is not None and not pid_alive(pid)


def test_child_killed_mid_run_is_one_line_and_no_file(files, tmp_path: Path) -> None:
    out = tmp_path / "out" / "r.rrd"
    out.parent.mkdir()
    p = _cli(["replay", str(files["test"]), "--speed", "10", "--up", "+z", "--rrd", str(out)])
    child = _child_of(p.pid)
    time.sleep(1.5)  # the child has imported rerun and logs
    os.kill(child, signal.SIGKILL)
    _, stderr = p.communicate(timeout=60)
    assert p.returncode == 2, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("accellog: error: ") and "Traceback" not in stderr
    assert str(out) in lines[0] and "was killed by SIGKILL" in lines[0], lines
    assert _left(out.parent) == [] and not (out.parent / ".r.rrd.lock").exists()


@pytest.mark.parametrize("how", ["SIGKILL", "SIGTERM", "SIGINT"])
def test_killed_or_interrupted_parent_leaves_no_child_and_no_file(files, tmp_path: Path, how: str) -> None:
    out = tmp_path / "out" / "r.rrd"
    out.parent.mkdir()
    p = _cli(["replay", str(files["test"]), "--speed", "10", "--up", "+z", "--rrd", str(out)])
    child = _child_of(p.pid)
    time.sleep(1.5)
    os.kill(p.pid, getattr(signal, how))
    _, stderr = p.communicate(timeout=60)
    assert _gone(child), "the writer child still runs"
    if how == "SIGINT":  # Ctrl-C: the parent stops the child and removes the file itself
        assert p.returncode == 130 and "Traceback" not in stderr
    assert _left(out.parent) == []  # the child removed the temporary file of its dead parent
    # the next writer of the same output takes the stale lock over
    q = _cli(["replay", str(files["test"]), "--speed", "max", "--up", "+z", "--rrd", str(out)])
    q.communicate(timeout=120)
    assert q.returncode == 0 and _left(out.parent) == ["r.rrd"]


def test_the_child_starts_before_the_commands_imports_and_ends_with_a_failed_command(tmp_path: Path) -> None:
    """`accellog replay ... --rrd` starts the writer before typer and the command are imported (its
    `import rerun` runs beside theirs); a command that then fails stops it and leaves no file."""
    probe = (
        "import sys\n"
        "from accellog.present.rrd import offload_process as op\n"
        "init, seen = op.Writer.__init__, []\n"
        "def counted(self):\n"
        "    seen.append(('typer' in sys.modules, 'accellog.flows.replay' in sys.modules))\n"
        "    init(self)\n"
        "    seen.append(self.proc.pid)\n"
        "op.Writer.__init__ = counted\n"
        "from accellog.cli import main\n"
        "rc = main(sys.argv[1:])\n"
        "print(rc, seen[0], op.started(), seen[1])\n"
    )
    out = tmp_path / "r.rrd"
    res = subprocess.run(
        [sys.executable, "-c", probe, "replay", str(tmp_path / "missing.mcap"), "--rrd", str(out)],
        env={**os.environ, "PYTHONPATH": str(ROOT), "RERUN_ANALYTICS": "0", "ACCELLOG_RRD_CHILD": "1"},
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.stdout.startswith("2 (False, False) False "), (res.stdout, res.stderr)
    assert _gone(int(res.stdout.split()[-1])) and not out.exists()
    assert res.stderr.count("\n") == 1 and "missing.mcap" in res.stderr


def test_bad_output_fails_before_any_work_as_in_process(
    files, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    (tmp_path / "dir.rrd").mkdir()
    locked = tmp_path / "locked.rrd"
    bad = [tmp_path / "dir.rrd", tmp_path / "missing" / "x.rrd", locked]
    with OutputLock(locked):  # another writer of that file right now
        for out in bad:
            errs = []
            for mode in ("0", "1"):
                monkeypatch.setenv("ACCELLOG_RRD_CHILD", mode)
                args = ["replay", str(files["test"]), "--speed", "max", "--cal", str(files["model3"])]
                assert main([*args, "--rrd", str(out)]) == 2
                res = capsys.readouterr()
                assert res.out == ""  # nothing replayed
                errs.append(res.err)
            assert errs[0] == errs[1] and errs[0].count("\n") == 1 and errs[0].startswith("accellog: error:")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.rrd"]


def test_one_core_stays_in_process(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ACCELLOG_RRD_CHILD", raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: 1)
    assert not offload_process.use_child()
    monkeypatch.setenv("ACCELLOG_RRD_CHILD", "0")
    monkeypatch.setattr(os, "cpu_count", lambda: 8)
    assert not offload_process.use_child()


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("robot") / "robot.mcap"
    assert main(["simulate", "--motion", "robot", "-o", str(out)]) == 0
    return out


@pytest.mark.parametrize("command", ["fit", "drift", "evaluate", "track", "run"])
def test_other_commands_write_the_recording_in_process_writes(
    command: str, files, robot, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, writers: list[int], capsys
) -> None:
    cal_session = files["test"].with_name("cal.mcap")
    args = {
        "fit": ["fit", str(cal_session), "-o", str(tmp_path / "c.json"), "--force"],  # run twice
        "drift": [
            "drift",
            str(files["still"]),
            "--cal",
            str(files["model3"]),
            "-o",
            str(tmp_path / "d.json"),
            "--force",
        ],
        "evaluate": ["evaluate", str(files["still"]), "--cal", str(files["model3"])],
        "track": ["track", str(robot), "--cal", str(files["model3"])],
        "run": [
            "run",
            str(ROOT / "pipelines" / "six_position.toml"),
            str(cal_session),
            *[str(files["still"])] * 3,
        ],
    }[command]
    outs = {}
    for mode in ("0", "1"):
        monkeypatch.setenv("ACCELLOG_RRD_CHILD", mode)
        out = tmp_path / f"{mode}.rrd"
        assert main([*args, "--rrd", str(out)]) == 0, capsys.readouterr().err
        assert len(writers) == (1 if mode == "1" else 0)
        outs[mode] = load_rrd(out)
    capsys.readouterr()
    a, b = outs["0"], outs["1"]
    assert a.entities == b.entities and len(a.entities) >= 5
    for ent in a.entities:
        assert a.components(ent) == b.components(ent), ent
        assert sum(c.num_rows for c in a.chunks[ent]) == sum(c.num_rows for c in b.chunks[ent]), ent
        if "Scalars:scalars" in a.components(ent) and "sensor_time" in a.chunks[ent][0].schema.names:
            for x, y in zip(a.series(ent), b.series(ent), strict=True):
                np.testing.assert_array_equal(x, y)
    assert sorted(map(repr, a.views())) == sorted(map(repr, b.views()))
