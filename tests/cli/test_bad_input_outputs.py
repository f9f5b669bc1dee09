"""Outputs only where the user pointed, only over regular files, never over an input (issue 46).

Each case runs the CLI in-process on inputs copied into its own folder: a non-zero exit, one stderr
line ``accellog: error: ...`` naming the option or file, no traceback, and the folder exactly as
before (no output, no temporary or lock file, inputs intact). Device nodes are stood in for by a
FIFO or a socket the test makes; the real /dev/null is only named through a link the door refuses
before anything is written.
"""

from __future__ import annotations

import os
import shutil
import socket
from collections.abc import Callable
from pathlib import Path

import pytest
from support.refusal import assert_refused
from support.sessions import synth_session

from accellog.cli import main
from accellog.core.errors import InputError
from accellog.store.atomic import AtomicOutput, declared_inputs, inside, write_text_atomic
from accellog.store.writer import write_session

PIPELINE = Path(__file__).resolve().parents[2] / "pipelines" / "six_position.toml"


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("outputs_good")
    s = synth_session(seed=5, hold_s=5.0, move_s=1.0, rate_hz=100.0)
    write_session(d / "six.mcap", s, chunk_size=8 * 1024)
    assert main(["fit", str(d / "six.mcap"), "--model", "model3", "-o", str(d / "cal.json")]) == 0
    rows = ["t,ax,ay,az"] + [f"{i * 0.01:.2f},0.0,0.0,1.0" for i in range(200)]
    (d / "in.csv").write_text("\n".join(rows) + "\n")
    (d / "rec.rrd").write_bytes(b"RRF2 not really a recording")
    return d


def _fifo(d: Path, name: str = "pipe") -> str:
    os.mkfifo(d / name)
    return str(d / name)


def _socket(d: Path) -> str:
    s = socket.socket(socket.AF_UNIX)
    s.bind(str(d / "sock"))
    s.close()  # the socket file stays
    return str(d / "sock")


def _link(d: Path, target: str | Path, name: str = "link.rrd") -> str:
    (d / name).symlink_to(target)
    return str(d / name)


def _sparse(p: Path, size: int) -> str:
    with p.open("wb") as f:
        f.truncate(size)
    return str(p)


def _pipeline(d: Path, output_dir: str) -> str:
    """A one-input pipeline (fit model3) whose report goes to output_dir."""
    text = '[pipeline]\nname = "t"\ninputs = ["cal"]\n[fit]\ninput = "cal"\nmodels = ["model3"]\n'
    (d / "p.toml").write_text(text + f'[report]\noutput_dir = "{output_dir}"\n')
    return str(d / "p.toml")


