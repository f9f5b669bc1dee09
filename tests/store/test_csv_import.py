"""Any logger's CSV: files written in the shapes of two public recordings (an industrial IMU in
offset-binary counts; an MPU-6050 log with a rate header and no time column), column maps, units,
delimiters, comments, block boundaries, and one-line errors whose hints never loop."""

from __future__ import annotations

import json
import re
import shlex
import threading
from pathlib import Path

import numpy as np
import pytest

from accellog.cli import main
from accellog.core.errors import InputError
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.store.importers import CsvOptions, import_csv, import_csv_to_mcap
from accellog.store.importers.csv_blocks import read_ahead
from accellog.store.reader import read_session

_RAW_MAP = "t=timestamp_us,ax=acc_x,ay=acc_y,az=acc_z,gx=gyr_x,gy=gyr_y,gz=gyr_z,temp=temp_C"
_RAW_ARGS = [
    "--columns", _RAW_MAP, "--time-unit", "us", "--unit", "counts", "--lsb-per-g", "16384",
    "--count-offset", "32768", "--gyro-unit", "counts", "--gyro-lsb-per-dps", "131",
]  # fmt: skip


def _run(argv, capsys):
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def _industrial(path: Path, n: int = 3000, seed: int = 3) -> dict:
    """Offset-binary 16-bit counts (centred on 32768), 1 kHz, microsecond Unix stamps, jittered."""
    rng = np.random.default_rng(seed)
    t_us = 1_700_000_000_000_000 + np.cumsum(rng.integers(990, 1010, n))
    acc = np.round(np.array([0.02, -0.01, 1.0]) * 16384 + rng.normal(0, 30, (n, 3))).astype(int)
    gyr = np.round(np.array([0.5, -0.3, 0.1]) * 131 + rng.normal(0, 20, (n, 3))).astype(int)
    temp = 30 + np.arange(n) / n
    rows = [
        f"{t},{a[0] + 32768},{a[1] + 32768},{a[2] + 32768},{g[0] + 32768},{g[1] + 32768},{g[2] + 32768},{c:.3f}"
        for t, a, g, c in zip(t_us, acc, gyr, temp, strict=True)
    ]
    path.write_text("timestamp_us,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z,temp_C\n" + "\n".join(rows) + "\n")
    return {"t_us": t_us, "acc": acc, "gyr": gyr, "temp": temp}


def _mpu6050(path: Path, n: int = 1500, seed: int = 4, rate_line: bool = True) -> dict:
    """Adafruit-style MPU-6050 log: a comment preamble with the rate, accel m/s^2, gyro rad/s, no time."""
    rng = np.random.default_rng(seed)
    acc = np.round(np.array([0.3, -0.2, 9.81]) + rng.normal(0, 0.05, (n, 3)), 6)
    gyr = np.round(np.array([0.01, -0.02, 0.005]) + rng.normal(0, 0.002, (n, 3)), 6)
    head = "# MPU-6050 logger v1.2\n# Sample rate: 100 Hz\n" if rate_line else "# MPU-6050 logger v1.2\n"
    rows = [",".join(f"{v:.6f}" for v in (*a, *g)) for a, g in zip(acc, gyr, strict=True)]
    path.write_text(head + "AccX,AccY,AccZ,GyroX,GyroY,GyroZ\n" + "\n".join(rows) + "\n")
    return {"acc": acc, "gyr": gyr}


_MPU_MAP = "ax=AccX,ay=AccY,az=AccZ,gx=GyroX,gy=GyroY,gz=GyroZ"


def test_offset_binary_counts_one_command(tmp_path, capsys):
    src, out = tmp_path / "imu_raw.csv", tmp_path / "raw.mcap"
    ref = _industrial(src)
    rc, stdout, err = _run(["import", "csv", str(src), *_RAW_ARGS, "-o", str(out), "--json"], capsys)
    assert rc == 0, err
    facts = json.loads(stdout)
    assert facts["samples"] == 3000 and facts["extra"]["count_offset"] == "32768"
    s = read_session(out)
    assert np.array_equal(s.accel_counts, ref["acc"]) and np.array_equal(s.gyro_counts, ref["gyr"])
    assert np.array_equal(s.accel_g, ref["acc"] / 16384.0)
    assert np.array_equal(s.gyro_dps, ref["gyr"] / 131.0)
    assert s.meta.start_time_unix_ns == int(ref["t_us"][0]) * 1000
    assert np.allclose(s.t_s, (ref["t_us"] - ref["t_us"][0]) * 1e-6, rtol=0, atol=1e-9)
    assert np.allclose(s.temp_degC, ref["temp"], atol=5e-4)
    assert s.meta.sample_rate_hz == pytest.approx(1000, rel=0.01)


