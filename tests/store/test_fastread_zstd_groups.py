"""The fast reader decompresses a group of small zstd chunks (recorder files) in one call (#11): the
same samples as chunk by chunk, and a damaged chunk still named on its own."""

from __future__ import annotations

import re
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from accellog.core.errors import DataIntegrityWarning
from accellog.flows.simulate import Scenario, simulate
from accellog.store.collect import crc32_holding_gil
from accellog.store.mcap import decompress as group_decompress
from accellog.store.mcap.index import read_footer
from accellog.store.reader import read_session

COLUMNS = ("t_s", "sample_index", "accel_counts", "gyro_counts", "temp_counts", "accel_g", "host_time_s")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """A session through the real recording path: 0.5 s zstd chunks (the recorder's defaults)."""
    p = tmp_path_factory.mktemp("rec") / "six.mcap"
    simulate(Scenario(protocol="six", hold_s=2.5, move_s=1.0, sample_rate_hz=200.0), p)
    return p


def _chunk_by_chunk_only(monkeypatch) -> None:
    monkeypatch.setattr(group_decompress.GroupDecompressor, "_zstd_group", lambda *a: None)


def test_groups_of_chunks_read_as_chunk_by_chunk(recorded, monkeypatch):
    with open(recorded, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) > 20 and {c.compression for c in chunks} == {"zstd"}
    calls = []
    by_chunk = group_decompress.GroupDecompressor._chunk_by_chunk
    monkeypatch.setattr(
        group_decompress.GroupDecompressor,
        "_chunk_by_chunk",
        lambda self, *a: calls.append(1) or by_chunk(self, *a),
    )
    grouped = read_session(recorded)
    assert not calls  # a sound file: every group in one call
    _chunk_by_chunk_only(monkeypatch)
    single = read_session(recorded)
    for name in COLUMNS:
        np.testing.assert_array_equal(getattr(grouped, name), getattr(single, name))
    assert grouped.events == single.events and grouped.poses == single.poses


def _flip(recorded: Path, tmp_path: Path, where) -> tuple[Path, int]:
    """A copy with one byte of the middle chunk changed at where(chunk index): (path, chunk offset)."""
    with open(recorded, "rb") as f:
        mid = make_reader(f).get_summary().chunk_indexes[10]
    b = bytearray(recorded.read_bytes())
    b[where(mid)] ^= 0x04
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b)
    return bad, mid.chunk_start_offset


@pytest.mark.parametrize(
    "where, why",
    [
        (lambda c: c.chunk_start_offset + c.chunk_length - 40, "decompress|CRC mismatch"),  # records
        (lambda c: c.chunk_start_offset + 9 + 8 + 8 + 8, "CRC mismatch"),  # its stored CRC
    ],
    ids=["records", "crc"],
)
def test_a_damaged_chunk_in_a_group_is_named_alone(recorded, tmp_path, monkeypatch, where, why):
    """One bad chunk: its group is read chunk by chunk, that chunk alone is left out and named at its
    byte offset; the samples read are those of the chunk-by-chunk reader."""
    bad, at = _flip(recorded, tmp_path, where)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DataIntegrityWarning)
        grouped = read_session(bad)
    assert any(f"damaged chunk at byte {at} " in str(w.message) for w in caught), [
        str(w.message) for w in caught
    ]
    (ev,) = [e for e in grouped.events if e.kind == "damaged"]
    assert ev.lost_samples > 0 and re.search(f"at byte {at} .*({why})", ev.detail), ev.detail
    _chunk_by_chunk_only(monkeypatch)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataIntegrityWarning)
        single = read_session(bad)
    for name in COLUMNS:
        np.testing.assert_array_equal(getattr(grouped, name), getattr(single, name))


@pytest.mark.parametrize("size", [0, 1, 4095, 4096, 4097, 20_000, 1 << 20])
def test_crc32_holding_gil_is_zlibs(size):
    b = np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8).tobytes()
    assert crc32_holding_gil(memoryview(b)) == zlib.crc32(b)
    assert crc32_holding_gil(memoryview(b)[size // 3 :], zlib.crc32(b[: size // 3])) == zlib.crc32(b)


def _count_crcs(monkeypatch) -> list[int]:
    calls: list[int] = []
    real = group_decompress.crc32_holding_gil
    monkeypatch.setattr(group_decompress, "crc32_holding_gil", lambda *a: calls.append(1) or real(*a))
    return calls


def test_a_whole_read_trusts_the_data_section_crc_a_stream_does_not(recorded, monkeypatch):
    """The data section CRC covers every chunk byte and is checked before read_session returns, so a
    whole read skips the chunks' own CRCs; a stream hands blocks out before that verdict: it checks
    every chunk. A file without a data section CRC: every chunk checked."""
    from accellog.store.stream import iter_imu

    calls = _count_crcs(monkeypatch)
    read_session(recorded)
    assert calls == []
    list(iter_imu(recorded))
    assert len(calls) > 20
    calls.clear()
    b = bytearray(recorded.read_bytes())
    at = read_footer(bytes(b))[1] - 13  # the DataEnd record: opcode 0x0F, length 4, CRC
    assert b[at] == 0x0F and int.from_bytes(b[at + 9 : at + 13], "little") != 0
    b[at + 9 : at + 13] = bytes(4)  # "no data section CRC stored"
    no_crc = recorded.parent / "no_data_crc.mcap"
    no_crc.write_bytes(b)
    s = read_session(no_crc)
    assert len(calls) > 20 and not [e for e in s.events if e.kind == "damaged"]
