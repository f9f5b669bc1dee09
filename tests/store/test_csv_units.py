"""Units checked at the door (issue 25 item 4, issue 27 item 2): `import csv` refuses a time column
in the wrong unit (rate outside 1 Hz .. 100 kHz), accelerations that are not ~1 g, gyro counts
declared as deg/s, a count offset subtracted from columns that are already signed, and a time stamp
beyond int64 nanoseconds, each with one line naming the fix and nothing written; following the
fix imports the exact values. `doctor` reports the same defects in files already written."""

from __future__ import annotations

import json
import re
import shlex

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from accellog.cli import main
from accellog.core.errors import InputError
from accellog.core.plausible import TIME_UNIT_S, gyro_counts_evidence, likely_time_unit, rate_ok
from accellog.store.importers import CsvOptions, import_csv
from accellog.store.reader import read_session
from accellog.store.writer import write_session

HEADER = "t,ax,ay,az,gx,gy,gz"


def _write(path, t, acc, gyr, fmt=("%.9g", "%.9g", "%.9g")):
    """A CSV with the header t,ax,ay,az,gx,gy,gz (values formatted per group: time, accel, gyro)."""
    rows = [
        ",".join([fmt[0] % ti, *(fmt[1] % v for v in a), *(fmt[2] % v for v in g)])
        for ti, a, g in zip(t, acc, gyr, strict=True)
    ]
    path.write_text(HEADER + "\n" + "\n".join(rows) + "\n")
    return path


