"""Corruption is detected: bit flips anywhere in a recorded MCAP file are caught by the chunk,
data-section and summary CRCs (skipped and named, or refused), or provably change nothing."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

import accellog.store.reader as reader
from accellog.cli import main
from accellog.core.errors import DataIntegrityWarning, InputError
from accellog.flows.simulate import Scenario, simulate

ARRAYS = ("t_s", "sample_index", "accel_g", "accel_counts", "gyro_dps", "gyro_counts", "temp_degC")
ARRAYS += ("temp_counts", "host_time_s", "mag_t_s", "mag_uT", "mag_counts", "mag_st2")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """A six-position session through the real recording path (chip -> driver -> Recorder -> MCAP,
    0.5 s chunks, magnetometer, poses, truth): ~230 kB, ~45 chunks."""
    p = tmp_path_factory.mktemp("rec") / "six.mcap"
    simulate(Scenario(protocol="six", hold_s=2.5, move_s=1.0, sample_rate_hz=200.0), p)
    return p


def _same(a, b) -> bool:
    for k in ARRAYS:
        x, y = getattr(a, k), getattr(b, k)
        if (x is None) != (y is None) or (x is not None and not np.array_equal(x, y)):
            return False
    truth_same = (a.truth is None) == (b.truth is None) and (
        a.truth is None or np.array_equal(a.truth.position_m, b.truth.position_m)
    )
    return a.poses == b.poses and a.events == b.events and a.meta == b.meta and truth_same


def _classify(path: Path, ref) -> str:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataIntegrityWarning)
        try:
            s = reader.read_session(path)
        except InputError:
            return "refused"
    if any(e.kind in ("damaged", "recovered") for e in s.events):
        return "detected"
    return "harmless" if _same(s, ref) else "silently different"


@pytest.mark.parametrize("fast", [True, False], ids=["fast-path", "generic-path"])
def test_bit_flips_are_detected_or_harmless(recorded, tmp_path, monkeypatch, fast):
    """200 single-bit flips at random positions: none gives silently different samples or a
    traceback (any exception but InputError fails the test)."""
    monkeypatch.setattr(reader, "FAST_READ", fast)
    ref = reader.read_session(recorded)
    orig = recorded.read_bytes()
    rng = np.random.default_rng(12 if fast else 13)
    bad = tmp_path / "flipped.mcap"
    outcome: dict[str, list[int]] = {}
    for pos in rng.integers(0, len(orig), 200).tolist():
        b = bytearray(orig)
        b[pos] ^= 1 << int(rng.integers(0, 8))
        bad.write_bytes(b)
        outcome.setdefault(_classify(bad, ref), []).append(pos)
    counts = {k: len(v) for k, v in outcome.items()}
    print(f"bit flips ({'fast' if fast else 'generic'} path): {counts}")
    assert "silently different" not in outcome, outcome["silently different"]
    assert counts.get("detected", 0) + counts.get("refused", 0) >= 190  # the CRCs cover every byte


def test_damaged_chunk_is_skipped_named_and_counted(recorded, tmp_path):
    """A flip inside a middle chunk: that chunk is skipped, the rest is read exactly, the Event
    names its byte offset and time range and counts exactly the IMU samples it held."""
    ref = reader.read_session(recorded)
    orig = recorded.read_bytes()
    bad = tmp_path / "bad.mcap"
    with open(recorded, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    mid = chunks[len(chunks) // 3]
    b = bytearray(orig)
    b[mid.chunk_start_offset + mid.chunk_length // 2] ^= 0x10  # inside its compressed records
    bad.write_bytes(b)
    for fast in (True, False):
        reader.FAST_READ = fast
        try:
            with pytest.warns(DataIntegrityWarning, match=r"damaged chunk at byte \d+ \(t [\d.]+-[\d.]+ s\)"):
                s = reader.read_session(bad)
        finally:
            reader.FAST_READ = True
        (ev,) = [e for e in s.events if e.kind == "damaged"]
        assert ev.lost_samples == ref.n - s.n > 0
        keep = np.isin(ref.sample_index, s.sample_index)
        np.testing.assert_array_equal(ref.accel_counts[keep], s.accel_counts)  # the rest is exact


def test_cli_prints_the_damage_on_stderr(recorded, tmp_path, capsys):
    with open(recorded, "rb") as f:
        mid = make_reader(f).get_summary().chunk_indexes[10]
    b = bytearray(recorded.read_bytes())
    b[mid.chunk_start_offset + mid.chunk_length // 2] ^= 0x01
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b)
    rc = main(["segment", str(bad), "-o", str(tmp_path / "obs.json")])
    err = capsys.readouterr().err
    assert rc == 0
    lines = [ln for ln in err.splitlines() if ln.startswith("accellog: warning:")]
    assert len(lines) == 1 and "damaged chunk at byte" in lines[0] and "IMU samples lost" in lines[0]
    assert "Traceback" not in err


def test_crc32_is_zlibs():
    """The reader's CRC-32 (ISA-L's when installed) gives zlib's values, also continued; a flip shows."""
    import zlib

    from accellog.store.collect import crc32

    rng = np.random.default_rng(3)
    for size in (0, 1, 15, 4096, 1 << 20):
        b = rng.integers(0, 256, size, dtype=np.uint8).tobytes()
        assert crc32(b) == zlib.crc32(b)
        assert crc32(b[size // 3 :], crc32(b[: size // 3])) == zlib.crc32(b)
    damaged = bytearray(b)
    damaged[12345] ^= 0x10
    assert crc32(damaged) != crc32(b)


def test_crc32_on_a_mapped_file(recorded):
    import mmap
    import zlib

    from accellog.store.collect import crc32

    with open(recorded, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as m:
        mv = memoryview(m)
        assert crc32(mv[100:-100], 7) == zlib.crc32(mv[100:-100], 7)
        mv.release()
