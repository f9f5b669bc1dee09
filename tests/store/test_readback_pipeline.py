"""read_session's group-by-group conversions (store.reader.ImuAccumulator) against the generic reader, bit for bit,
on files shaped like bench_readback's: accel/gyro/temp counts with host times, FIFO reads of 36 or
30-42 samples, recorder (0.5 s chunks) and write_session (1 MiB chunks) layouts, zstd and lz4, read
in small chunk groups so that group and chunk boundaries fall inside every kind of run."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from accellog.core.session import Session, SessionMeta
from accellog.core.units import temp_counts_to_degC
from accellog.store import reader
from accellog.store.codec import encode
from accellog.store.mcap import fastread
from accellog.store.mcap import index as mcap_index
from accellog.store.mcap.batch_decode import decode_batch
from accellog.store.reader import read_session
from accellog.store.writer import SessionWriter, write_session

NS = 1_000_000_000


def _session(n: int, seed: int) -> Session:
    """bench_readback.simulate in small: counts of a level sensor with noise, warm-up temperature."""
    rng = np.random.default_rng(seed)
    ac = np.round((np.array([0.02, -0.01, 1.0]) + rng.normal(0, 0.004, (n, 3))) * 16384).astype(np.int32)
    gc = np.round(rng.normal(0, 0.05, (n, 3)) * 131 + [30, -12, 5]).astype(np.int32)
    tc = np.round(3000 + rng.normal(0, 3, n)).astype(np.int32)
    meta = SessionMeta(
        source="emulator", accel_lsb_per_g=16384.0, gyro_lsb_per_dps=131.0, sample_rate_hz=1000.0
    )
    t_ns = np.arange(n, dtype=np.int64) * 1_000_000
    return Session(
        meta=meta,
        t_s=t_ns / NS,
        sample_index=np.arange(n, dtype=np.int64),
        accel_g=ac / 16384.0,
        accel_counts=ac,
        gyro_dps=gc / 131.0,
        gyro_counts=gc,
        temp_degC=temp_counts_to_degC(tc.astype(np.float64)),
        temp_counts=tc,
        host_time_s=((np.arange(n) // 36 + 1) * 36_000_000 + 250_000) / NS,
    )


def _recorder(path, s: Session, compression: str, vary: bool, gap: bool) -> None:
    """One message per FIFO read (36 samples, or 30-42 when vary), as the recorder writes them;
    gap: 17 samples lost in the middle (the sample index jumps)."""
    rng = np.random.default_rng(1)
    bounds = [0]
    while bounds[-1] < s.n:
        bounds.append(min(s.n, bounds[-1] + (int(rng.integers(30, 43)) if vary else 36)))
    t_ns = np.round(s.t_s * NS).astype(np.int64)
    with SessionWriter(path, s.meta, compression=compression) as w:
        for i, j in itertools.pairwise(bounds):
            first = i + (17 if gap and i >= s.n // 2 else 0)
            host = round(float(s.host_time_s[j - 1]) * NS)
            w.write_imu(first, t_ns[i:j], s.accel_counts[i:j], s.gyro_counts[i:j], s.temp_counts[i:j], host)


def _same(a: Session, b: Session) -> None:
    for f in dataclasses.fields(Session):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert isinstance(x, np.ndarray) and isinstance(y, np.ndarray), f.name
            assert (x.dtype, x.shape, x.tobytes()) == (y.dtype, y.shape, y.tobytes()), f.name
        elif f.name != "path":
            assert repr(x) == repr(y), f.name


@pytest.mark.parametrize(
    ("layout", "compression", "vary", "gap"),
    [
        ("recorder", "zstd", False, False),
        ("recorder", "lz4", False, True),
        ("recorder", "lz4", True, False),
        ("recorder", "zstd", True, True),
        ("write_session", "zstd", False, False),
        ("write_session", "lz4", False, False),
    ],
)
def test_group_conversions_equal_generic_reader(tmp_path, monkeypatch, layout, compression, vary, gap):
    s = _session(30_000, seed=3)
    p = tmp_path / "b.mcap"
    if layout == "recorder":
        _recorder(p, s, compression, vary, gap)
    else:
        write_session(p, s, compression=compression, chunk_size=64 * 1024)
    monkeypatch.setattr(fastread, "_GROUP_BYTES", 96 << 10)  # many groups: boundaries inside runs
    monkeypatch.setattr(mcap_index, "_INDEX_WINDOW", 7)  # the chunk indexes checked 7 at a time
    ahead, real = [], fastread._ahead
    monkeypatch.setattr(fastread, "_ahead", lambda *a: ahead.append(real(*a)) or ahead[-1])
    col = reader.collect_session(p, accumulator=reader._imu_accumulator)
    assert ahead == [2 if compression == "zstd" else 1]  # small zstd chunks (both layouts here): 2 threads
    assert col.recovered is None and set(col.decoders["/imu"].derived) == {
        "t_s", "accel_g", "gyro_dps", "temp_degC", "host_time_s", "sample_index"
    }  # fmt: skip
    fast = read_session(p)
    monkeypatch.setattr(reader, "FAST_READ", False)
    generic = read_session(p)
    _same(fast, generic)
    assert fast.n == s.n and np.array_equal(fast.accel_counts, s.accel_counts)
    assert np.array_equal(fast.t_s, s.t_s) and np.array_equal(fast.accel_g, s.accel_g)
    if not gap:
        assert np.array_equal(fast.sample_index, np.arange(s.n))


def test_imu_accumulator_grows_while_converting():
    """Parts added with done = 1 make every store grow at every part (realloc) while the previous
    part's conversion may still be running: the columns equal those converted at the end."""
    rng = np.random.default_rng(4)
    msgs, first = [], 5
    for k in range(40):
        m = int(rng.integers(1, 60))
        t = (first + np.arange(m)) * 1_000_000
        msgs.append(
            encode(
                "ImuBatch",
                first_sample_index=first,
                t_ns=t,
                accel_counts=rng.integers(-32768, 32768, 3 * m),
                gyro_counts=rng.integers(-32768, 32768, 3 * m),
                temp_counts=rng.integers(-5000, 5000, m),
                host_time_ns=int(k * 7 + 1),
            )
        )
        first += m + (3 if k == 20 else 0)
    acc = reader.ImuAccumulator("ImuBatch", 16384.0, 131.0)
    for lo in range(0, 40, 7):
        part = b"".join(msgs[lo : lo + 7])
        buf = np.frombuffer(part + bytes(16), np.uint8)
        ends = np.cumsum([len(m) for m in msgs[lo : lo + 7]])
        starts = ends - [len(m) for m in msgs[lo : lo + 7]]
        dec = decode_batch("ImuBatch", buf, starts, ends, None, lo % 14 == 0)  # scalars as arrays or lists
        acc.add(dec, 1.0)
    out = acc.finish()
    counts = out.counts["t_ns"]
    assert out.n_messages == 40 and "t_ns" not in out.arrays  # the times were converted in place
    assert np.asarray(out.scalars["host_time_ns"]).tolist() == [k * 7 + 1 for k in range(40)]
    d = out.derived
    n = int(counts.sum())
    first_idx = np.asarray(out.scalars["first_sample_index"], dtype=np.int64)
    want_idx = np.repeat(first_idx - (np.cumsum(counts) - counts), counts) + np.arange(n)
    assert np.array_equal(d["sample_index"], want_idx)
    assert np.array_equal(d["t_s"], want_idx * 1_000_000 / NS)
    assert d["accel_g"].tobytes() == (out.arrays["accel_counts"] / 16384.0).tobytes()
    assert d["gyro_dps"].tobytes() == (out.arrays["gyro_counts"] / 131.0).tobytes()
    assert d["temp_degC"].tobytes() == temp_counts_to_degC(out.arrays["temp_counts"]).tobytes()
    host = np.asarray(out.scalars["host_time_ns"], dtype=np.int64)
    assert d["host_time_s"].tobytes() == np.repeat(host / NS, counts).tobytes()


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_damaged_chunks_are_still_reported(tmp_path, compression):
    """Bit flips inside the compressed chunks (zstd is decompressed straight into the group buffer):
    every one is refused, reported as damage, or changes nothing."""
    import warnings

    from accellog.core.errors import DataIntegrityWarning, InputError

    s = _session(6000, seed=8)
    p = tmp_path / "ok.mcap"
    _recorder(p, s, compression, vary=True, gap=False)
    ref = read_session(p)
    orig = p.read_bytes()
    rng = np.random.default_rng(9)
    bad = tmp_path / "bad.mcap"
    seen = set()
    for pos in rng.integers(200, len(orig) // 2, 60).tolist():
        b = bytearray(orig)
        b[pos] ^= 1 << int(rng.integers(0, 8))
        bad.write_bytes(b)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DataIntegrityWarning)
            try:
                got = read_session(bad)
            except InputError:
                seen.add("refused")
                continue
        if any(e.kind == "damaged" for e in got.events):
            seen.add("detected")
            assert got.n < ref.n or any("outside the chunks" in e.detail for e in got.events)
        else:
            _same(got, ref)
    assert "detected" in seen


