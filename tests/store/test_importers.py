"""Importers against the real shared data, generic CSV on simulated data, bad input through the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from accellog.cli import main
from accellog.core.errors import InputError
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.store.importers import import_capstone, import_csv, import_imucal, load_capstone_pose_table
from accellog.store.reader import read_session


def _run(argv: list[str], capsys) -> tuple[int, str, str]:
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def _assert_cli_error(argv: list[str], out_path: Path, capsys, *, where: str, match: str) -> None:
    rc, _, err = _run([*argv, "-o", str(out_path)], capsys)
    assert rc != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("accellog: error: "), err
    assert where in lines[0], lines[0]
    assert match in lines[0], lines[0]
    assert not out_path.exists()
    assert not list(out_path.parent.glob(f".{out_path.name}*"))  # no temp file either


# ---------------------------------------------------------------------------------------------
# capstone


def test_capstone_test_file(shared_data, tmp_path, capsys):
    src = shared_data / "capstone" / "final_trial" / "six_position_test_data.csv"
    out = tmp_path / "cap.mcap"
    rc, stdout, _ = _run(["import", "capstone", str(src), "-o", str(out), "--json"], capsys)
    assert rc == 0
    facts = json.loads(stdout)
    assert facts["samples"] == 10_763 and facts["poses"] == ["+z"]
    s = read_session(out)
    assert s.n == 10_763
    assert s.t_s[0] == pytest.approx(0.005635976791381836, abs=1e-9)
    assert s.t_s[-1] == pytest.approx(60.004655838012695, abs=1e-9)
    assert s.accel_g[0].tolist() == [0.103271484375, 0.0556640625, 0.7744140625]
    assert s.accel_g[-1].tolist() == [0.095703125, 0.0576171875, 0.771484375]
    assert s.meta.accel_lsb_per_g == 16384.0 and s.accel_counts[0].tolist() == [1692, 912, 12688]
    # every value is exactly counts/16384 g: compare with an independent parse of the file
    ref = np.loadtxt(src, delimiter=",", skiprows=2)
    assert np.array_equal(s.accel_g, ref[:, 1:4])
    assert np.allclose(s.t_s, ref[:, 0], rtol=0, atol=1e-9)
    (p,) = s.poses
    assert p.name == "+z" and p.up_sensor == (0.0, 0.0, 1.0)
    assert s.slice_time(p.start_s, p.end_s) == slice(0, 10_763)
    assert s.meta.local_gravity_mps2 == 9.797 and s.meta.extra["source_unit"] == "g"


def test_capstone_pose_table(shared_data):
    pt = load_capstone_pose_table(shared_data / "capstone" / "trial_1" / "six_position_data_1.csv")
    assert pt.names == ["+z", "-z", "+y", "-y", "+x", "-x"]
    assert pt.truth_g.shape == pt.mean_g.shape == pt.std_g.shape == (6, 3)
    assert pt.truth_g[1].tolist() == [0.0, 0.0, -1.0]
    assert pt.mean_g[1].tolist() == [0.08148270064239228, 0.0412137427064632, -1.2718213065950403]
    assert pt.std_g[1, 2] == 0.004304465548707763


def test_capstone_non_quantized_values_fall_back_to_g(tmp_path):
    f = tmp_path / "c.csv"
    f.write_text("Title.\ntime (s)x (g),y (g),z (g)\n0.01,0.1,0.2,1.0001\n0.02,0.1,0.2,1.0\n")
    s = import_capstone(f)
    assert s.accel_counts is None and s.meta.accel_lsb_per_g is None
    assert s.accel_g[0].tolist() == [0.1, 0.2, 1.0001]


def test_capstone_bad_input(shared_data, tmp_path, capsys):
    lines = (shared_data / "capstone" / "trial_1" / "six_position_test_data_1.csv").read_text().splitlines()
    bad = tmp_path / "bad.csv"
    lines[99] = "1.0,0.1,oops,1.0"
    bad.write_text("\n".join(lines) + "\n")
    _assert_cli_error(
        ["import", "capstone", str(bad)], tmp_path / "o.mcap", capsys, where="bad.csv:100", match="'y'"
    )
    lines[99] = "1.0,0.1,1.0"
    bad.write_text("\n".join(lines) + "\n")
    _assert_cli_error(
        ["import", "capstone", str(bad)], tmp_path / "o.mcap", capsys, where="bad.csv:100", match="columns"
    )
    table = shared_data / "capstone" / "final_trial" / "six_position_data.csv"
    _assert_cli_error(
        ["import", "capstone", str(table)],
        tmp_path / "o.mcap",
        capsys,
        where="six_position_data.csv:1",
        match="pose table",
    )
    hdr = tmp_path / "hdr.csv"
    hdr.write_text("t,x,y,z\n0,0,0,1\n")
    _assert_cli_error(
        ["import", "capstone", str(hdr)], tmp_path / "o.mcap", capsys, where="hdr.csv:2", match="capstone"
    )
    back = tmp_path / "back.csv"
    back.write_text("Title\ntime (s)x (g),y (g),z (g)\n0.2,0,0,1\n0.1,0,0,1\n")
    _assert_cli_error(
        ["import", "capstone", str(back)], tmp_path / "o.mcap", capsys, where="back.csv:4", match="backwards"
    )


# ---------------------------------------------------------------------------------------------
# imucal


def test_imucal_ferraris_session(shared_data, tmp_path, capsys):
    src = shared_data / "imucal" / "example_ferraris_session.csv"
    out = tmp_path / "fer.mcap"
    rc, _, _ = _run(["import", "imucal", str(src), "-o", str(out)], capsys)
    assert rc == 0
    s = read_session(out)
    assert s.n == 10_376 and s.meta.sample_rate_hz == 102.4
    sections = json.loads((shared_data / "imucal" / "example_ferraris_session_list.json").read_text())
    raw = np.loadtxt(src, delimiter=",", skiprows=1)
    acc_mps2 = raw[:, 4:7]
    # values kept: accel_g * g0 gives back the file's m/s^2 (to the last bit or one ulp)
    assert np.allclose(s.accel_g * STANDARD_GRAVITY_MPS2, acc_mps2, rtol=4e-16, atol=0)
    assert np.array_equal(s.gyro_dps, raw[:, 1:4])
    assert s.meta.extra["source_unit"] == "m/s^2"
    names = {"x_p": "+x", "x_a": "-x", "y_p": "+y", "y_a": "-y", "z_p": "+z", "z_a": "-z"}
    assert [p.name for p in s.poses] == ["+x", "-x", "+y", "-y", "+z", "-z"]
    for p in s.poses:
        label = next(k for k, v in names.items() if v == p.name)
        sl = s.slice_time(p.start_s, p.end_s)
        assert (sl.start, sl.stop) == (sections[label]["start"], sections[label]["end"])
        mean = s.accel_g[sl].mean(axis=0)
        assert np.dot(mean, p.up_sensor) > 0.9  # the labelled axis points up
    rot = [json.loads(e.detail) for e in s.events if e.kind == "motion_segment"]
    assert [r["label"] for r in rot] == ["x_rot", "y_rot", "z_rot"]
    assert rot[0]["start_s"] == pytest.approx(6770 / 102.4) and rot[0]["end_s"] == pytest.approx(7093 / 102.4)


def test_imucal_annotated_session(shared_data, tmp_path, capsys):
    src = shared_data / "imucal" / "annotated_session.csv"
    out = tmp_path / "ann.mcap"
    assert _run(["import", "imucal", str(src), "-o", str(out)], capsys)[0] == 0
    s = read_session(out)
    assert s.n == 9414 and s.meta.sample_rate_hz == 204.8 and s.meta.accel_lsb_per_g == 2048.0
    rows = {"+x": 1028, "-x": 1061, "+y": 734, "-y": 848, "+z": 881, "-z": 1044}
    for p in s.poses:
        sl = s.slice_time(p.start_s, p.end_s)
        assert sl.stop - sl.start == rows[p.name]
        assert np.dot(s.accel_g[sl].mean(axis=0), p.up_sensor) > 0.9
    rot = {json.loads(e.detail)["label"]: e for e in s.events if e.kind == "motion_segment"}
    assert set(rot) == {"x_rot", "y_rot", "z_rot"}
    # raw counts stored exactly: first file row (x_a, sample 1028)
    i = int(np.flatnonzero(s.sample_index == 1028)[0])
    assert s.accel_counts[i].tolist() == [-2052, -28, -73] and s.gyro_counts[i].tolist() == [1, 0, -5]


def test_imucal_bad_input(shared_data, tmp_path, capsys):
    src = shared_data / "imucal" / "example_ferraris_session.csv"
    lonely = tmp_path / "session.csv"
    lonely.write_text(src.read_text())
    _assert_cli_error(
        ["import", "imucal", str(lonely)],
        tmp_path / "o.mcap",
        capsys,
        where="session.csv",
        match="section list",
    )
    sec = tmp_path / "sec.json"
    sec.write_text(json.dumps({"x_p": {"start": 10, "end": 99999}}))
    _assert_cli_error(
        ["import", "imucal", str(lonely), "--sections", str(sec)],
        tmp_path / "o.mcap",
        capsys,
        where="sec.json",
        match="outside",
    )
    sec.write_text(json.dumps({"w_p": {"start": 1, "end": 5}}))
    _assert_cli_error(
        ["import", "imucal", str(lonely), "--sections", str(sec)],
        tmp_path / "o.mcap",
        capsys,
        where="sec.json",
        match="w_p",
    )
    lines = (shared_data / "imucal" / "annotated_session.csv").read_text().splitlines()
    lines[41] = lines[41] + ",7"
    ann = tmp_path / "ann.csv"
    ann.write_text("\n".join(lines) + "\n")
    _assert_cli_error(
        ["import", "imucal", str(ann)], tmp_path / "o.mcap", capsys, where="ann.csv:42", match="columns"
    )
    other = tmp_path / "other.csv"
    other.write_text("a,b\n1,2\n")
    _assert_cli_error(
        ["import", "imucal", str(other)], tmp_path / "o.mcap", capsys, where="other.csv:1", match="imucal"
    )


# ---------------------------------------------------------------------------------------------
# generic CSV


def _sim_csv(
    path: Path, *, scale: float = 1.0, fmt: str = "{:.17g}", poses: bool = True, seed: int = 5
) -> np.ndarray:
    """Write a seeded six-pose recording (plus a tilted custom pose) as a generic CSV; return the accel."""
    rng = np.random.default_rng(seed)
    holds = [("+z", (0, 0, 1)), ("-z", (0, 0, -1)), ("+x", (1, 0, 0)), ("tilt", (0.6, 0, 0.8))]
    rows, acc_all = [], []
    t = 0.0
    for name, up in holds:
        for phase in ("move", "hold"):
            for _ in range(200):
                t += rng.uniform(0.004, 0.006)
                a = np.array(up, float) + rng.normal(0, 0.01 if phase == "hold" else 0.2, 3)
                acc_all.append(a)
                v = a * scale
                label = name if (phase == "hold" and poses) else ""
                true = "0.6,0,0.8" if label == "tilt" else ",,"
                rows.append(
                    ",".join(
                        [
                            f"{t:.17g}",
                            *(fmt.format(x) for x in v),
                            f"{25 + t / 10:.4f}",
                            "0.1,-0.2,0.3",
                            label,
                            true,
                        ]
                    )
                )
    path.write_text("t,ax,ay,az,temp,gx,gy,gz,pose,true_x,true_y,true_z\n" + "\n".join(rows) + "\n")
    return np.array(acc_all)


def test_generic_csv_in_g(tmp_path, capsys):
    src = tmp_path / "rec.csv"
    acc = _sim_csv(src)
    out = tmp_path / "rec.mcap"
    assert _run(["import", "csv", str(src), "--unit", "g", "-o", str(out)], capsys)[0] == 0
    s = read_session(out)
    assert s.n == 1600 and np.array_equal(s.accel_g, acc)
    assert [p.name for p in s.poses] == ["+z", "-z", "+x", "tilt"]
    assert [p.hold_index for p in s.poses] == [0, 1, 2, 3]
    assert s.poses[3].up_sensor == (0.6, 0.0, 0.8) and s.poses[3].q_sensor_to_world is None
    assert s.poses[1].q_sensor_to_world is not None
    for k, p in enumerate(s.poses):
        sl = s.slice_time(p.start_s, p.end_s)
        assert (sl.start, sl.stop) == (400 * k + 200, 400 * k + 400)
    assert np.allclose(s.gyro_dps, [0.1, -0.2, 0.3]) and s.temp_degC is not None


def test_generic_csv_mps2_and_counts(tmp_path):
    src = tmp_path / "m.csv"
    acc = _sim_csv(src, scale=STANDARD_GRAVITY_MPS2)
    s = import_csv(src, unit="m/s^2")
    assert np.allclose(s.accel_g, acc, rtol=1e-15, atol=1e-15)
    assert s.meta.extra["source_unit"] == "m/s^2" and "9.80665" in s.meta.extra["conversion"]
    src2 = tmp_path / "c.csv"
    _sim_csv(src2, scale=4096.0, fmt="{:.0f}", poses=False)
    s2 = import_csv(src2, unit="counts", lsb_per_g=4096)
    assert s2.meta.accel_lsb_per_g == 4096.0 and s2.accel_counts.dtype == np.int32
    assert np.array_equal(s2.accel_g, s2.accel_counts / 4096.0) and s2.poses == []


def test_generic_csv_quaternion_column(tmp_path):
    f = tmp_path / "q.csv"
    f.write_text("t,ax,ay,az,pose,qw,qx,qy,qz\n0,0,0,1,+z,1,0,0,0\n0.01,0,0,1,+z,1,0,0,0\n0.02,0,0,1,,,,,\n")
    (p,) = import_csv(f).poses
    assert p.q_sensor_to_world == (1.0, 0.0, 0.0, 0.0) and p.end_s == 0.02


@pytest.mark.parametrize(
    ("content", "args", "where", "match"),
    [
        ("t,ax,ay,az\n0,0,0,1\n0.1,0,0\n", [], ":3", "expected 4 columns"),
        ("t,ax,ay,az\n0,0,0,1\n0.1,0,0,1\n0.2,0,x1,1\n", [], ":4", "'ay'"),
        ("t,ax,ay,az\n0,0,0,1\n0.1,0,nan,1\n", [], ":3", "finite"),
        ("t,ax,ay,az\n0,0,0,1\n0.1,0,,1\n", [], ":3", "empty value"),
        ("t,ax,ay,az\n0,0,0,1\n0.2,0,0,1\n\n0.1,0,0,1\n", [], ":5", "backwards"),
        ("t,ax,ay,az,pose\n0,0,0,1,\n0.1,0,0,1,flat\n0.2,0,0,1,flat\n", [], ":3", "unknown pose 'flat'"),
        (
            "t,ax,ay,az,pose,true_x,true_y,true_z\n0,0,0,1,a,0,0,2\n0.1,0,0,1,a,0,0,2\n",
            [],
            ":2",
            "not a unit vector",
        ),
        ("t,ax,ay\n0,0,0\n", [], ":1", "missing column(s) az"),
        ("t,ax,ay,az\n0,0,0,9.81\n0.1,0,0,9.8\n", [], "", "--unit m/s^2"),
        ("t,ax,ay,az\n0,0,0,16384\n0.1,0,0,16390\n", [], "", "--unit counts --lsb-per-g 16384"),
        ("t,ax,ay,az\n0,0,0,1\n", ["--unit", "m/s^2"], "", "--unit g"),
        ("t,ax,ay,az\n0,0,0,4096\n", ["--unit", "counts", "--lsb-per-g", "16384"], "", "--lsb-per-g 4096"),
        ("t,ax,ay,az\n0,0,0,16384.5\n", ["--unit", "counts", "--lsb-per-g", "16384"], ":2", "not integers"),
        ("t,ax,ay,az\n0,0,0,1\n", ["--unit", "counts"], "", "needs --lsb-per-g"),
        ("t,ax,ay,az\n", [], "", "no data rows"),
    ],
)
def test_generic_csv_bad_input(tmp_path, capsys, content, args, where, match):
    f = tmp_path / "in.csv"
    f.write_text(content)
    w = f"in.csv{where}" if where else ""
    _assert_cli_error(["import", "csv", str(f), *args], tmp_path / "out.mcap", capsys, where=w, match=match)


def test_missing_input_file(tmp_path, capsys):
    for kind in ("capstone", "imucal", "csv"):
        _assert_cli_error(
            ["import", kind, str(tmp_path / "nope.csv")],
            tmp_path / "o.mcap",
            capsys,
            where="nope.csv",
            match="no such file",
        )


def test_importers_raise_input_error_directly(tmp_path):
    f = tmp_path / "x.csv"
    f.write_text("t,ax,ay,az\n0,0,0,1\n")
    with pytest.raises(InputError, match="unknown unit"):
        import_csv(f, unit="furlongs")
    with pytest.raises(InputError, match="imucal"):
        import_imucal(f)
