"""MCAP storage: exact round trips, validation by independent readers, crash safety and recovery."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import Writer

from accellog.core.errors import InputError
from accellog.core.session import Event, PoseLabel, Session, SessionMeta, Truth
from accellog.store import reader
from accellog.store.codec import encode
from accellog.store.layout import meta_to_metadata
from accellog.store.mcap import fastread, field_walk, record_starts
from accellog.store.reader import read_attachments, read_session, read_vector3, session_summary
from accellog.store.schema import file_descriptor_set_bytes, full_name, stock_message_class
from accellog.store.writer import SessionWriter, write_session

NS = 1_000_000_000


def _meta(**kw) -> SessionMeta:
    base = dict(
        source="emulator",
        who_am_i=0x71,
        accel_range_g=2.0,
        gyro_range_dps=250.0,
        accel_lsb_per_g=16384.0,
        gyro_lsb_per_dps=131.0,
        dlpf_cfg=3,
        a_dlpf_cfg=None,
        sample_rate_hz=1000.0,
        local_gravity_mps2=9.797,
        software="accellog test",
        host="h",
        protocol="six",
        start_time_unix_ns=1_700_000_000_000_000_000,
        extra={"scenario": json.dumps({"seed": 3}), "note": "a=b, c"},
    )
    base.update(kw)
    return SessionMeta(**base)


def _session(seed: int = 0, n: int = 20_000) -> Session:
    """Simulated session with gaps, per-batch host times, mag, poses, events and truth."""
    rng = np.random.default_rng(seed)
    si = np.arange(n, dtype=np.int64)
    si[5000:] += 7  # a gap of 7 samples
    si[12000:] += 36  # an overflow
    t_ns = si * 1_000_000 + rng.integers(-2000, 2000, n)  # jittery sensor time
    t_ns.sort()
    host_ns = (np.arange(n) // 36 + 1) * 36_000_000 + 123  # one host time per 36-sample FIFO read
    ac = rng.integers(-32768, 32768, (n, 3)).astype(np.int32)
    gc = rng.integers(-32768, 32768, (n, 3)).astype(np.int32)
    tc = rng.integers(-3000, 3000, n).astype(np.int32)
    m = n // 10
    mc = rng.integers(-4912, 4912, (m, 3)).astype(np.int32)
    k = n // 10
    truth = Truth(
        t_s=np.arange(k) * 10_000_000 / NS,  # times are stored as int ns
        specific_force_g=rng.normal(size=(k, 3)),
        omega_dps=rng.normal(size=(k, 3)),
        position_m=rng.normal(size=(k, 3)),
        velocity_mps=rng.normal(size=(k, 3)),
        q_sensor_to_world=rng.normal(size=(k, 4)),
        temp_degC=rng.normal(25, 1, k),
    )
    return Session(
        meta=_meta(),
        t_s=t_ns / NS,
        sample_index=si,
        accel_g=ac / 16384.0,
        accel_counts=ac,
        gyro_dps=gc / 131.0,
        gyro_counts=gc,
        temp_degC=tc / 333.87 + 21.0,
        temp_counts=tc,
        host_time_s=host_ns / NS,
        mag_t_s=np.arange(m) * 10_000_000 / NS,
        mag_uT=mc * 0.15 * 1.05,
        mag_counts=mc,
        mag_st2=rng.integers(0, 256, m).astype(np.uint8),
        poses=[
            PoseLabel("+z", 0.5, 4.25, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0), 0),
            PoseLabel("custom", 5.0, 9.5, (0.6, 0.0, 0.8), None, 1),
        ],
        events=[
            Event(5.0, "gap", "7 samples missing", 5000, 7),
            Event(12.0, "fifo_overflow", "FIFO full", 12000, 36),
            Event(13.5, "note", "héllo, wörld"),
        ],
        truth=truth,
    )


def _assert_same(a: Session, b: Session, *, n: int | None = None) -> None:
    n = a.n if n is None else n
    assert b.meta == a.meta
    assert np.array_equal(b.t_s, a.t_s[:n])
    assert np.array_equal(b.sample_index, a.sample_index[:n])
    for name in ("accel_counts", "gyro_counts", "temp_counts"):
        x, y = getattr(a, name), getattr(b, name)
        assert y.dtype == np.int32 and np.array_equal(y, x[:n]), name
    for name in ("accel_g", "gyro_dps", "temp_degC", "host_time_s"):
        assert np.array_equal(getattr(b, name), getattr(a, name)[:n]), name


def test_round_trip_bit_exact(tmp_path):
    s = _session()
    p = write_session(tmp_path / "s.mcap", s, batch_size=100)
    r = read_session(p)
    _assert_same(s, r)
    assert np.array_equal(r.mag_t_s, s.mag_t_s)
    assert np.array_equal(r.mag_counts, s.mag_counts)
    assert np.array_equal(r.mag_uT, s.mag_uT)
    assert np.array_equal(r.mag_st2, s.mag_st2)
    assert r.poses == s.poses
    assert r.events == s.events
    for f in (
        "t_s",
        "specific_force_g",
        "omega_dps",
        "position_m",
        "velocity_mps",
        "q_sensor_to_world",
        "temp_degC",
    ):
        assert np.array_equal(getattr(r.truth, f), getattr(s.truth, f)), f
    assert r.path == str(p)
    assert r.lost_samples() == 43
    assert not list(tmp_path.glob(".*tmp"))  # no temp file left


def test_values_only_session_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    n = 3001
    s = Session(
        meta=SessionMeta(source="import:csv", sample_rate_hz=100.0, extra={"source_unit": "m/s^2"}),
        t_s=np.cumsum(rng.uniform(0.004, 0.006, n)),
        sample_index=np.arange(n),
        accel_g=rng.normal(size=(n, 3)),
        gyro_dps=rng.normal(size=(n, 3)),
        temp_degC=rng.normal(30, 1, n),
    )
    r = read_session(write_session(tmp_path / "v.mcap", s))
    assert r.meta == s.meta
    assert np.array_equal(r.accel_g, s.accel_g) and r.accel_counts is None
    assert np.array_equal(r.gyro_dps, s.gyro_dps) and r.gyro_counts is None
    assert np.array_equal(r.temp_degC, s.temp_degC) and r.host_time_s is None
    assert r.mag_t_s is None and r.truth is None and r.poses == [] and r.events == []


def test_counts_not_matching_values_keep_both(tmp_path):
    s = _session(n=2000)
    s.accel_g = s.accel_g + 1e-3  # values not counts/LSB (e.g. a preprocessed source)
    r = read_session(write_session(tmp_path / "b.mcap", s))
    assert np.array_equal(r.accel_g, s.accel_g) and np.array_equal(r.accel_counts, s.accel_counts)


def test_files_pass_independent_readers(tmp_path):
    p = write_session(tmp_path / "s.mcap", _session(n=5000), batch_size=36)
    # the mcap library: indexed reader with chunk CRCs, and a streaming pass with the data-section CRC
    with open(p, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        msgs = list(reader.iter_messages())
        summ = reader.get_summary()
    assert len(msgs) == summ.statistics.message_count > 140
    with open(p, "rb") as f:
        assert sum(
            1 for _ in NonSeekingReader(f, validate_crcs=True).iter_messages(log_time_order=False)
        ) == len(msgs)
    # the stock protobuf runtime decodes the /imu payloads to the same arrays
    cls = stock_message_class("ImuBatch")
    imu = [cls.FromString(m.data) for s, c, m in msgs if c.topic == "/imu"]
    r = read_session(p)
    assert np.array_equal(
        np.concatenate([np.array(list(m.accel_counts)) for m in imu]), r.accel_counts.ravel()
    )
    assert np.array_equal(np.concatenate([np.array(list(m.t_ns)) for m in imu]), np.round(r.t_s * NS))
    assert all(s.encoding == "protobuf" and s.name.startswith("accellog.v1.") for s, c, m in msgs)
    # Rerun's MCAP reader (a second, independent implementation)
    rerun = shutil.which("rerun")
    if rerun is None:
        pytest.skip("rerun binary not found")
    env = dict(os.environ, RERUN_ANALYTICS="0")
    out = subprocess.run(
        [rerun, "mcap", "info", str(p)], capture_output=True, text=True, env=env, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert re.search(rf"/imu\s+{len(imu)}\s", out.stdout), out.stdout
    assert "accellog.v1.ImuBatch" in out.stdout
    chk = subprocess.run(
        [rerun, "mcap", "check", str(p)], capture_output=True, text=True, env=env, timeout=120
    )
    assert chk.returncode == 0 and re.search(r"ok\s+\d+\s+\d+\s+/imu", chk.stdout), chk.stdout


def test_writer_streaming_api(tmp_path):
    meta = _meta(start_time_unix_ns=0)
    p = tmp_path / "w.mcap"
    with SessionWriter(p, meta, flush_interval_s=0.5) as w:
        for b in range(500):  # 10 s at 1 kHz in 20-sample batches
            idx = b * 20 + np.arange(20)
            w.write_imu(
                b * 20, idx * 1_000_000, accel_counts=np.stack([idx, -idx, idx % 7], 1), host_time_ns=1
            )
        w.write_mag(
            [0, 10_000_000],
            mag_counts=[[100, -200, 300], [1, 2, 3]],
            st2=[16, 24],
            asa_factor=[1.1, 0.9, 1.0],
            ut_per_lsb=0.15,
        )
        w.write_event(Event(1.0, "note", "hi"))
        w.write_pose(PoseLabel("+x", 1.0, 2.0, (1.0, 0.0, 0.0)))
        w.write_vector3("accel_cal", np.arange(4) * 1000, np.arange(12.0).reshape(4, 3), "g")
        w.attach("calibration/accel.json", "application/json", b'{"b": [0, 0, 0]}')
        assert (w.samples_written, w.events_written, w.poses_written, w.mag_samples_written) == (
            10_000,
            1,
            1,
            2,
        )
        assert w.flushes >= 19  # at least every 0.5 s of sensor time
    summ = session_summary(p)
    assert summ["finished"] and summ["chunks"] >= 19 and summ["topics"]["/imu"]["messages"] == 500
    assert (
        summ["metadata"]["accel_lsb_per_g"] == "16384.0"
        and summ["metadata"]["schema_version"] == "accellog.v1"
    )
    assert summ["attachments"] == [("calibration/accel.json", "application/json", 16)]
    r = read_session(p)
    assert r.n == 10_000 and np.array_equal(r.accel_counts[:, 0], np.arange(10_000))
    assert np.allclose(
        r.mag_uT, [[100 * 1.1 * 0.15, -200 * 0.9 * 0.15, 300 * 0.15], [1.1 * 0.15, 2 * 0.9 * 0.15, 3 * 0.15]]
    )
    assert r.mag_st2.tolist() == [16, 24]
    t, v, unit, frame = read_vector3(p, "/derived/accel_cal")
    assert np.array_equal(v, np.arange(12.0).reshape(4, 3)) and unit == "g" and frame == "sensor"
    assert np.array_equal(t, np.arange(4) * 1e-6)
    assert read_attachments(p) == [("calibration/accel.json", "application/json", b'{"b": [0, 0, 0]}')]
    with pytest.raises(InputError, match="no derived channel"):
        read_vector3(p, "nothing")


def test_exception_inside_with_still_finishes_file(tmp_path):
    p = tmp_path / "e.mcap"
    with pytest.raises(RuntimeError, match="boom"), SessionWriter(p, _meta()) as w:
        w.write_imu(0, [0, 1_000_000], accel_counts=np.ones((2, 3), int))
        raise RuntimeError("boom")
    assert session_summary(p)["finished"]
    r = read_session(p)
    assert r.n == 2 and r.events[-1].kind == "note" and "RuntimeError: boom" in r.events[-1].detail
    assert not any(e.kind == "recovered" for e in r.events)


def test_truncated_file_recovery_at_many_cut_points(tmp_path):
    s = _session(seed=3, n=30_000)
    s.truth = None
    full = write_session(tmp_path / "full.mcap", s, batch_size=36, chunk_size=32 * 1024).read_bytes()
    last_n = 0
    for frac in (0.2, 0.35, 0.5, 0.65, 0.8, 0.95, 0.999):
        cut = tmp_path / f"cut{frac}.mcap"
        cut.write_bytes(full[: int(len(full) * frac)])
        r = read_session(cut)
        assert 0 < r.n <= s.n
        assert r.n >= last_n  # more file, more data
        last_n = r.n
        _assert_same(s, r, n=r.n)  # what survives is an exact prefix
        assert r.n >= frac * s.n - 2 * 32 * 1024 / 40  # lose at most ~ one chunk
        rec = [e for e in r.events if e.kind == "recovered"]
        assert len(rec) == 1 and "salvaged" in rec[0].detail
    # cut before any complete chunk: one-line error
    small = tmp_path / "small.mcap"
    small.write_bytes(full[:200])
    with pytest.raises(InputError, match=r"truncated|no IMU"):
        read_session(small)
    assert not session_summary(cut)["finished"]


def test_recovery_agrees_with_rerun_recover(tmp_path):
    rerun = shutil.which("rerun")
    if rerun is None:
        pytest.skip("rerun binary not found")
    s = _session(seed=4, n=20_000)
    full = write_session(tmp_path / "f.mcap", s, batch_size=36, chunk_size=32 * 1024).read_bytes()
    cut = tmp_path / "c.mcap"
    cut.write_bytes(full[: len(full) * 3 // 5])
    summ = session_summary(cut)
    env = dict(os.environ, RERUN_ANALYTICS="0")
    out = subprocess.run(
        [rerun, "mcap", "info", "--recover", str(cut)], capture_output=True, text=True, env=env, timeout=120
    )
    m = re.search(r"/imu\s+(\d+)\s", out.stdout)
    assert m, out.stdout + out.stderr
    assert summ["topics"]["/imu"]["messages"] == int(m.group(1))


def test_unfinished_writer_is_recovered(tmp_path):
    """A writer that never finished (as if the process died): everything up to the last flush survives."""
    p = tmp_path / "u.mcap"
    w = SessionWriter(p, _meta(), flush_interval_s=0.5)
    for b in range(100):  # 2 s
        idx = b * 20 + np.arange(20)
        w.write_imu(b * 20, idx * 1_000_000, accel_counts=np.stack([idx, idx, idx], 1))
    snap = tmp_path / "snap.mcap"
    shutil.copyfile(p, snap)  # file as a killed process leaves it (Python buffers lost)
    w.close()
    r = read_session(snap)
    assert 2000 - 500 <= r.n <= 2000
    assert np.array_equal(r.accel_counts[:, 0], np.arange(r.n))
    assert r.events[-1].kind == "recovered"
    assert r.meta == _meta()


_KILL_SCRIPT = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from accellog.store.writer import SessionWriter
    from accellog.core.session import SessionMeta

    meta = SessionMeta(source="emulator", accel_lsb_per_g=16384.0, gyro_lsb_per_dps=131.0, sample_rate_hz=1000.0)
    with SessionWriter(sys.argv[1], meta) as w:
        i = 0
        while True:
            idx = i + np.arange(20)
            a = np.stack([idx % 32768, -(idx % 32768), idx % 999], 1)
            w.write_imu(i, idx * 1_000_000, accel_counts=a, gyro_counts=a, temp_counts=idx % 1000,
                        host_time_ns=int(idx[-1]) * 1_000_000)
            i += 20
            print(i, flush=True)
            time.sleep(0.004)  # ~5x faster than real time: 1 kHz sensor time
    """
)