M, C, V = "six.mcap", "cal.json", "in.csv"
Case = Callable[[Path], list[str]]
CASES: dict[str, tuple[Case, tuple[str, ...]]] = {
    # --rrd / -o over an input: each destroyed its input before
    "doctor-rrd-is-input": (lambda d: ["doctor", M, "--rrd", M], ("--rrd", "input file")),
    "doctor-csv-rrd-is-input": (lambda d: ["doctor", V, "--rrd", V], ("--rrd", "input file")),
    "noise-rrd-is-input": (lambda d: ["noise", M, "--rrd", M], ("--rrd", "input file")),
    "noise-out-is-input": (lambda d: ["noise", M, "-o", M], ("--out", "input file")),
    "magcal-rrd-is-input": (lambda d: ["magcal", M, "--rrd", M], ("--rrd", "input file")),
    "diagnose-rrd-is-input": (lambda d: ["diagnose", M, "--rrd", M], ("--rrd", "input file")),
    "evaluate-rrd-is-session": (lambda d: ["evaluate", M, "--cal", C, "--rrd", M], ("--rrd", "input")),
    "evaluate-rrd-is-cal": (lambda d: ["evaluate", M, "--cal", C, "--rrd", C], ("--rrd", "input")),
    "track-rrd-is-input": (lambda d: ["track", M, "--rrd", M], ("--rrd", "input file")),
    "workbench-rrd-is-input": (lambda d: ["workbench", M, "--rrd", M], ("--rrd", "input file")),
    "workbench-out-is-input": (lambda d: ["workbench", M, "-o", M], ("--output", "input file")),
    "replay-rrd-is-input": (lambda d: ["replay", M, "--cal", C, "--rrd", C], ("--rrd", "input")),
    "compare-rrd-is-input": (lambda d: ["compare", M, "--cal", C, "--rrd", M], ("--rrd", "input")),
    "view-screenshot-is-input": (lambda d: ["view", "rec.rrd", "--screenshot", "rec.rrd"], ("input",)),
    "apply-ros2-is-input": (lambda d: ["apply", M, "--cal", C, "-o", "o.mcap", "--ros2", M], ("--ros2",)),
    "run-rrd-is-input": (lambda d: ["run", str(PIPELINE), M, M, M, M, "--rrd", M], ("--rrd", "input")),
    "export-out-is-input": (lambda d: ["export", C, "--to", "yaml", "-o", C], ("input file",)),
    # by identity, whatever the name
    "rrd-symlink-to-input": (lambda d: ["doctor", M, "--rrd", _link(d, M)], ("--rrd", "input file")),
    "out-symlink-to-cal": (lambda d: ["evaluate", M, "--cal", C, "--rrd", _link(d, C)], ("input file",)),
    "rrd-hard-link-to-input": (
        lambda d: ["track", M, "--rrd", (os.link(d / M, d / "h.rrd"), "h.rrd")[1]],
        ("--rrd", "input file"),
    ),
    # never over something that is not a regular file
    "fit-out-fifo": (lambda d: ["fit", M, "-o", _fifo(d)], ("--output", "FIFO")),
    "apply-out-fifo": (lambda d: ["apply", M, "--cal", C, "-o", _fifo(d)], ("--output", "FIFO")),
    "apply-ros2-fifo": (lambda d: ["apply", M, "--cal", C, "-o", "o.mcap", "--ros2", _fifo(d)], ("FIFO",)),
    "simulate-out-fifo": (lambda d: ["simulate", "--hold", "2", "-o", _fifo(d)], ("--out", "FIFO")),
    "record-out-fifo": (lambda d: ["record", "--sim", "--fast", "-o", _fifo(d), "--force"], ("FIFO",)),
    "export-out-fifo": (lambda d: ["export", C, "--to", "yaml", "-o", _fifo(d)], ("--output", "FIFO")),
    "integrate-out-fifo": (lambda d: ["integrate", M, "-o", _fifo(d)], ("--output", "FIFO")),
    "segment-out-fifo": (lambda d: ["segment", M, "-o", _fifo(d)], ("--output", "FIFO")),
    "doctor-rrd-fifo": (lambda d: ["doctor", M, "--rrd", _fifo(d)], ("--rrd", "FIFO")),
    "view-screenshot-fifo": (lambda d: ["view", "rec.rrd", "--screenshot", _fifo(d, "s.png")], ("FIFO",)),
    "fit-out-socket": (lambda d: ["fit", M, "-o", _socket(d)], ("--output", "socket")),
    "fit-out-link-to-dev-null": (lambda d: ["fit", M, "-o", _link(d, "/dev/null")], ("character device",)),
    "doctor-rrd-link-to-fifo": (
        lambda d: ["doctor", M, "--rrd", _link(d, _fifo(d))],
        ("--rrd", "FIFO"),
    ),
    "noise-rrd-directory": (
        lambda d: ["noise", M, "--rrd", str((d / "sub").mkdir() or d / "sub")],
        ("directory",),
    ),
    "run-output-dir-is-a-file": (
        lambda d: ["run", str(PIPELINE), M, M, M, M, "-o", C],
        ("--output-dir", "not a folder"),
    ),
    "fleet-out-is-a-file": (lambda d: ["fleet", "run", str(PIPELINE), M, "-o", M], ("--out", "not a folder")),
    "demo-out-is-a-file": (lambda d: ["demo", "-o", C], ("--out", "not a folder")),
    # a data file never chooses where to write
    "pipeline-output-dir-dotdot": (
        lambda d: ["run", _pipeline(d, "../escaped"), M],
        ("p.toml:8", "report.output_dir", "'..'"),
    ),
    "pipeline-output-dir-absolute": (
        lambda d: ["run", _pipeline(d, str(d / "abs")), M],
        ("p.toml", "relative path"),
    ),
    # special files as inputs: refused before a byte is read (a FIFO would block, /dev/zero never end)
    "cal-fifo": (lambda d: ["evaluate", M, "--cal", _fifo(d, "c.json")], ("calibration file", "FIFO")),
    "cal-dev-zero": (
        lambda d: ["evaluate", M, "--cal", _link(d, "/dev/zero", "z.json")],
        ("character device",),
    ),
    "cal-dev-urandom": (
        lambda d: ["export", _link(d, "/dev/urandom", "u.json"), "--to", "yaml"],
        ("device",),
    ),
    "scenario-fifo": (
        lambda d: ["simulate", "--scenario", _fifo(d, "s.toml"), "-o", "x.mcap"],
        ("scenario file", "FIFO"),
    ),
    "scenario-dev-zero": (
        lambda d: ["simulate", "--scenario", _link(d, "/dev/zero", "s.toml"), "-o", "x.mcap"],
        ("scenario file", "character device"),
    ),
    "pipeline-fifo": (lambda d: ["run", _fifo(d, "p.toml"), M], ("pipeline file", "FIFO")),
    "pipeline-dev-urandom": (
        lambda d: ["run", _link(d, "/dev/urandom", "p.toml"), M],
        ("pipeline file", "device"),
    ),
    "effects-fifo": (
        lambda d: ["fit", M, "--add", "x", "--effects-file", _fifo(d, "fx.py"), "-o", "c.json"],
        ("effects file", "FIFO"),
    ),
    "effects-dev-zero": (
        lambda d: ["fit", M, "--add", "x", "--effects-file", _link(d, "/dev/zero", "fx.py"), "-o", "c.json"],
        ("effects file", "character device"),
    ),
    "effects-directory": (
        lambda d: [
            "fit",
            M,
            "--add",
            "x",
            "--effects-file",
            str((d / "fx").mkdir() or d / "fx"),
            "-o",
            "c.json",
        ],
        ("effects file", "directory"),
    ),
    "effects-2MiB": (
        lambda d: [
            "fit",
            M,
            "--add",
            "x",
            "--effects-file",
            _sparse(d / "fx.py", 2 * 1024**2),
            "-o",
            "c.json",
        ],
        ("effects file", "at most 1 MiB"),
    ),
    "report-fifo": (lambda d: ["report", _fifo(d, "r.json")], ("FIFO",)),
    "obs-fifo": (lambda d: ["fit", _fifo(d, "obs.json"), "-o", "c.json"], ("FIFO",)),
    "pipeline-output-dir-symlink-out": (
        lambda d: ["run", _pipeline(d, (_link(d, d.parent, "up"), "up/escaped")[1]), M],
        ("p.toml", "leads outside"),
    ),
}