def _still(n=2000, rate_hz=100.0, seed=0):
    """Still log, z up: time (s), accel (g), gyro (deg/s, with a bias)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate_hz
    acc = np.array([0.01, -0.02, 1.0]) + rng.normal(0, 0.002, (n, 3))
    gyr = np.array([-3.2, 1.1, 0.4]) + rng.normal(0, 0.05, (n, 3))
    return t, acc, gyr


def _mpu6050_counts(path, n=2000, seed=1, accel_offset=0, gyro_offset=0):
    """MPU-6050 raw log: signed (or offset-binary) counts, +-2 g (16384 LSB/g), +-250 deg/s (131 LSB)."""
    t, acc, gyr = _still(n, seed=seed)
    a = np.round(acc * 16384).astype(int) + accel_offset
    g = np.round(gyr * 131).astype(int) + gyro_offset
    _write(path, t, a, g, ("%.6f", "%d", "%d"))
    return a, g


def _import(tmp_path, capsys, src, *args, name="out.mcap"):
    out = tmp_path / name
    rc = main(["import", "csv", str(src), "-o", str(out), "--json", "--force", *args])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err.strip(), out


def _refused(tmp_path, capsys, src, *args) -> str:
    rc, _, err, out = _import(tmp_path, capsys, src, *args, name="refused.mcap")
    assert rc != 0 and len(err.splitlines()) == 1 and err.startswith("accellog: error: "), err
    assert not out.exists() and not list(tmp_path.glob(".refused.mcap*")), "something was written"
    return err


def test_microseconds_without_time_unit_refused_then_exact(tmp_path, capsys):
    t, acc, gyr = _still()
    src = _write(tmp_path / "us.csv", 1_000_000 + t * 1e6, acc, gyr, ("%.0f", "%.9g", "%.9g"))
    err = _refused(tmp_path, capsys, src)
    assert "time column looks like microseconds: pass --time-unit us" in err and "us.csv" in err
    rc, stdout, err, out = _import(tmp_path, capsys, src, "--time-unit", "us")
    assert rc == 0, err
    facts = json.loads(stdout)
    assert facts["sample_rate_hz"] == pytest.approx(100.0) and facts["duration_s"] == pytest.approx(19.99)
    assert np.allclose(read_session(out).t_s, 1.0 + t, rtol=0, atol=1e-9)  # 1e6 us = 1 s: kept


@pytest.mark.parametrize(
    ("stamps", "declared", "unit"),
    [
        (lambda t: t * 1e3, [], "milliseconds: pass --time-unit ms"),
        (lambda t: t * 1e9, ["--time-unit", "us"], "nanoseconds: pass --time-unit ns"),
        (lambda t: t, ["--time-unit", "us"], "seconds: pass --time-unit s"),  # 1e8 Hz
        (lambda t: t * 1e-6, [], "no time unit makes it one"),  # 1e8 Hz read as s, 1e11 Hz as ms..ns
    ],
)
def test_time_unit_mistakes_name_the_unit(tmp_path, capsys, stamps, declared, unit):
    t, acc, gyr = _still(200)
    src = _write(tmp_path / "t.csv", stamps(t), acc, gyr, ("%.17g", "%.9g", "%.9g"))
    err = _refused(tmp_path, capsys, src, *declared)
    assert unit in err and "Hz" in err


@pytest.mark.parametrize("rate_hz", [20.0, 50.0, 100.0, 200.0, 500.0, 999.0])
@pytest.mark.parametrize(("unit", "per_s"), [("ms", 1e3), ("us", 1e6), ("ns", 1e9)])
def test_likely_time_unit_over_typical_rates(rate_hz, unit, per_s):
    assert likely_time_unit(per_s / rate_hz, "s") == unit  # stamps in `unit`, read as seconds
    assert likely_time_unit(1.0 / rate_hz, "s") == "s"


def test_rate_line_and_rate_option_out_of_range(tmp_path, capsys):
    rows = "\n".join("0.01,0.02,1.0" for _ in range(20))
    src = tmp_path / "norate.csv"
    src.write_text(f"# Sample rate: 0.2 Hz\nax,ay,az\n{rows}\n")
    assert "give the rate with --rate HZ" in _refused(tmp_path, capsys, src)
    src.write_text(f"ax,ay,az\n{rows}\n")
    for bad in ("0.5", "2e5", "nan"):
        assert "--rate" in _refused(tmp_path, capsys, src, "--rate", bad)
    rc, _, err, _ = _import(tmp_path, capsys, src, "--rate", "50")
    assert rc == 0, err


def test_time_stamp_beyond_int64_ns_refused_with_its_line(tmp_path, capsys):
    t, acc, gyr = _still(500)
    t[-1] = 1e300
    src = _write(tmp_path / "huge.csv", t, acc, gyr)
    err = _refused(tmp_path, capsys, src)
    assert "huge.csv:501:" in err and "1e+300" in err and "int64" in err
    with pytest.raises(InputError, match="int64"):
        import_csv(src)  # the in-memory import refuses it too (the session could never be written)
    t[-1] = 9.3e9  # just beyond 2**63 ns
    _write(src, t, acc, gyr)
    assert "huge.csv:501:" in _refused(tmp_path, capsys, src)


@pytest.mark.parametrize(
    ("scale", "args", "hint"),
    [
        (9.80665, [], "use --unit m/s^2"),
        (1.0, ["--unit", "m/s^2"], "use --unit g"),
        (2048.0, ["--unit", "counts", "--lsb-per-g", "16384"], "--lsb-per-g 2048"),  # a +-16 g range
    ],
)
def test_accel_unit_mistakes(tmp_path, capsys, scale, args, hint):
    t, acc, gyr = _still(300)
    acc = np.round(acc * scale) if scale > 100 else acc * scale
    src = _write(tmp_path / "a.csv", t, acc, gyr)
    assert hint in _refused(tmp_path, capsys, src, *args)


def test_mpu6050_gyro_counts_refused_then_follow_the_hint(tmp_path, capsys):
    """The issue's row: gyro in raw counts imported with --unit counts (gyro stored as deg/s silently)."""
    src = tmp_path / "mpu6050.csv"
    a, g = _mpu6050_counts(src)
    args = ["--unit", "counts", "--lsb-per-g", "16384"]
    err = _refused(tmp_path, capsys, src, *args)
    assert "gx,gy,gz declared as deg/s are whole numbers" in err and "131" in err
    fix = shlex.split(re.search(r"use (--.*)$", err).group(1).replace("LSB", "131"))
    assert fix == ["--gyro-unit", "counts", "--gyro-lsb-per-dps", "131"]
    rc, _, err, out = _import(tmp_path, capsys, src, *args, *fix)
    assert rc == 0, err
    s = read_session(out)
    assert np.array_equal(s.gyro_counts, g) and np.array_equal(s.gyro_dps, g / 131.0)
    assert np.array_equal(s.accel_counts, a)
    # a user who says the whole numbers are deg/s is taken at their word
    rc, _, err, out = _import(tmp_path, capsys, src, *args, "--gyro-unit", "deg/s")
    assert rc == 0 and np.array_equal(read_session(out).gyro_dps, g), err


