"""A full file system (issue 46, item 5): every command that writes fails with one line, leaves no
temporary or lock file (nor a folder it made) and the next run works once there is room; a command
with two outputs, one on a read-only file system, writes neither.

The full disk is a 2 MiB tmpfs mounted for the test (root only; skipped elsewhere) and filled to
its last KiBs, so that each command runs out of space part-way through writing.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from support.refusal import assert_refused
from support.sessions import synth_session

from accellog.cli import main
from accellog.store.reader import read_session
from accellog.store.writer import write_session

ROOM_KIB = 24
"""What the filler leaves free: less than any output below needs."""


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("full_disk_inputs")
    write_session(d / "six.mcap", synth_session(seed=9, hold_s=5.0, move_s=1.0, rate_hz=100.0))
    rows = ["t,ax,ay,az"] + [f"{i * 0.01:.2f},0.001,0.002,1.00{i % 7}" for i in range(40_000)]
    (d / "long.csv").write_text("\n".join(rows) + "\n")  # ~1 MB of text, ~0.3 MB as MCAP
    return d


def _tmpfs(mnt: Path, options: str) -> None:
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(mnt)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs: {r.stderr.decode().strip()}")


@pytest.fixture
def full(tmp_path) -> Path:
    """tmp_path/full: a 2 MiB tmpfs with ROOM_KIB free (unmounted afterwards)."""
    mnt = tmp_path / "full"
    _tmpfs(mnt, "size=2m")
    try:
        st = os.statvfs(mnt)
        (mnt / "filler").write_bytes(b"\xff" * (st.f_bavail * st.f_frsize - ROOM_KIB * 1024))
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


@pytest.fixture
def read_only(tmp_path) -> Path:
    mnt = tmp_path / "ro"
    _tmpfs(mnt, "size=1m,ro")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def _room(full: Path) -> None:
    (full / "filler").unlink()


def test_import_on_a_full_disk_leaves_no_temporary_or_lock_file(inputs, full, tmp_path, capsys):
    argv = ["import", "csv", str(inputs / "long.csv"), "-o", str(full / "o.mcap")]
    assert_refused(argv, full, capsys, ("No space left on device",))
    _room(full)
    assert main(argv) == 0
    assert sorted(p.name for p in full.iterdir()) == ["o.mcap"]


def test_a_recording_on_a_full_disk_releases_its_lock_and_says_what_it_kept(inputs, full, capsys):
    out = full / "r.mcap"
    argv = ["record", "--sim", "--fast", "--hold", "30", "--protocol", "six", "-o", str(out)]
    capsys.readouterr()
    assert main(argv) != 0
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(f"accellog: error: {out}: cannot finish the MCAP file: No space left"), err
    assert "samples, without its summary" in err
    assert sorted(p.name for p in full.iterdir()) == ["filler", "r.mcap"]  # no .r.mcap.lock
    assert read_session(out).n > 0  # the chunks written before the disk filled
    _room(full)
    assert main([*argv[:-4], "--hold", "2", "--protocol", "+z", "-o", str(out), "--force"]) == 0


@pytest.mark.parametrize(
    "argv",
    [
        ["doctor", "{in}/six.mcap", "--rrd", "{full}/d.rrd"],  # rerun's file sink in this process
        ["simulate", "--fleet", "3", "--fleet-sessions", "1", "--hold", "5", "-o", "{full}/fleet"],
        ["demo", "--quick", "--no-rrd", "-o", "{full}/demo/new"],
    ],
    ids=["doctor-rrd", "simulate-fleet", "demo"],
)
def test_a_full_disk_leaves_no_partial_file_or_folder(argv, inputs, full, capsys):
    argv = [a.format(**{"in": inputs, "full": full}) for a in argv]
    capsys.readouterr()
    assert main(argv) != 0
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err, err
    assert err.splitlines()[-1].startswith("accellog: error: "), err
    assert [p.name for p in full.iterdir()] == ["filler"]


def test_apply_with_its_ros2_bag_on_a_read_only_folder_writes_neither(inputs, read_only, tmp_path, capsys):
    d = tmp_path / "case"
    d.mkdir()
    (d / "six.mcap").write_bytes((inputs / "six.mcap").read_bytes())
    assert main(["fit", str(d / "six.mcap"), "-o", str(d / "cal.json")]) == 0
    argv = ["apply", str(d / "six.mcap"), "--cal", str(d / "cal.json"), "-o", str(d / "o.mcap")]
    assert_refused([*argv, "--ros2", str(read_only / "bag")], d, capsys, ("Read-only file system",))
    assert main([*argv, "--ros2", str(d / "bag")]) == 0  # the next run, somewhere writable


def test_an_rrd_on_a_full_disk_is_one_line_from_a_real_process(inputs, full):
    """rerun's own log lines about its failing file sink stay quiet (present.rrd.sdk): the command's
    stderr is its one error line."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2]), "RERUN_ANALYTICS": "0"}
    env.pop("RUST_LOG", None)
    argv = [sys.executable, "-m", "accellog", "noise", str(inputs / "six.mcap"), "--rrd", str(full / "n.rrd")]
    r = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert lines[0].startswith(f"accellog: error: {full / 'n.rrd'}: cannot write the recording"), lines
    assert "file system is full" in lines[0]
    assert [p.name for p in full.iterdir()] == ["filler"]
