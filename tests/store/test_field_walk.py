"""store.mcap.field_walk: the sequence walk (same keys, lengths free: recorder batches of varying FIFO reads)
and the varint reader give what the message-by-message decoder gives."""

from __future__ import annotations

import numpy as np
import pytest

from accellog.store.codec import BatchDecoder, encode
from accellog.store.mcap import field_walk
from accellog.store.mcap.batch_decode import decode_batch


def _imu_batches(rng, n_messages: int, drop_host_at: int | None = None) -> list[bytes]:
    """ImuBatch messages of 30-42 samples (counts), as a recorder polling a FIFO writes them (a
    session's first batch, first_sample_index 0, lacks that key: these start later)."""
    msgs, first = [], 5000
    for i in range(n_messages):
        k = int(rng.integers(30, 43))
        host = 0 if i == drop_host_at else (1 << 33) + 36_000_000 * i  # 0: not written (proto3 default)
        msgs.append(
            encode(
                "ImuBatch",
                first_sample_index=first,
                t_ns=(first + np.arange(k)) * 1_000_000,
                accel_counts=rng.integers(-32768, 32768, 3 * k),
                gyro_counts=rng.integers(-32768, 32768, 3 * k),
                temp_counts=rng.integers(-3000, 3000, k),
                host_time_ns=host,
            )
        )
        first += k
    return msgs


def _decode(msgs: list[bytes], monkeypatch) -> tuple[object, list[bool]]:
    """decode_batch of msgs packed with junk between them, and what the sequence walk returned."""
    gap = b"\xaa" * 7
    buf = np.frombuffer(gap + gap.join(msgs) + gap, np.uint8)
    lens = np.array([len(m) for m in msgs])
    starts = len(gap) + np.concatenate([[0], np.cumsum(lens + len(gap))[:-1]])
    taken: list[bool] = []
    real = field_walk._sequence_walk
    monkeypatch.setattr(field_walk, "_sequence_walk", lambda *a: taken.append(real(*a)) or taken[-1])
    return decode_batch("ImuBatch", buf, starts, starts + lens), taken


def _assert_as_reference(got, msgs: list[bytes]) -> None:
    ref = BatchDecoder("ImuBatch")
    for m in msgs:
        ref.add(m)
    (a1, s1, c1), (a2, s2, c2) = got.result(), ref.result()
    assert list(a1) == list(a2) and list(s1) == list(s2)
    for k in a2:
        assert a1[k].dtype == a2[k].dtype and np.array_equal(a1[k], a2[k]), k
    for k in c2:
        assert np.array_equal(c1[k], c2[k]), k
    for k in s2:
        assert list(s1[k]) == list(s2[k]), k


def test_varying_batches_take_the_sequence_walk(monkeypatch):
    msgs = _imu_batches(np.random.default_rng(1), 500)
    assert len({len(m) for m in msgs}) > 10  # the uniform layout cannot hold
    got, taken = _decode(msgs, monkeypatch)
    assert taken == [True]
    _assert_as_reference(got, msgs)


@pytest.mark.parametrize("at", [0, 1, 250, 499])
def test_a_message_without_a_field_falls_back_to_the_general_walk(monkeypatch, at):
    """One message lacks host_time_ns: the sequence walk stops (the first message's keys differ, or
    a later one's do) and the general walk gives the reference result."""
    msgs = _imu_batches(np.random.default_rng(2), 500, drop_host_at=at)
    got, taken = _decode(msgs, monkeypatch)
    assert taken == [False]
    _assert_as_reference(got, msgs)


def _varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b, v = v & 0x7F, v >> 7
        out.append(b | (0x80 if v else 0))
        if not v:
            return bytes(out)


def test_varints_equal_python_and_refuse_overflow_and_overrun():
    rng = np.random.default_rng(3)
    values = [int(rng.integers(0, 2**63)) >> int(rng.integers(0, 63)) for _ in range(400)]
    values += [0, 1, 127, 128, 2**63 - 1, 2**64 - 1]
    for order in (values, sorted(values), [values[0]] * 50):  # mixed widths, runs, all one width
        parts = [_varint(v) for v in order]
        buf = np.frombuffer(b"".join(parts) + bytes(16), np.uint8)
        pos = np.concatenate([[0], np.cumsum([len(p) for p in parts])[:-1]]).astype(np.int64)
        end = pos + [len(p) for p in parts]
        got = field_walk._varints(buf, pos, end)
        assert got is not None and got[0].tolist() == order and np.array_equal(got[1], end)
        assert field_walk._varints(buf, pos, end - 1) is None  # each runs past its end
    too_big = np.frombuffer(b"\xff" * 9 + b"\x02" + bytes(8), np.uint8)  # 2**64 and more
    assert field_walk._varints(too_big, np.array([0]), np.array([10])) is None
