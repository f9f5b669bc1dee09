"""Clean after a kill (issue 27, item 4): leftovers of dead writers are removed by the next writer of
the same output (with a note), `import` refuses an existing output without --force, outputs honour
the umask, and a ROS 2 bag that fails leaves no temporary folder.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from support.sessions import synth_session

from accellog.cli import main
from accellog.store.atomic import pid_alive, remove_stale
from accellog.store.reader import read_session
from accellog.store.writer import write_session

ENV = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
SIM = ["simulate", "--hold", "2", "--protocol", "+z"]


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    assert not pid_alive(p.pid)
    return p.pid


def test_dead_writers_leftovers_are_removed_by_the_next_writer(tmp_path, capsys):
    dead = _dead_pid()
    out = tmp_path / "s.mcap"
    stale = [
        tmp_path / f".s.mcap.{dead}.abcdefgh.tmp",
        tmp_path / ".s.mcap.k4d3m2p7.tmp",
    ]  # new and old names
    for p in stale:
        p.write_bytes(b"half a session")
    (tmp_path / ".s.mcap.lock").write_text(f"{dead}\n")
    keep = [
        tmp_path / f".s.mcap.{os.getppid()}.abcdefgh.tmp",  # a running process's: never touched
        tmp_path / f".s.mcap.bak.{dead}.abcdefgh.tmp",  # another output's (s.mcap.bak)
        tmp_path / "notes.tmp",
    ]
    for p in keep:
        p.write_bytes(b"not ours")
    capsys.readouterr()
    assert main([*SIM, "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"removed {stale[0]}" in err and f"process {dead}, which is not running" in err
    assert f"removed {stale[1]}" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["s.mcap", *(p.name for p in keep)])
    assert read_session(out).n > 0


def test_a_killed_simulate_is_cleaned_by_the_next_run(tmp_path, capsys):
    out = tmp_path / "s.mcap"
    cmd = [sys.executable, "-m", "accellog", "simulate", "--hold", "600", "--protocol", "six", "-o", str(out)]
    proc = subprocess.Popen(cmd, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 20
        while not list(tmp_path.glob(".s.mcap.*.tmp")) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    left = sorted(p.name for p in tmp_path.iterdir())
    assert f".s.mcap.{proc.pid}." in " ".join(left) and ".s.mcap.lock" in left, left
    assert main([*SIM, "-o", str(out)]) == 0
    assert f"process {proc.pid}, which is not running" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.mcap"]


@pytest.mark.parametrize("mask, mode", [(0o022, 0o644), (0o027, 0o640), (0o002, 0o664)])
def test_outputs_honour_the_umask(tmp_path, mask, mode):
    old = os.umask(mask)
    try:
        assert main([*SIM, "-o", str(tmp_path / "s.mcap")]) == 0
        assert main(["segment", str(tmp_path / "s.mcap"), "-o", str(tmp_path / "o.json")]) == 0
    finally:
        os.umask(old)
    for name in ("s.mcap", "o.json"):
        assert (tmp_path / name).stat().st_mode & 0o777 == mode, name


def test_import_refuses_an_existing_output_without_force(tmp_path, capsys):
    src = tmp_path / "in.csv"
    t = np.arange(200) / 100.0
    src.write_text("t,ax,ay,az\n" + "".join(f"{x:.2f},0.01,-0.02,1.0\n" for x in t))
    out = tmp_path / "out.mcap"
    out.write_bytes(b"a precious session")
    capsys.readouterr()
    assert main(["import", "csv", str(src), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("accellog: error: ") and "--force" in err and "\n" not in err
    assert out.read_bytes() == b"a precious session"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.csv", "out.mcap"]
    assert main(["import", "csv", str(src), "-o", str(out), "--force"]) == 0
    assert read_session(out).n == 200


def test_ros2_bag_leaves_no_temporary_folder(tmp_path, capsys):
    """A writer that fails inside leaves nothing; a killed writer's .bagtmp/ is removed by the next
    `apply --ros2` of the same output."""
    from accellog.store.ros2_writer import Ros2BagWriter

    with pytest.raises(RuntimeError, match="boom"), Ros2BagWriter(tmp_path / "b.mcap"):
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []

    s = synth_session(seed=3, hold_s=5.0, move_s=1.0, rate_hz=100.0)
    mcap = write_session(tmp_path / "six.mcap", s)
    assert main(["fit", str(mcap), "--model", "model3", "-o", str(tmp_path / "cal.json")]) == 0
    dead = _dead_pid()
    stale = tmp_path / f".r.{dead}.bagtmp"
    (stale / "sub").mkdir(parents=True)
    (stale / "sub" / "r_0.mcap").write_bytes(b"half a bag")
    capsys.readouterr()
    argv = ["apply", str(mcap), "--cal", str(tmp_path / "cal.json"), "-o", str(tmp_path / "c.mcap")]
    assert main([*argv, "--ros2", str(tmp_path / "r.mcap")]) == 0
    assert f"removed {stale}" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.mcap", "cal.json", "r.mcap", "six.mcap"]


def test_remove_stale_keeps_live_and_foreign_entries(tmp_path):
    dead = _dead_pid()
    (tmp_path / f".x.{dead}.bagtmp").mkdir()
    (tmp_path / f".x.{os.getpid()}.bagtmp").mkdir()  # this process's own
    (tmp_path / f".xy.{dead}.bagtmp").mkdir()  # another output
    (tmp_path / f".x.{dead}.bagtmp.keep").write_text("")
    assert remove_stale(tmp_path, ".x.", "bagtmp") == [f".x.{dead}.bagtmp"]
    assert len(list(tmp_path.iterdir())) == 3


def test_ros2_bag_folder_holds_plainly_named_files(tmp_path):
    """A bag folder's files are named after the folder (not after the temporary name)."""
    from accellog.store.ros2_writer import Ros2BagWriter

    with Ros2BagWriter(tmp_path / "bag") as w:
        w.write_temperature(np.array([1_000_000_000, 1_100_000_000]), np.array([25.0, 25.1]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]
    assert sorted(p.name for p in (tmp_path / "bag").iterdir()) == ["bag.mcap", "metadata.yaml"]


def test_a_killed_record_leaves_its_data_and_the_next_run_clears_the_lock(tmp_path, capsys):
    """A live recording writes under its real name (a crash keeps the data); its lock file, left by
    the kill, is removed by the next run, which still refuses the existing file without --force."""
    out = tmp_path / "rec.mcap"
    cmd = [
        sys.executable,
        "-m",
        "accellog",
        "record",
        "--sim",
        "--hold",
        "30",
        "--protocol",
        "+z",
        "-o",
        str(out),
    ]
    proc = subprocess.Popen(cmd, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 20
        while not (tmp_path / ".rec.mcap.lock").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.3)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert (tmp_path / ".rec.mcap.lock").read_text().strip() == str(proc.pid)
    data = out.read_bytes()
    capsys.readouterr()
    assert main(["record", "--sim", "--fast", "--hold", "1", "--protocol", "+z", "-o", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    assert out.read_bytes() == data  # the killed recording's data is kept
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.mcap"]
