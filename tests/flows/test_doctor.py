"""`accellog doctor`: passes a clean emulated log, flags every defect of one damaged on purpose (gap,
duplicate, out-of-order, jitter, bursts, clipping), reads ROS 2 bags, writes a readable .rrd."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from support.ros2_bags import session_to_bag

from accellog.cli import main
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session
from accellog.store.writer import write_session
from tests.rrd_readback import load_rrd


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    p = tmp_path_factory.mktemp("doctor") / "clean.mcap"
    # +-1000 deg/s: the 1 s moves exceed the default +-250 deg/s (the doctor flags that as clipping)
    simulate(
        Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0, gyro_range_dps=1000, seed=31),
        p,
    )
    return p


def _doctor(path, capsys, *extra):
    rc = main(["doctor", str(path), "--json", *map(str, extra)])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    return json.loads(cap.out)


def test_clean_log_passes(clean, capsys):
    r = _doctor(clean, capsys)
    assert r["healthy"] and r["findings"] == []
    assert r["rate_hz"] == pytest.approx(200.0, rel=1e-3) and r["jitter_rel"] < 1e-6
    ok = {x["calibration"]: x["ok"] for x in r["supports"]}
    assert ok["model3 on labelled poses (fit)"] and ok["gyro bias"]
    assert not ok["noise density (export --to kalibr)"]  # 3 s holds: too short, and it says so
    assert r["distinct_orientations"] == 6
    assert r["device"]["who_am_i"] == 0x71 and r["device"]["i2c_bus"] == "emulator"  # the device key


def test_a_gyro_in_rad_s_stored_as_deg_s_is_a_defect(clean, tmp_path, capsys):
    """Issue 45: a gyro written in rad/s where deg/s belongs (57x small) passed as healthy; doctor
    judges it from the motion as the CSV importer does (core.plausible.GravityTurns): gravity turns
    by hundreds of degrees between the rests while the gyro integrates ~57x less."""
    s = read_session(clean)
    rad = tmp_path / "rad.mcap"
    write_session(rad, dataclasses.replace(s, gyro_dps=s.gyro_dps * np.pi / 180.0))
    r = _doctor(rad, capsys)
    units = [f["detail"] for f in r["findings"] if f["kind"] == "unit"]
    assert not r["healthy"] and any("look like rad/s" in d and "--gyro-unit rad/s" in d for d in units), r


def test_still_intervals_are_the_emulators_holds(clean, capsys):
    """One still interval around each of the six holds the emulator labels (the settling before and
    after a hold is still too)."""
    r = _doctor(clean, capsys)
    poses = read_session(clean).poses
    assert len(r["still_intervals"]) == len(poses) == 6
    for h, p in zip(r["still_intervals"], poses, strict=True):
        assert h["start_s"] <= p.start_s and p.end_s <= h["end_s"] <= p.end_s + 0.5
        assert np.dot(h["up"], p.up_sensor) > np.cos(np.deg2rad(5.0))


def test_the_demos_still_test_is_one_interval(tmp_path, capsys):
    """The demo's static test (one still 62 s hold at 1 kHz, accellog.flows.demo) is one still interval
    spanning the emulator's hold, long enough for drift evaluation and noise density, and >= 2 bias
    windows for the gyro."""
    from accellog.flows.demo import CHIP_SEED

    p = tmp_path / "static_test.mcap"
    simulate(Scenario(protocol="+z", hold_s=62.0, chip_seed=CHIP_SEED, seed=3), p)
    (pose,) = read_session(p).poses
    r = _doctor(p, capsys)
    (h,) = r["still_intervals"]
    assert h["start_s"] <= pose.start_s and pose.end_s <= h["end_s"]
    ok = {x["calibration"]: x for x in r["supports"]}
    for name in ("drift evaluation (evaluate / drift)", "noise density (export --to kalibr)", "gyro bias"):
        assert ok[name]["ok"], ok[name]["why"]
    windows = int((h["end_s"] - h["start_s"] - 2 * 0.2) // 1.0)  # the bias fit's windows (0.2 s trimmed)
    assert windows >= 61 and ok["gyro bias"]["why"].startswith(f"{windows} whole 1 s windows in 1 still")
    assert r["distinct_orientations"] == 1 and r["healthy"]


def test_long_streamed_log_against_the_emulators_truth(tmp_path, capsys):
    """A 24-pose log of 309,513 samples (> 2^18: streamed, its still intervals found on every 2nd
    sample) with the bus cut for 0.5 s at 100 s: every sample counted, the one gap found with the
    samples the emulator's events say were lost, and every labelled hold inside one still interval
    (the turns about the vertical keep gravity still: one interval per face)."""
    p = tmp_path / "long.mcap"
    simulate(
        Scenario(protocol="24", hold_s=10.0, seed=5, faults={"disconnect_at_s": 100.0, "disconnect_s": 0.5}),
        p,
    )
    s = read_session(p)
    lost = sum(e.lost_samples for e in s.events)
    assert s.n > 1 << 18 and lost > 400
    r = _doctor(p, capsys)
    assert r["samples"] == s.n and r["duration_s"] == pytest.approx(s.t_s[-1] - s.t_s[0], abs=1e-9)
    kinds = {f["kind"]: f for f in r["findings"]}
    assert kinds["gap"]["count"] == 1 and f"~{lost} samples missing" in kinds["gap"]["detail"]
    assert 99.0 < kinds["gap"]["t_s"][0] < 100.5 and r["events"]["lost_samples"] == lost
    holds = r["still_intervals"]
    assert len(holds) == r["distinct_orientations"] == 6
    for pose in s.poses:
        (h,) = [h for h in holds if h["start_s"] <= pose.start_s and pose.end_s <= h["end_s"]]
        assert np.dot(h["up"], pose.up_sensor) > np.cos(np.deg2rad(5.0))


def _damage(s, *, counts: bool):
    rng = np.random.default_rng(0)
    n = s.n
    keep = np.ones(n, bool)
    keep[400:440] = False  # a 0.2 s gap
    idx = np.flatnonzero(keep)
    t = s.t_s[idx].copy()
    dt = np.median(np.diff(t))
    t[600:900] += rng.uniform(-0.2, 0.2, 300) * dt  # jitter (intervals 0.6..1.4 x)
    t[1000] = t[999]  # duplicate stamp
    t[1200], t[1201] = t[1201], t[1200]  # out of order
    t[1400:1410] = t[1400] + np.arange(10) * 0.05 * dt  # a burst of 10 samples
    ag = s.accel_g[idx].copy()
    ac = None if s.accel_counts is None else s.accel_counts[idx].copy()
    if counts:
        ac[1600:1610, 0] = 32767  # saturated counts
        ag[1600:1610, 0] = 32767 / s.meta.accel_lsb_per_g
    else:
        ac = None
        ag[1600:1610, 2] = ag[:, 2].max()  # a flat top at the extreme: values clipped without counts
    return dataclasses.replace(
        s,
        t_s=t,
        sample_index=np.arange(idx.size, dtype=np.int64),
        accel_g=ag,
        accel_counts=ac,
        gyro_dps=s.gyro_dps[idx],
        gyro_counts=None if s.gyro_counts is None else s.gyro_counts[idx],
        temp_degC=s.temp_degC[idx],
        temp_counts=None if s.temp_counts is None else s.temp_counts[idx],
        host_time_s=None,
        truth=None,
        meta=s.meta if counts else s.meta.replace(accel_lsb_per_g=None),
    )


@pytest.mark.parametrize("counts", [True, False])
def test_damaged_log_every_defect_flagged(clean, tmp_path, capsys, counts):
    bad = tmp_path / "bad.mcap"
    write_session(bad, _damage(read_session(clean), counts=counts))
    rrd = tmp_path / "bad.rrd"
    r = _doctor(bad, capsys, "--rrd", rrd)
    kinds = {f["kind"]: f for f in r["findings"]}
    assert set(kinds) == {"gap", "duplicate", "out_of_order", "burst", "jitter", "clipping"}, kinds.keys()
    # the 40 removed samples are the longest gap (0.205 s); the swap, duplicate and burst leave short ones
    assert "longest 0.205 s" in kinds["gap"]["detail"] and kinds["duplicate"]["count"] == 1
    assert kinds["gap"]["t_s"][0] == pytest.approx(399 * 0.005, abs=1e-6)
    assert kinds["clipping"]["count"] == 10 and not r["healthy"]
    rec = load_rrd(rrd)
    assert rec.bar_values("doctor/interval_histogram").sum() == r["samples"] - 1
    texts = [x for _, x in rec.texts("doctor/findings")]
    assert any(x.startswith("gap:") for x in texts) and any(x.startswith("clipping:") for x in texts)
    assert main(["doctor", str(bad), "--strict"]) == 1
    capsys.readouterr()


def test_ros2_bag_and_csv_inputs(clean, tmp_path, capsys):
    s = read_session(clean)
    bag = session_to_bag(s, tmp_path / "b.mcap")
    r = _doctor(bag, capsys)
    assert r["source"] == "import:ros2" and r["samples"] == s.n and r["healthy"]
    csv = tmp_path / "c.csv"
    csv.write_text("t,ax,ay,az\n" + "\n".join(f"{i * 0.01:.2f},0,0,1" for i in range(50)) + "\n")
    r = _doctor(csv, capsys)
    assert r["samples"] == 50 and r["rate_hz"] == pytest.approx(100.0) and r["healthy"]
    # stamps `import csv` refuses are reported, not refused, by the doctor
    rows = [f"{i * 0.01:.2f},0,0,1" for i in range(50)]
    rows[20] = rows[19]  # duplicate
    rows[30], rows[31] = rows[31], rows[30]  # out of order
    csv.write_text("t,ax,ay,az\n" + "\n".join(rows) + "\n")
    kinds = {f["kind"] for f in _doctor(csv, capsys)["findings"]}
    assert {"duplicate", "out_of_order"} <= kinds