def test_sigkill_loses_at_most_about_one_second(tmp_path):
    script = tmp_path / "rec.py"
    script.write_text(_KILL_SCRIPT)
    rng = np.random.default_rng(11)
    env = dict(os.environ, RERUN_ANALYTICS="0")
    for trial, delay in enumerate(rng.uniform(0.3, 1.8, 3)):
        p = tmp_path / f"k{trial}.mcap"
        proc = subprocess.Popen(
            [sys.executable, str(script), str(p)], stdout=subprocess.PIPE, text=True, env=env
        )
        assert proc.stdout.readline().strip() == "20"  # recording has started
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        lines = proc.stdout.read().split()
        proc.stdout.close()
        written = int(lines[-1]) if lines else 20
        assert written > 200
        r = read_session(p)
        assert written - 1000 <= r.n <= written + 20, (trial, written, r.n)
        assert np.array_equal(r.sample_index, np.arange(r.n))
        assert np.array_equal(r.accel_counts[:, 0], np.arange(r.n) % 32768)
        assert np.array_equal(r.temp_counts, np.arange(r.n) % 1000)
        assert r.events[-1].kind == "recovered"


def test_bad_files_give_one_line_errors(tmp_path):
    txt = tmp_path / "a.csv"
    txt.write_text("t,ax\n0,1\n")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    other = tmp_path / "other.mcap"
    with open(other, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("foo.Bar", "jsonschema", b"{}")
        cid = w.register_channel("/imu", "json", sid)
        w.add_message(cid, log_time=0, publish_time=0, data=b"{}")
        w.finish()
    cases = [
        (tmp_path / "missing.mcap", "no such file"),
        (txt, "not an MCAP file"),
        (empty, "empty file"),
        (other, r"no /imu channel of accellog.v1.ImuBatch \(channels: /imu \(foo.Bar as json\)\)"),
    ]
    for path, msg in cases:
        with pytest.raises(InputError, match=msg) as ei:
            read_session(path)
        assert "\n" not in str(ei.value) and str(path) in str(ei.value)
    no_samples = tmp_path / "nosamples.mcap"
    with SessionWriter(no_samples, _meta()) as w:
        w.write_event(Event(0.0, "note", "nothing recorded"))
    with pytest.raises(InputError, match="no IMU samples"):
        read_session(no_samples)


# --- the vectorised reader (fast_collect) against the generic one (mcap reader + BatchDecoder) -----------


def _read_both(path, monkeypatch) -> tuple[Session, Session]:
    fast = read_session(path)
    monkeypatch.setattr(reader, "FAST_READ", False)
    generic = read_session(path)
    monkeypatch.setattr(reader, "FAST_READ", True)
    return fast, generic


def _same_value(x, y) -> bool:
    if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
        return (
            isinstance(x, np.ndarray)
            and isinstance(y, np.ndarray)
            and x.dtype == y.dtype
            and x.shape == y.shape
            and x.tobytes() == y.tobytes()
        )
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return type(x) is type(y) and all(
            _same_value(getattr(x, f.name), getattr(y, f.name)) for f in dataclasses.fields(x)
        )
    if isinstance(x, list | tuple):
        return type(x) is type(y) and len(x) == len(y) and all(map(_same_value, x, y))
    return type(x) is type(y) and (x == y or (x != x and y != y))


def _assert_identical(a: Session, b: Session) -> None:
    """Bit-identical Sessions: every field, dtype, shape, pose, event (types included)."""
    for f in dataclasses.fields(Session):
        assert _same_value(getattr(a, f.name), getattr(b, f.name)), f.name


def _recorder_file(path, seed: int, compression: str = "zstd", shuffle: bool = False):
    """As the recorder writes: FIFO reads of 30-40 samples, gaps, events, poses, mag, derived, truth."""
    rng = np.random.default_rng(seed)
    meta = _meta()
    batches, i = [], 0
    while i < 9000:
        n = int(rng.integers(30, 41))
        if rng.random() < 0.02:
            i += int(rng.integers(1, 50))  # lost samples
        batches.append((i, n))
        i += n
    if shuffle:  # batches out of order (and one overlapping the previous): read_session sorts samples
        rng.shuffle(batches)
        batches.append((batches[-1][0] + 3, 10))
    with SessionWriter(path, meta, compression=compression, flush_interval_s=0.25) as w:
        for k, (i, n) in enumerate(batches):
            idx = i + np.arange(n)
            ac = rng.integers(-32768, 32768, (n, 3))
            w.write_imu(
                i, idx * 1_000_000, ac, ac[:, ::-1], idx % 3000, host_time_ns=int(idx[-1]) * 1_000_000 + 7
            )
            if k % 3 == 0:
                w.write_mag(
                    [int(idx[0]) * 1_000_000],
                    mag_counts=[[k, -k, 2 * k]],
                    st2=[16],
                    asa_factor=[1.1, 0.9, 1.0],
                    ut_per_lsb=0.15,
                )
            if k % 50 == 0:
                w.write_event(Event(i / 1000, "gap", f"batch {k} ✓", i, k % 4))
                w.write_pose(PoseLabel(f"+z@{k}", i / 1000, i / 1000 + 0.5, (0.0, 0.6, 0.8), None, k))
        w.write_vector3("accel_cal", np.arange(5) * 1000, np.arange(15.0).reshape(5, 3), "g")
        w.write_truth(_session(seed, n=3000).truth, batch_size=128)
    return path


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_fast_reader_equals_generic_recorder_files(tmp_path, monkeypatch, compression):
    p = _recorder_file(tmp_path / "r.mcap", seed=1, compression=compression)
    assert fastread.fast_collect(p) is not None  # the fast path is taken
    fast, generic = _read_both(p, monkeypatch)
    _assert_identical(fast, generic)
    assert (
        fast.n > 8000 and fast.mag_t_s is not None and fast.poses and fast.events and fast.truth is not None
    )
    assert read_vector3(p, "accel_cal")[1].tolist() == np.arange(15.0).reshape(5, 3).tolist()


def test_fast_reader_equals_generic_out_of_order_batches(tmp_path, monkeypatch):
    p = _recorder_file(tmp_path / "s.mcap", seed=2, shuffle=True)
    assert fastread.fast_collect(p) is not None
    fast, generic = _read_both(p, monkeypatch)
    _assert_identical(fast, generic)
    assert np.all(np.diff(fast.sample_index) >= 0)


@pytest.mark.parametrize(
    ("batch_size", "chunk_size", "compression"),
    [(36, 32 * 1024, "zstd"), (500, 1024 * 1024, "lz4"), (7, 4096, "none")],
)
def test_fast_reader_equals_generic_write_session(tmp_path, monkeypatch, batch_size, chunk_size, compression):
    s = _session(seed=5, n=12_000)
    p = write_session(
        tmp_path / "w.mcap", s, batch_size=batch_size, chunk_size=chunk_size, compression=compression
    )
    assert fastread.fast_collect(p) is not None
    fast, generic = _read_both(p, monkeypatch)
    _assert_identical(fast, generic)
    _assert_same(s, fast)


def test_fast_reader_equals_generic_value_fields(tmp_path, monkeypatch):
    rng = np.random.default_rng(6)
    n = 5001
    imported = Session(
        meta=SessionMeta(source="import:csv", sample_rate_hz=100.0, extra={"source_unit": "m/s^2"}),
        t_s=np.cumsum(rng.uniform(0.004, 0.006, n)),
        sample_index=np.arange(n),
        accel_g=rng.normal(size=(n, 3)),
        gyro_dps=rng.normal(size=(n, 3)),
        temp_degC=rng.normal(30, 1, n),
    )
    both = _session(seed=7, n=4000)
    both.accel_g = both.accel_g + 1e-3  # counts and values stored
    for i, s in enumerate((imported, both)):
        p = write_session(tmp_path / f"v{i}.mcap", s, batch_size=333)
        assert fastread.fast_collect(p) is not None
        fast, generic = _read_both(p, monkeypatch)
        _assert_identical(fast, generic)


def test_fast_reader_declines_truncated_files(tmp_path, monkeypatch):
    full = _recorder_file(tmp_path / "full.mcap", seed=8).read_bytes()
    for frac in (0.3, 0.7, 0.9999):
        cut = tmp_path / f"cut{frac}.mcap"
        cut.write_bytes(full[: int(len(full) * frac)])
        assert fastread.fast_collect(cut) is None  # unfinished: the generic reader salvages it
        fast, generic = _read_both(cut, monkeypatch)
        _assert_identical(fast, generic)
        assert fast.events[-1].kind == "recovered"


def _foreign_imu_file(path, payloads: list[bytes]) -> None:
    """A valid MCAP file of accellog.v1.ImuBatch messages written byte by byte by another program."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("session", meta_to_metadata(_meta()))
        sid = w.register_schema(full_name("ImuBatch"), "protobuf", file_descriptor_set_bytes())
        cid = w.register_channel("/imu", "protobuf", sid)
        for k, data in enumerate(payloads):
            w.add_message(cid, log_time=k, publish_time=k, data=data, sequence=k)
        w.finish()


def test_fast_reader_falls_back_on_foreign_encodings(tmp_path, monkeypatch):
    good = [
        encode("ImuBatch", first_sample_index=10 * k, t_ns=np.arange(10) + 10 * k, accel_counts=np.ones(30))
        for k in range(20)
    ]
    # field 1 after field 2 and an unknown field 12: valid protobuf, not our canonical layout
    reordered = encode("ImuBatch", t_ns=np.arange(10) + 200, accel_counts=np.ones(30)) + encode(
        "ImuBatch", first_sample_index=200
    )
    unknown = encode("ImuBatch", first_sample_index=210, t_ns=np.arange(10) + 210, accel_counts=np.ones(30))
    unknown += bytes([12 << 3]) + b"\x05"
    p = tmp_path / "foreign.mcap"
    _foreign_imu_file(p, [*good, reordered, unknown])
    assert fastread.fast_collect(p) is None
    fast, generic = _read_both(p, monkeypatch)
    _assert_identical(fast, generic)
    assert fast.n == 220 and np.array_equal(fast.sample_index, np.arange(220))
    ok = tmp_path / "canonical.mcap"
    _foreign_imu_file(ok, good)  # the same writer with canonical payloads: fast path
    assert fastread.fast_collect(ok) is not None
    _assert_identical(*_read_both(ok, monkeypatch))


def test_fast_reader_equals_generic_steady_recorder_stream(tmp_path, monkeypatch):
    """The common case: 36-sample FIFO reads (record walk guesses hit, one message layout per group,
    except where the first_sample_index varint grows at 128 and 16384), read in many small chunk
    groups (decompressed ahead on a thread) with the unit conversions split over two threads."""
    meta = _meta()
    rng = np.random.default_rng(5)
    n = 20_000
    ac = rng.integers(-32768, 32768, (n, 3))
    p = tmp_path / "steady.mcap"
    with SessionWriter(p, meta, compression="lz4") as w:
        for i in range(0, n, 36):
            j = min(i + 36, n)
            idx = np.arange(i, j)
            w.write_imu(i, idx * 1_000_000, ac[i:j], ac[i:j, ::-1], idx % 3000, host_time_ns=(1 << 40) + j)
    uniform = []
    real = field_walk._uniform_layout
    monkeypatch.setattr(field_walk, "_uniform_layout", lambda *a: uniform.append(real(*a)) or uniform[-1])
    monkeypatch.setattr(fastread, "_GROUP_BYTES", 16 << 10)
    monkeypatch.setattr(reader, "_SPLIT_MIN", 1000)
    fast, generic = _read_both(p, monkeypatch)
    _assert_identical(fast, generic)
    assert (
        fast.n == n
        and np.array_equal(fast.accel_counts, ac)
        and np.array_equal(fast.sample_index, np.arange(n))
    )
    assert np.array_equal(fast.accel_g, ac / meta.accel_lsb_per_g)
    assert len(uniform) > 20 and any(uniform) and not all(uniform)  # both field walks were taken


@pytest.mark.parametrize("per_chunk", [450, 10])
def test_message_starts_runs_and_steps(per_chunk):
    """The record walks find every Message record, in order, whether lengths repeat (guessed runs),
    vary from record to record (stepped in Python) or alternate between the two, across chunk ends;
    many small chunks are walked side by side (chunkwise_starts), a long chunk makes it give up."""
    rng = np.random.default_rng(11)
    lengths = [40] * 300 + [int(x) for x in rng.integers(22, 90, 700)] + [50] * 100 + [60, 61] * 200
    lengths += [int(x) for x in rng.integers(22, 25, 500)] + [70] * 2000
    chunks, starts, pos = [], [], 0
    for lo in range(0, len(lengths), per_chunk):
        body = b""
        for ln in lengths[lo : lo + per_chunk]:
            starts.append(pos + len(body))
            body += bytes([0x05]) + ln.to_bytes(8, "little") + rng.integers(0, 256, ln, np.uint8).tobytes()
        chunks.append(body)
        pos += len(body)
    records = bytearray(b"".join(chunks) + bytes(16))
    sizes = [len(c) for c in chunks]
    assert record_starts.message_starts(records, sizes).tolist() == starts
    chunkwise = record_starts.chunkwise_starts(records, sizes)
    assert (chunkwise is None) == (per_chunk > record_starts.MAX_STEPS)
    assert chunkwise is None or chunkwise.tolist() == starts
    bad = [sizes[0] - 1, sizes[1] + 1, *sizes[2:]]  # a record across a chunk end
    for walk in (record_starts.message_starts, record_starts.chunkwise_starts):
        with pytest.raises(fastread.NotFast):
            walk(records, bad)


def test_equal_records_guess_checks_every_record():
    """The all-chunks guess (each chunk: Messages of its first record's length) keeps only chunks
    whose every guessed record it checked: a chunk whose size is a multiple of the guessed stride
    but whose records differ, one that starts with another record, and one that does not divide
    evenly are left to the walk; the offsets kept are those of the walk."""
    from accellog.store.mcap.index import equal_records

    def rec(op: int, ln: int) -> bytes:
        return bytes([op]) + ln.to_bytes(8, "little") + bytes([5]) * ln  # payload bytes look like opcodes

    chunks = [
        [(5, 40)] * 5,
        [(5, 40), (5, 31), (5, 49)],
        [(0x0A, 40), (5, 40)],
        [(5, 60)] * 3,
        [(5, 40), (5, 41)],
    ]
    bodies = [b"".join(rec(*r) for r in c) for c in chunks]
    assert len(bodies[1]) == 3 * 49  # a multiple of the first record's stride
    sizes = np.array([len(b) for b in bodies], dtype=np.int64)
    end = np.cumsum(sizes)
    rb = np.frombuffer(bytearray(b"".join(bodies) + bytes(16)), np.uint8)
    found, left = equal_records(rb, end - sizes, end)
    assert left.tolist() == [False, True, True, False, True]
    first, fourth = int(end[0] - sizes[0]), int(end[3] - sizes[3])
    assert found[0].tolist() == [first + 49 * k for k in range(5)] + [fourth + 69 * k for k in range(3)]
    records = bytearray(rb.tobytes())
    walked = record_starts.chunkwise_starts(records, sizes.tolist())
    assert walked is not None and set(found[0].tolist()) <= set(walked.tolist())