@pytest.mark.parametrize("name", list(CASES))
def test_refused(name, good, tmp_path, capsys, monkeypatch):
    build, needles = CASES[name]
    d = tmp_path / "case"
    shutil.copytree(good, d)
    monkeypatch.chdir(d)
    outside = sorted(p.name for p in tmp_path.iterdir())
    assert_refused(build(d), d, capsys, needles)
    assert sorted(p.name for p in tmp_path.iterdir()) == outside, "written outside the folder"


def test_the_rename_never_replaces_a_fifo_that_appeared_meanwhile(tmp_path):
    out = tmp_path / "o.json"
    ao = AtomicOutput(out)
    tmp = ao.begin()
    tmp.write_text("{}")
    os.mkfifo(out)  # created after the checks, before the rename
    with pytest.raises(InputError, match="FIFO"):
        ao.commit()
    assert out.is_fifo() and sorted(p.name for p in tmp_path.iterdir()) == ["o.json"]


def test_declared_inputs_guard_every_writer_of_the_command(tmp_path):
    a = tmp_path / "a.mcap"
    a.write_bytes(b"input")
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "results.json").symlink_to(a)
    with declared_inputs([a]), pytest.raises(InputError, match="input file"):
        write_text_atomic(tmp_path / "o" / "results.json", "{}")
    write_text_atomic(tmp_path / "o" / "other.json", "{}")  # outside the block: the usual rules
    assert a.read_bytes() == b"input"


@pytest.mark.parametrize("rel", ["/etc/x", "../x", "a/../../x", "~/x"])
def test_inside_refuses_paths_that_leave_the_folder(tmp_path, rel):
    with pytest.raises(InputError, match="relative path"):
        inside(tmp_path, rel, "f.toml:3")


def test_inside_keeps_a_path_below_the_folder(tmp_path):
    assert inside(tmp_path, "out/run1", "f.toml:3") == tmp_path / "out" / "run1"


def test_a_pipeline_output_dir_inside_its_folder_is_written(good, tmp_path):
    d = tmp_path / "case"
    shutil.copytree(good, d)
    m = str(d / M)
    assert main(["run", _pipeline(d, "out/run1"), m]) == 0
    assert (d / "out" / "run1" / "results.json").is_file()