def test_gyro_counts_beside_g_accel_and_honest_gyros_accepted(tmp_path, capsys):
    t, acc, gyr = _still(300)
    counts = tmp_path / "gc.csv"
    _write(counts, t, acc, np.round(gyr * 131), ("%.6f", "%.6f", "%d"))  # median |w| 144 "deg/s", whole
    assert "--gyro-unit counts --gyro-lsb-per-dps LSB" in _refused(tmp_path, capsys, counts)
    whole = tmp_path / "whole.csv"  # a logger printing whole deg/s: 0 and +-1 at rest
    _write(whole, t, acc, np.round(gyr / 3), ("%.6f", "%.6f", "%d"))
    for ok in (whole, _write(tmp_path / "float.csv", t, acc, gyr)):
        rc, _, err, _ = _import(tmp_path, capsys, ok)
        assert rc == 0, err
    assert gyro_counts_evidence(gyr, accel_counts=True) is None  # fractional values are never counts
    assert "beyond any MEMS range" in gyro_counts_evidence(gyr + 5000, accel_counts=False)


def test_count_offsets_say_which_columns_and_apply_per_group(tmp_path, capsys):
    base = ["--unit", "counts", "--lsb-per-g", "16384", "--gyro-unit", "counts", "--gyro-lsb-per-dps", "131"]
    signed = tmp_path / "signed.csv"
    _mpu6050_counts(signed)
    err = _refused(tmp_path, capsys, signed, *base, "--count-offset", "32768")
    assert "subtracted from ax,ay,az and gx,gy,gz" in err and "drop --count-offset" in err
    err = _refused(tmp_path, capsys, signed, *base, "--gyro-count-offset", "32768")
    assert "--gyro-count-offset 32768 is subtracted from gx,gy,gz" in err and "--gyro-count-offset 0" in err
    # offset-binary accel, signed gyro: the offset given for both is wrong for the gyro
    mixed = tmp_path / "mixed.csv"
    a, g = _mpu6050_counts(mixed, accel_offset=32768)
    err = _refused(tmp_path, capsys, mixed, *base, "--count-offset", "32768")
    assert "gx,gy,gz are centred on 0" in err and "use --gyro-count-offset 0" in err
    rc, stdout, err, out = _import(
        tmp_path, capsys, mixed, *base, "--count-offset", "32768", "--gyro-count-offset", "0"
    )
    assert rc == 0, err
    assert json.loads(stdout)["extra"]["count_offset_columns"] == "ax,ay,az - 32768; gx,gy,gz - 0"
    s = read_session(out)
    assert np.array_equal(s.accel_counts, a - 32768) and np.array_equal(s.gyro_counts, g)
    # signed accel, offset-binary gyro
    other = tmp_path / "other.csv"
    _mpu6050_counts(other, gyro_offset=32768)
    assert "use --gyro-count-offset 32768" in _refused(tmp_path, capsys, other, *base)
    # the gyro offset needs gyro counts
    assert "give --gyro-unit counts" in _refused(tmp_path, capsys, signed, "--gyro-count-offset", "5")


def test_doctor_reports_rate_and_units_as_defects(tmp_path, capsys):
    t, acc, gyr = _still(1000)
    us = _write(tmp_path / "us.csv", t * 1e6, acc, gyr, ("%.0f", "%.9g", "%.9g"))
    r = json.loads(_doctor(us, capsys))
    rate = [f for f in r["findings"] if f["kind"] == "rate"]
    assert not r["healthy"] and rate and "--time-unit us" in rate[0]["detail"]
    # a file written before the door checks existed: µs read as s, m/s^2 stored as g, gyro counts as deg/s
    src = _write(tmp_path / "bad.csv", t * 1e6, acc * 9.80665, np.round(gyr * 131), ("%.0f", "%.9g", "%d"))
    bad = tmp_path / "bad.mcap"
    write_session(bad, import_csv(src, CsvOptions(check_units=False)))
    r = json.loads(_doctor(bad, capsys))
    details = " | ".join(f"{f['kind']}: {f['detail']}" for f in r["findings"])
    assert "rate: " in details and "--time-unit us" in details
    assert "accel: median |a| 9.8" in details and "--unit m/s^2" in details
    assert "gyro: values stored as deg/s are whole numbers" in details and "--gyro-unit counts" in details
    good = _write(tmp_path / "good.csv", t, acc, gyr)
    assert json.loads(_doctor(good, capsys))["healthy"]


