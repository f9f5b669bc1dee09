"""Bad input: a one-line message naming what and where, a non-zero exit, no traceback, no output file.

Each case writes a real (broken) input file and runs the CLI through accellog.cli.main.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from mcap.writer import Writer
from support.sessions import synth_session

from accellog.cli import main
from accellog.core.session import PoseLabel
from accellog.store.writer import write_session


def _fails(capsys, argv: list[str], *needles: str, out: Path | None = None) -> str:
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc != 0, err
    assert err.startswith("accellog: error: ") and "\n" not in err and "Traceback" not in err, err
    for n in needles:
        assert n in err, (n, err)
    if out is not None:
        assert not out.exists() and not list(out.parent.glob(f".{out.name}*"))
    return err


def _fit(tmp_path: Path, session, name: str = "s.mcap") -> tuple[list[str], Path]:
    src = write_session(tmp_path / name, session)
    out = tmp_path / "cal.json"
    return ["fit", str(src), "--model", "model3", "-o", str(out)], out


def test_missing_poses(tmp_path, capsys):
    argv, out = _fit(tmp_path, synth_session(seed=51, poses=["+z", "-z", "+y"]))
    _fails(capsys, argv, "s.mcap", "missing", "-x", out=out)


def test_duplicated_pose(tmp_path, capsys):
    s = synth_session(seed=52)
    p = s.poses[3]
    s.poses[3] = PoseLabel(s.poses[1].name, p.start_s, p.end_s, s.poses[1].up_sensor, None, 0)
    argv, out = _fit(tmp_path, s)
    _fails(capsys, argv, "pose '-z' (hold 0) is labelled twice", out=out)


def test_too_few_samples(tmp_path, capsys):
    argv, out = _fit(tmp_path, synth_session(seed=53, hold_s=1.05, rate_hz=20.0))
    _fails(capsys, argv, "pose '+z'", "samples after trimming", out=out)


def test_nan_readings(tmp_path, capsys):
    s = synth_session(seed=54)
    s.accel_counts = None
    s.meta = s.meta.replace(accel_lsb_per_g=None)
    k = s.slice_time(s.poses[4].start_s + 3.0, s.poses[4].start_s + 3.1)
    s.accel_g[k] = np.nan
    argv, out = _fit(tmp_path, s)
    _fails(capsys, argv, "pose '+x'", "NaN", out=out)


def test_counts_declared_as_g(tmp_path, capsys):
    s = synth_session(seed=55)
    s.accel_g = s.accel_counts.astype(float)  # raw counts written as if they were g
    s.accel_counts = None
    s.meta = s.meta.replace(accel_lsb_per_g=None)
    argv, out = _fit(tmp_path, s)
    _fails(capsys, argv, "pose '+z'", "counts declared as g", out=out)


def test_moving_window_labelled_static(tmp_path, capsys):
    s = synth_session(seed=56)
    p = s.poses[5]
    k = s.slice_time(p.start_s + 5.0, p.start_s + 6.0)
    s.accel_counts[k] += np.random.default_rng(1).normal(0, 3000, (k.stop - k.start, 3)).astype(np.int32)
    s.accel_g = s.accel_counts / s.meta.accel_lsb_per_g
    argv, out = _fit(tmp_path, s)
    _fails(capsys, argv, "pose '-x' is labelled static but moves at t = 6", out=out)


def test_truncated_mcap(tmp_path, capsys):
    src = write_session(tmp_path / "full.mcap", synth_session(seed=57))
    data = src.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    out = tmp_path / "cal.json"
    err = _fails(capsys, ["fit", str(cut), "-o", str(out)], "cut.mcap", out=out)
    assert "truncated" in err or "no pose labels" in err


def test_truncated_capstone_csv(tmp_path, capsys, shared_data):
    lines = (shared_data / "capstone" / "final_trial" / "six_position_test_data.csv").read_text().splitlines()
    bad = tmp_path / "test.csv"
    bad.write_text("\n".join(lines[:500]) + "\n" + lines[500][:12])  # cut in the middle of a row
    cal = tmp_path / "c.json"
    assert (
        main(["fit", str(shared_data / "capstone" / "final_trial" / "six_position_data.csv"), "-o", str(cal)])
        == 0
    )
    capsys.readouterr()
    _fails(capsys, ["evaluate", str(bad), "--cal", str(cal)], "test.csv:501")


def test_file_with_another_schema(tmp_path, capsys):
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("foo.Bar", "jsonschema", b"{}")
        cid = w.register_channel("/foo", "json", sid)
        w.add_message(cid, log_time=1, publish_time=1, data=b"{}")
        w.finish()
    out = tmp_path / "cal.json"
    _fails(capsys, ["fit", str(foreign), "-o", str(out)], "foreign.mcap", "not an accellog session", out=out)


def test_foreign_or_broken_calibration(tmp_path, capsys, shared_data):
    s = write_session(tmp_path / "s.mcap", synth_session(seed=58, poses=["+z"], hold_s=20.0))
    imucal = shared_data / "imucal" / "example_cal.json"
    _fails(capsys, ["evaluate", str(s), "--cal", str(imucal)], "example_cal.json", "imucal calibration")
    broken = tmp_path / "b.json"
    broken.write_text('{"format": "accellog.calibration",\n"params": [')
    _fails(capsys, ["evaluate", str(s), "--cal", str(broken)], "b.json:2", "not valid JSON")


def test_bad_pose_table_and_unknown_model(tmp_path, capsys, shared_data):
    text = (shared_data / "capstone" / "final_trial" / "six_position_data.csv").read_text().splitlines()
    text[3] = text[3].replace(text[3].split(",")[1], "nan", 1)
    p = tmp_path / "poses.csv"
    p.write_text("\n".join(text) + "\n")
    out = tmp_path / "c.json"
    err = _fails(capsys, ["fit", str(p), "-o", str(out)], "poses.csv", out=out)
    assert "NaN" in err or "nan" in err
    good = shared_data / "capstone" / "final_trial" / "six_position_data.csv"
    _fails(
        capsys, ["fit", str(good), "--model", "model9", "-o", str(out)], "unknown effect 'model9'", out=out
    )