def test_hints_lead_to_a_working_command_and_never_loop(tmp_path, capsys):
    """Start from the bare command, apply each hint's flags; it must succeed without repeating a hint."""
    src, out = tmp_path / "imu_raw.csv", tmp_path / "raw.mcap"
    _industrial(src)
    args = ["--columns", _RAW_MAP, "--time-unit", "us"]
    seen = []
    for _ in range(4):
        rc, _, err = _run(["import", "csv", str(src), *args, "-o", str(out)], capsys)
        if rc == 0:
            break
        assert len(err.strip().splitlines()) == 1
        m = re.search(r"use (--.*)$", err.strip())
        assert m, err
        assert m.group(1) not in seen, f"hint repeated: {err}"
        seen.append(m.group(1))
        flags = shlex.split(m.group(1).replace("LSB", "131"))
        for i in range(0, len(flags), 2):  # replace flags already present
            if flags[i] in args:
                args[args.index(flags[i]) + 1] = flags[i + 1]
            else:
                args += flags[i : i + 2]
    assert rc == 0 and read_session(out).accel_counts is not None
    assert len(seen) == 2  # accel (counts, offset, LSB), then gyro counts


def test_rate_header_no_time_column_one_command(tmp_path, capsys):
    src, out = tmp_path / "mpu6050.csv", tmp_path / "m.mcap"
    ref = _mpu6050(src)
    argv = ["import", "csv", str(src), "--columns", _MPU_MAP, "--unit", "m/s^2", "--gyro-unit", "rad/s"]
    rc, _, err = _run([*argv, "-o", str(out)], capsys)
    assert rc == 0, err
    s = read_session(out)
    assert s.n == 1500 and s.meta.sample_rate_hz == 100.0
    assert np.allclose(s.t_s, np.arange(1500) / 100.0, rtol=0, atol=1e-9)
    assert np.allclose(s.accel_g, ref["acc"] / STANDARD_GRAVITY_MPS2, rtol=1e-12, atol=0)
    assert np.allclose(s.gyro_dps, np.rad2deg(ref["gyr"]), rtol=1e-12, atol=0)
    assert "header line: 100 Hz" in s.meta.extra["time_source"]
    # the same file without the rate line needs --rate, and the error says so
    bare = tmp_path / "bare.csv"
    _mpu6050(bare, rate_line=False)
    rc, _, err = _run(["import", "csv", str(bare), *argv[3:], "-o", str(out), "--force"], capsys)
    assert rc != 0 and "--rate HZ" in err and "bare.csv:2" in err
    rc, _, err = _run(
        ["import", "csv", str(bare), *argv[3:], "--rate", "100", "-o", str(out), "--force"], capsys
    )
    assert rc == 0, err
    assert np.array_equal(read_session(out).t_s, s.t_s)


def test_blocks_give_the_same_session_and_lines(tmp_path):
    """Tiny blocks (many boundaries, comments and blank lines inside) give the same arrays as one block."""
    src = tmp_path / "b.csv"
    lines = ["# comment", "t;ax;ay;az;gx;gy;gz;pose"]
    for i in range(400):
        lines.append(f"{i * 10};0.01;0.02;{1 + i * 1e-5};0.1;0.2;0.3;{'+z' if 100 <= i < 300 else ''}")
        if i % 97 == 5:
            lines.append("# a note from the logger")
        if i % 131 == 7:
            lines.append("")
    src.write_text("\n".join(lines) + "\n")
    kw = {"delimiter": ";", "time_unit": "ms"}
    big = import_csv(src, **kw)
    small = import_csv(src, **kw, block_bytes=200)
    for name in ("t_s", "accel_g", "gyro_dps"):
        assert np.array_equal(getattr(big, name), getattr(small, name))
    assert big.poses == small.poses and [p.name for p in big.poses] == ["+z"]
    assert big.poses[0].start_s == 1.0 and big.poses[0].end_s == 3.0
    # a duplicated stamp deep in the file: its exact line, whatever the block size
    bad = lines.copy()
    k = next(i for i, ln in enumerate(bad) if ln.startswith("3000;"))
    bad[k] = bad[k].replace("3000;", "2990;", 1)
    src.write_text("\n".join(bad) + "\n")
    for bb in (200, 1 << 20):
        with pytest.raises(InputError, match="duplicated timestamp") as e:
            import_csv(src, **kw, block_bytes=bb)
        assert e.value.where == f"{src}:{k + 1}"