def _doctor(path, capsys) -> str:
    rc = main(["doctor", str(path), "--json"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    return cap.out


def test_imucal_raw_counts_gyro_is_not_taken_for_deg_per_s(shared_data, tmp_path, capsys):
    """imucal's annotated_session.csv (raw counts, +-16 g / +-2000 deg/s): with --unit counts alone
    the gyro counts used to be stored as deg/s; now refused, then imported exactly with the fix."""
    src = shared_data / "imucal" / "annotated_session.csv"
    cols = ["--columns", "ax=acc_x,ay=acc_y,az=acc_z,gx=gyr_x,gy=gyr_y,gz=gyr_z", "--rate", "204.8"]
    args = [*cols, "--unit", "counts", "--lsb-per-g", "2048"]
    assert "--gyro-unit counts" in _refused(tmp_path, capsys, src, *args)
    rc, _, err, out = _import(
        tmp_path, capsys, src, *args, "--gyro-unit", "counts", "--gyro-lsb-per-dps", "16.384"
    )
    assert rc == 0, err
    raw = np.loadtxt(src, delimiter=",", skiprows=1, usecols=(5, 6, 7))
    s = read_session(out)
    assert s.n == 9414 and np.array_equal(s.gyro_counts, raw) and np.array_equal(s.gyro_dps, raw / 16.384)


def test_fit_on_a_csv_points_to_import_csv_for_the_fix(tmp_path, capsys):
    """Stages that read a CSV directly have no --time-unit: the one line says where the option goes."""
    t, acc, gyr = _still(300)
    src = _write(tmp_path / "us.csv", t * 1e6, acc, gyr, ("%.0f", "%.9g", "%.9g"))
    out = tmp_path / "cal.json"
    assert main(["fit", str(src), "-o", str(out)]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--time-unit us" in err and "accellog import csv" in err
    assert not out.exists()


@pytest.mark.parametrize("block_bytes", [64, 1 << 20])
def test_line_numbers_exact_with_crlf_blank_lines_and_hash_in_values(tmp_path, block_bytes):
    """Blocks map rows to lines in O(1) only when every line became a row; CRLF line ends, blank
    lines and a '#' inside a value (not a comment) keep the reported line exact."""
    lines = ["t,ax,ay,az,note"]
    for i in range(60):
        lines.append(f"{i * 0.01:.2f},0.01,0.02,1.0,{'#1' if 10 <= i < 20 else ''}")
        if i == 30:
            lines.append("")
    k = len(lines) - 5
    lines[k] = lines[k - 1]  # a duplicated stamp after the blank line
    src = tmp_path / "crlf.csv"
    src.write_bytes(("\r\n".join(lines) + "\r\n").encode())
    with pytest.raises(InputError, match="duplicated timestamp") as e:
        import_csv(src, block_bytes=block_bytes)
    assert e.value.where == f"{src}:{k + 1}"
    lines[k] = f"{float(lines[k - 1].split(',')[0]) + 0.005:.4f},0.01,0.02,1.0,"  # repaired
    src.write_bytes(("\r\n".join(lines) + "\r\n").encode())
    s = import_csv(src, block_bytes=block_bytes)  # '#1' in the ignored 'note' column is no comment
    assert s.n == 60 and s.meta.extra["ignored_columns"] == "note"


@settings(max_examples=300, deadline=None)
@given(
    step=st.floats(min_value=1e-15, max_value=1e15, allow_nan=False),
    declared=st.sampled_from(["s", "ms", "us", "ns"]),
)
def test_likely_time_unit_property(step, declared):
    """The unit named is None or one whose rate is an IMU rate; the declared one when it already is."""
    u = likely_time_unit(step, declared)
    rate = {k: 1.0 / (step * f) for k, f in TIME_UNIT_S.items()}
    if rate_ok(rate[declared]):
        assert u == declared
    elif u is None:
        assert not any(rate_ok(r) for r in rate.values())
    else:
        assert rate_ok(rate[u])


def test_millisecond_counter_at_1khz_is_not_taken_for_a_1hz_log(tmp_path, capsys):
    """Whole-number stamps 1 apart read as s are 1 Hz, inside the range: a millisecond counter at 1 kHz
    far more often. Refused with the fix; naming the unit keeps it as a 1 Hz log."""
    _, acc, gyr = _still(500)
    src = _write(tmp_path / "millis.csv", 100 + np.arange(500), acc, gyr, ("%d", "%.9g", "%.9g"))
    err = _refused(tmp_path, capsys, src)
    assert "time column looks like milliseconds: pass --time-unit ms" in err and "--time-unit s if" in err
    rc, stdout, err, _ = _import(tmp_path, capsys, src, "--time-unit", "ms")
    assert rc == 0 and json.loads(stdout)["sample_rate_hz"] == pytest.approx(1000.0), err
    rc, stdout, err, _ = _import(tmp_path, capsys, src, "--time-unit", "s", name="slow.mcap")
    assert rc == 0 and json.loads(stdout)["sample_rate_hz"] == pytest.approx(1.0), err
    frac = _write(tmp_path / "frac.csv", 0.5 + np.arange(500), acc, gyr)  # not whole numbers: 1 Hz as given
    rc, _, err, _ = _import(tmp_path, capsys, frac, name="frac.mcap")
    assert rc == 0, err
