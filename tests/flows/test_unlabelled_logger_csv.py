"""A logger's CSV of the 24-pose protocol without a pose column (issue 45, item 1): rotations about
the vertical read as one orientation, so fit fits what the six faces identify and diagnose /
workbench refuse it, each naming what makes it work; `import csv --detect-holds` labels the face
holds and all three then run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from accellog.cli import main
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session

COLUMNS = "t=timestamp_us,ax=acc_x,ay=acc_y,az=acc_z,gx=gyr_x,gy=gyr_y,gz=gyr_z,temp=temp_C"


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def logger_csv(tmp_path_factory):
    """An emulated 24-pose session written as a logger writes it: no pose column, time in us."""
    d = tmp_path_factory.mktemp("logger")
    sim = d / "s24.mcap"
    simulate(Scenario(protocol="24", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0, seed=3), sim)
    s = read_session(sim)
    t_us = np.round(s.t_s * 1e6).astype(np.int64)
    rows = np.column_stack([t_us, s.accel_g, s.gyro_dps, s.temp_degC])
    path = d / "logger.csv"
    header = "timestamp_us,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z,temp_C"
    np.savetxt(path, rows, delimiter=",", header=header, comments="", fmt=["%d"] + ["%.6f"] * 7)
    return path


def _import(csv, out, capsys, *extra):
    return _run(["import", "csv", csv, "--columns", COLUMNS, "--time-unit", "us", "-o", out, *extra], capsys)


def test_unlabelled_24_pose_csv_fits_what_its_faces_identify_and_names_the_option(
    logger_csv, tmp_path, capsys
):
    """fit: the six faces identify the biases and scales (the cross-axis terms are held, said); the
    note names the pose column and --detect-holds. diagnose and workbench, which need the full
    model, refuse in one line naming them."""
    ses = tmp_path / "u.mcap"
    assert _import(logger_csv, ses, capsys)[0] == 0
    rc, out, err = _run(["fit", ses, "-o", tmp_path / "u.json", "--json"], capsys)
    assert rc == 0, err
    assert "found at most 6 distinct static orientations" in err
    assert "pose column" in err and "import csv ... --detect-holds" in err
    ident = json.loads(out)["identification"]
    assert {"b_x", "b_y", "b_z", "S_xx", "S_yy", "S_zz"} <= set(ident["identified"]), ident
    assert {"S_yx", "S_zx", "S_zy"} <= set(ident["not_identified"]), ident
    for argv in (["diagnose", ses], ["workbench", ses]):
        rc, _, err = _run(argv, capsys)
        assert rc == 2, (argv, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1, err
        assert "found at most 6 distinct static orientations" in lines[0]
        assert "pose column" in lines[0] and "import csv ... --detect-holds" in lines[0]


def test_detect_holds_labels_the_faces_and_fit_diagnose_workbench_run(logger_csv, tmp_path, capsys):
    ses, cal = tmp_path / "l.mcap", tmp_path / "l.json"
    rc, out, err = _import(logger_csv, ses, capsys, "--detect-holds", "--json")
    assert rc == 0, err
    assert sorted(json.loads(out)["poses"]) == ["+x", "+y", "+z", "-x", "-y", "-z"]
    assert "labelled as the face" in read_session(ses).meta.extra["poses"]
    rc, out, err = _run(["fit", ses, "-o", cal, "--json"], capsys)
    assert rc == 0, err
    assert json.loads(out)["n_poses"] == 6
    assert _run(["diagnose", ses], capsys)[0] == 0
    rc, _, err = _run(["workbench", ses], capsys)
    assert rc == 0, err


def test_detect_holds_refuses_a_file_with_pose_labels(tmp_path, capsys):
    path = tmp_path / "labelled.csv"
    t = np.arange(400) / 100.0
    rows = "\n".join(f"{x:.2f},0,0,1,{'+z' if x < 2 else '-z'}" for x in t)
    path.write_text("t,ax,ay,az,pose\n" + rows + "\n")
    rc, _, err = _run(["import", "csv", path, "--detect-holds", "-o", tmp_path / "o.mcap"], capsys)
    assert rc == 2 and "has a pose column" in err and not (tmp_path / "o.mcap").exists()