@pytest.mark.parametrize(
    "field", [0, 1, 25, 37, 45]
)  # opcode, length, uncompressed size, name length, records length
def test_chunk_header_disagreeing_with_its_index(tmp_path, monkeypatch, field):
    """The chunk headers are checked as the chunks are decompressed: with a sound summary (CRC) the
    chunk is skipped and named as before; without a summary CRC the generic reader decides."""
    import struct
    import warnings

    from mcap.reader import make_reader

    from accellog.core.errors import DataIntegrityWarning

    s = _session(6000, seed=10)
    p = tmp_path / "ok.mcap"
    _recorder(p, s, "lz4", vary=False, gap=False)
    with open(p, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    at = chunks[len(chunks) // 2].chunk_start_offset
    b = bytearray(p.read_bytes())
    b[at + field] ^= 0x01
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataIntegrityWarning)
        col = fastread.fast_collect(bad)
        assert col is not None
        assert [(d.offset, d.reason) for d in col.damaged] == [(at, "chunk header disagrees with its index")]
        fast = read_session(bad)
        assert fast.n < s.n and any(e.kind == "damaged" for e in fast.events)
        b[-8 - 4 : -8] = struct.pack("<I", 0)  # no summary CRC: the index itself may be the damage
        bad.write_bytes(b)
        assert fastread.fast_collect(bad) is None
        fast = read_session(bad)
        monkeypatch.setattr(reader, "FAST_READ", False)
        _same(fast, read_session(bad))


@pytest.mark.filterwarnings("error::RuntimeWarning")  # no int64 overflow on the way
@pytest.mark.parametrize(
    ("first", "ok"),
    [(2**63 + 5, False), (2**64 - 1, False), (2**63 - 10, False), (2**63 - 36 * 3, True)],
)
def test_first_sample_index_near_int64(tmp_path, monkeypatch, first, ok):
    """first_sample_index is a uint64: indexes beyond int64 are one InputError line in every reader
    (not an OverflowError traceback, not wrapped-around indexes); the last representable one reads."""
    from accellog.core.errors import InputError
    from accellog.store.stream import iter_imu

    s = _session(36 * 3, seed=11)
    p = tmp_path / "big.mcap"
    with SessionWriter(p, s.meta, compression="zstd") as w:
        for k in range(3):
            sl = slice(36 * k, 36 * (k + 1))
            t = np.round(s.t_s[sl] * NS).astype(np.int64)
            w.write_imu(first + 36 * k, t, s.accel_counts[sl], s.gyro_counts[sl], s.temp_counts[sl], k + 1)
    for fast in (True, False):
        monkeypatch.setattr(reader, "FAST_READ", fast)
        if ok:
            got = read_session(p)
            assert got.sample_index[0] == first and got.sample_index[-1] == 2**63 - 1
            assert [int(b.sample_index[-1]) for b in iter_imu(p)] == [2**63 - 1]
            continue
        with pytest.raises(InputError, match="beyond int64") as err:
            read_session(p)
        assert "\n" not in str(err.value) and str(p) in str(err.value)
        with pytest.raises(InputError, match="beyond int64"):
            list(iter_imu(p))


def test_conversion_error_on_the_worker_falls_back(tmp_path, monkeypatch):
    """An exception in a group's conversion (worker thread) surfaces on the reading thread: the fast
    reader declines, the generic reader gives the session, and no worker thread is left behind."""
    import threading

    s = _session(20_000, seed=12)
    p = tmp_path / "b.mcap"
    _recorder(p, s, "zstd", vary=True, gap=False)
    monkeypatch.setattr(fastread, "_GROUP_BYTES", 64 << 10)
    calls = []
    convert = reader.ImuAccumulator._convert

    def failing(self, *args):
        calls.append(1)
        if len(calls) == 3:
            raise MemoryError("worker")
        return convert(self, *args)

    monkeypatch.setattr(reader.ImuAccumulator, "_convert", failing)
    threads = threading.active_count()
    dec = reader.collect_session(p, accumulator=reader._imu_accumulator).decoders["/imu"]
    assert getattr(dec, "derived", None) is None
    assert len(calls) == 3  # it failed mid-file, then the generic reader decided
    got = read_session(p)
    assert threading.active_count() == threads
    monkeypatch.setattr(reader, "FAST_READ", False)
    _same(got, read_session(p))


def test_message_that_does_not_decode_leaves_nothing_behind(tmp_path, monkeypatch):
    """A damaged message in a file without CRCs (uncompressed chunks) ends the salvage there: the
    session is the messages before it, none of the broken message's samples (its t_ns used to be
    kept without its other fields: a traceback, or samples from a message that does not decode)."""
    from mcap.writer import Writer

    from accellog.store import writer

    monkeypatch.setattr(writer, "Writer", lambda f, **kw: Writer(f, **{**kw, "enable_crcs": False}))
    s = _session(36 * 30, seed=13)
    p = tmp_path / "nocrc.mcap"
    with SessionWriter(p, s.meta, compression="none", chunk_size=4096) as w:
        for k in range(30):
            sl = slice(36 * k, 36 * (k + 1))
            t = np.round(s.t_s[sl] * NS).astype(np.int64)
            w.write_imu(36 * k, t, s.accel_counts[sl], s.gyro_counts[sl], s.temp_counts[sl], k + 1)
    b = bytearray(p.read_bytes())
    sl = slice(36 * 20, 36 * 21)
    t = np.round(s.t_s[sl] * NS).astype(np.int64)
    payload = encode("ImuBatch", first_sample_index=36 * 20, t_ns=t, accel_counts=s.accel_counts[sl],
                     gyro_counts=s.gyro_counts[sl], temp_counts=s.temp_counts[sl], host_time_ns=21)  # fmt: skip
    at = bytes(b).index(payload)
    b[at] = 2 << 3 | 2  # t_ns first, its length running past the message: t_ns parsed, then truncated
    b[at + 1] = 0x7F
    p.write_bytes(b)
    for fast in (True, False):
        monkeypatch.setattr(reader, "FAST_READ", fast)
        got = read_session(p)
        assert got.n == 36 * 20 and np.array_equal(got.accel_counts, s.accel_counts[: 36 * 20])
        (ev,) = [e for e in got.events if e.kind == "recovered"]
        assert "salvaged 20 messages" in ev.detail


def test_worker_thread_stopped_when_the_fast_reader_declines_mid_file(tmp_path, monkeypatch):
    """A surprise mid-file (here: a group that is not canonical protobuf) stops the conversion
    thread at once, not when the garbage collector finds the abandoned accumulator."""
    import gc
    import threading

    s = _session(20_000, seed=14)
    p = tmp_path / "b.mcap"
    _recorder(p, s, "lz4", vary=True, gap=False)
    monkeypatch.setattr(fastread, "_GROUP_BYTES", 64 << 10)
    calls = []

    def decode(*args):
        calls.append(1)
        return None if len(calls) == 5 else decode_batch(*args)

    monkeypatch.setattr(fastread, "decode_batch", decode)
    threads = threading.active_count()
    gc.disable()
    try:
        for _ in range(3):
            calls.clear()
            assert fastread.fast_collect(p, None, reader._imu_accumulator) is None
            assert threading.active_count() == threads
    finally:
        gc.enable()