def test_streaming_matches_in_memory(tmp_path):
    src, out = tmp_path / "r.csv", tmp_path / "r.mcap"
    _industrial(src, n=2000)
    opts = CsvOptions.make(**dict(zip(
        ("columns", "time_unit", "unit", "lsb_per_g", "count_offset", "gyro_unit", "gyro_lsb_per_dps"),
        (_RAW_MAP, "us", "counts", 16384.0, 32768.0, "counts", 131.0), strict=True,
    )))  # fmt: skip
    mem = import_csv(src, opts)
    import_csv_to_mcap(src, out, opts, block_bytes=4096)
    s = read_session(out)
    assert np.array_equal(s.accel_counts, mem.accel_counts) and np.array_equal(s.gyro_counts, mem.gyro_counts)
    assert np.allclose(s.t_s, mem.t_s, rtol=0, atol=1e-9)


def test_read_ahead_keeps_order_errors_and_stops_early():
    """Items in order, at most one made ahead of the one in use; the producer's error is raised at its
    place; leaving the loop early closes the source and ends the thread."""
    made, closed = [], []

    def source(n, fail_at=None):
        try:
            for i in range(n):
                if i == fail_at:
                    raise InputError("bad row", where=f"x.csv:{i}")
                made.append(i)
                yield i
        finally:
            closed.append(True)

    got = []
    for k, i in enumerate(read_ahead(source(40), "t-order")):
        assert len(made) <= k + 2  # item k in use, k + 1 at most made ahead
        got.append(i)
    assert got == list(range(40)) and closed == [True]

    made.clear()
    got = []
    with pytest.raises(InputError, match="bad row") as e:
        for i in read_ahead(source(40, fail_at=7), "t-error"):
            got.append(i)
    assert got == list(range(7)) and e.value.where == "x.csv:7"

    made.clear()
    closed.clear()
    gen = read_ahead(source(10**6), "t-stop")
    assert [next(gen), next(gen)] == [0, 1]
    gen.close()
    assert closed == [True] and len(made) <= 3
    assert not [t for t in threading.enumerate() if t.name.startswith("t-")]


def test_streaming_error_deep_in_the_file_leaves_nothing(tmp_path):
    """A bad row found by the read-ahead thread several blocks in: its line, and no output or
    temporary file left behind."""
    src, out = tmp_path / "d.csv", tmp_path / "d.mcap"
    rows = [f"{i * 0.01:.2f},0.01,0.02,1.0" for i in range(3000)]
    rows[2500] = rows[2499]
    src.write_text("t,ax,ay,az\n" + "\n".join(rows) + "\n")
    with pytest.raises(InputError, match="duplicated timestamp") as e:
        import_csv_to_mcap(src, out, block_bytes=4096)
    assert e.value.where == f"{src}:2502"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.csv"]
    assert not [t for t in threading.enumerate() if t.name == "csv-parse"]


@pytest.mark.parametrize(
    ("content", "args", "where", "match"),
    [
        ("t,ax,ay,az\n0,0,0,1\n0.1,0,0,1\n0.1,0,0,1\n", [], ":4", "duplicated timestamp"),
        ("t,ax,ay,az\n0,0,0,1\n", [], "", "only 1 row"),
        ("t,ax,ay,az\n0,0,0,1\n0,0,0,1\n", [], ":3", "duplicated"),
        ("time,x,y,z\n0,0,0,1\n0.1,0,0,1\n", ["--columns", "t=time,ax=x,ay=y,az=zz"], ":1", "no such column"),
        ("t,ax,ay,az\n0,0,0,1\n0.1,0,0,1\n", ["--rate", "100"], ":1", "drop --rate"),
        ("t,ax,ay,az\n0,0,0,1\n0.1,0,0,1\n", ["--columns", "t=a=b"], "", "--columns"),
        ("t,ax,ay,az\n0,0,0,1\n0.1,0,0,1\n", ["--gyro-unit", "furlongs"], "", "unknown gyro unit"),
        ("t,ax,ay,az,gx,gy,gz\n0,0,0,1,32768,32768,32768\n0.1,0,0,1,32768,32768,32768\n", [], "", "--gyro-unit counts"),
        ("t,ax,ay,az\n0,32768,32768,49152\n0.1,32768,32768,49152\n", [], "", "--count-offset 32768"),
        ("0,0,0,1\n0.1,0,0,1\n", [], ":1", "no header row"),
        ("t,ax,ay,az\n0,0,0,1\n0.1,0,0,1\n", ["--count-offset", "5"], "", "applies to counts"),
    ],
)  # fmt: skip
def test_csv_bad_input_one_line(tmp_path, capsys, content, args, where, match):
    f, out = tmp_path / "in.csv", tmp_path / "out.mcap"
    f.write_text(content)
    rc, _, err = _run(["import", "csv", str(f), *args, "-o", str(out)], capsys)
    lines = err.strip().splitlines()
    assert rc != 0 and len(lines) == 1 and lines[0].startswith("accellog: error: "), err
    assert (f"in.csv{where}" if where else "") in lines[0] and match in lines[0], lines[0]
    assert not out.exists() and not list(tmp_path.glob(".out.mcap*"))
