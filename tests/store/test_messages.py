"""Protobuf schemas: .proto file vs runtime descriptors, numpy wire codec vs the stock protobuf runtime."""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import numpy as np
import pytest
from google.protobuf import descriptor_pb2

from accellog.store.codec import BatchDecoder, decode, encode
from accellog.store.mcap.batch_decode import BatchAccumulator, decode_batch, gather_bytes
from accellog.store.schema import (
    MESSAGE_DEFS,
    MESSAGES,
    file_descriptor_set_bytes,
    render_proto,
    stock_message_class,
)

PROTO = Path(__file__).resolve().parents[2] / "schemas" / "accellog_v1.proto"

_TYPE_NAMES = {
    v: k[5:].lower() for k, v in descriptor_pb2.FieldDescriptorProto.Type.items() if k.startswith("TYPE_")
}


def _parse_proto_file(text: str) -> dict[str, list[tuple[str, str, int, bool]]]:
    """Independent minimal .proto parser: message -> [(field, type, number, repeated)]."""
    text = re.sub(r"//[^\n]*", "", text)
    assert re.search(r'syntax\s*=\s*"proto3"\s*;', text)
    assert re.search(r"package\s+accellog\.v1\s*;", text)
    out = {}
    for name, body in re.findall(r"message\s+(\w+)\s*\{([^}]*)\}", text):
        fields = re.findall(r"(repeated\s+)?(\w+)\s+(\w+)\s*=\s*(\d+)\s*;", body)
        out[name] = [(f, t, int(num), bool(rep)) for rep, t, f, num in fields]
    return out


def test_proto_file_is_rendered_from_descriptions():
    assert PROTO.read_text() == render_proto(), (
        "regenerate: python -m accellog.store.schema > schemas/accellog_v1.proto"
    )


def test_proto_file_agrees_with_runtime_descriptor_pool():
    parsed = _parse_proto_file(PROTO.read_text())
    assert set(parsed) == {m.name for m in MESSAGES}
    for name, fields in parsed.items():
        desc = stock_message_class(name).DESCRIPTOR
        assert desc.full_name == f"accellog.v1.{name}"
        got = [(f.name, _TYPE_NAMES[f.type], f.number, f.is_repeated) for f in desc.fields]
        assert sorted(got, key=lambda x: x[2]) == sorted(fields, key=lambda x: x[2])
        for f in desc.fields:  # proto3 repeated scalars are packed: that is what the codec writes
            if f.is_repeated:
                assert f.is_packed


def test_file_descriptor_set_parses():
    fds = descriptor_pb2.FileDescriptorSet.FromString(file_descriptor_set_bytes())
    assert [f.package for f in fds.file] == ["accellog.v1"]
    assert {m.name for m in fds.file[0].message_type} == set(MESSAGE_DEFS)


def _random_values(message: str, rng: np.random.Generator, n: int) -> dict:
    vals: dict = {}
    for f in MESSAGE_DEFS[message].fields:
        if f.repeated:
            k = int(rng.integers(0, 3)) * n  # some fields empty
            if f.type == "sfixed64":
                vals[f.name] = rng.integers(-(2**62), 2**62, k, dtype=np.int64)
            elif f.type == "sfixed32":
                vals[f.name] = rng.integers(-(2**31), 2**31 - 1, k, dtype=np.int64).astype(np.int32)
            else:
                vals[f.name] = rng.normal(0, 1e3, k)
        elif f.type == "uint64":
            vals[f.name] = int(rng.integers(0, 2**63))
        elif f.type == "uint32":
            vals[f.name] = int(rng.integers(0, 2**31))
        elif f.type in ("int64", "int32"):
            vals[f.name] = int(rng.integers(-(2**31), 2**31))
        elif f.type == "double":
            vals[f.name] = float(rng.normal())
        elif f.type == "string":
            vals[f.name] = "héllo +z" if rng.random() < 0.7 else ""
        elif f.type == "bytes":
            vals[f.name] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
    return vals


@pytest.mark.parametrize("message", [m.name for m in MESSAGES])
def test_stock_runtime_parses_what_we_write_identically(message):
    rng = np.random.default_rng(7)
    cls = stock_message_class(message)
    for trial in range(20):
        vals = _random_values(message, rng, n=int(rng.integers(1, 40)))
        data = encode(message, **vals)
        msg = cls.FromString(data)
        for name, v in vals.items():
            got = getattr(msg, name)
            if isinstance(v, np.ndarray):
                assert np.array_equal(np.asarray(list(got), dtype=v.dtype), v), (trial, name)
            else:
                assert got == v, (trial, name)
        # byte-identical to the runtime's own serialization (proto3 defaults omitted, packed arrays)
        assert msg.SerializeToString() == data
        # and our decoder reads the runtime's bytes back
        back = decode(message, msg.SerializeToString())
        for name, v in vals.items():
            if isinstance(v, np.ndarray):
                assert np.array_equal(back[name], v)
            else:
                assert back[name] == v


def test_negative_and_default_scalars():
    data = encode("Event", t_ns=-5, kind="", detail="d", sample_index=-1, lost_samples=0)
    msg = stock_message_class("Event").FromString(data)
    assert (msg.t_ns, msg.sample_index, msg.lost_samples, msg.kind) == (-5, -1, 0, "")
    assert decode("Event", data) == {
        "t_ns": -5,
        "kind": "",
        "detail": "d",
        "sample_index": -1,
        "lost_samples": 0,
    }


def test_unknown_field_is_rejected_on_encode():
    with pytest.raises(TypeError, match="no field"):
        encode("ImuBatch", accel=np.zeros(3))


def test_batch_decoder_concatenates_and_counts():
    rng = np.random.default_rng(1)
    msgs, ref_t, ref_a = [], [], []
    for i in range(50):
        k = int(rng.integers(1, 37))
        t = rng.integers(0, 10**12, k)
        a = rng.integers(-32768, 32768, (k, 3)).astype(np.int32)
        msgs.append(encode("ImuBatch", first_sample_index=i * 100, t_ns=t, accel_counts=a, host_time_ns=i))
        ref_t.append(t)
        ref_a.append(a)
    dec = BatchDecoder("ImuBatch")
    for m in msgs:
        dec.add(m)
    arrays, scalars, counts = dec.result()
    assert np.array_equal(arrays["t_ns"], np.concatenate(ref_t))
    assert np.array_equal(arrays["accel_counts"].reshape(-1, 3), np.concatenate(ref_a))
    assert arrays["accel_counts"].flags.writeable
    assert scalars["first_sample_index"] == [i * 100 for i in range(50)]
    assert scalars["host_time_ns"] == list(range(50))
    assert np.array_equal(counts["t_ns"], [len(t) for t in ref_t])
    assert arrays["gyro_counts"].size == 0


# --- vectorised decoding (decode_batch / BatchAccumulator), checked against BatchDecoder --------------


def _reference(message: str, msgs: list[bytes]):
    dec = BatchDecoder(message)
    for m in msgs:
        dec.add(m)
    return dec.result()


def _assert_results_equal(got, ref) -> None:
    (a1, s1, c1), (a2, s2, c2) = got, ref
    assert list(a1) == list(a2) and list(s1) == list(s2) and list(c1) == list(c2)
    for k in a2:
        assert a1[k].dtype == a2[k].dtype and a1[k].flags.writeable, k
        assert np.array_equal(a1[k], a2[k], equal_nan=True) and a1[k].tobytes() == a2[k].tobytes(), k
    for k in c2:
        assert c1[k].dtype == c2[k].dtype and np.array_equal(c1[k], c2[k]), k
    for k in s2:  # same Python values and types (floats compared bit for bit)
        assert [_bits(v) for v in s1[k]] == [_bits(v) for v in s2[k]], k


def _bits(v):
    return (float, np.float64(v).tobytes()) if isinstance(v, float) else (type(v), v)


def _pack(msgs: list[bytes], gap: bytes = b"\xaa" * 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Messages in one buffer with junk between them (as payloads sit between MCAP record headers)."""
    buf = gap + gap.join(msgs) + gap
    lens = np.array([len(m) for m in msgs], dtype=np.int64)
    starts = len(gap) + np.concatenate([[0], np.cumsum(lens + len(gap))[:-1]]).astype(np.int64)
    return np.frombuffer(buf, np.uint8), starts, starts + lens


@pytest.mark.parametrize("message", [m.name for m in MESSAGES])
@pytest.mark.parametrize("sizes", ["equal", "few", "many"])
def test_decode_batch_equals_batch_decoder(message, sizes):
    rng = np.random.default_rng(sum(map(ord, message + sizes)))
    msgs = []
    for i in range(300):
        n = {"equal": 36, "few": int(rng.choice([1, 35, 36, 37])), "many": int(rng.integers(1, 200))}[sizes]
        vals = _random_values(message, rng, n)
        if sizes == "equal":  # every repeated field present: all messages of one length per field
            vals = {
                k: (np.resize(v, n * (4 if "q_" in k else 3)) if isinstance(v, np.ndarray) else v)
                for k, v in vals.items()
            }
        if i % 7 == 0:  # scalars at their defaults are not written
            vals.update({k: type(v)() for k, v in vals.items() if not isinstance(v, np.ndarray)})
        msgs.append(encode(message, **vals))
    buf, starts, ends = _pack(msgs)
    got = decode_batch(message, buf, starts, ends)
    assert got is not None and got.n_messages == len(msgs)
    _assert_results_equal(got.result(), _reference(message, msgs))


@pytest.mark.parametrize("message", [m.name for m in MESSAGES])
@pytest.mark.parametrize("spacing", ["even", "uneven"])
def test_decode_batch_uniform_layout(message, spacing, monkeypatch):
    """Messages of one layout (same fields, lengths and varint sizes; values vary) take the uniform
    walk, read as one strided view when evenly spaced and gathered by offset otherwise: same result."""
    import accellog.store.mcap.field_walk as fw

    rng = np.random.default_rng(sum(map(ord, message + spacing)))
    fields = MESSAGE_DEFS[message].fields
    msgs = []
    for i in range(200):
        vals = _random_values(message, rng, 36)
        for f in fields:
            if f.repeated:
                vals[f.name] = np.resize(vals[f.name], 36 * 3) if vals[f.name].size else vals[f.name][:0] + 1
            elif f.type in ("uint64", "uint32", "int64", "int32"):
                vals[f.name] = (1 << 28) + i  # 5-byte varints throughout
            elif f.type in ("string", "bytes"):
                vals[f.name] = type(vals[f.name])()
        msgs.append(vals)
    for f in fields:  # one layout: a repeated field is present in every message or in none
        if f.repeated:
            for v in msgs[1:]:
                v[f.name] = v[f.name][:0] if msgs[0][f.name].size == 0 else np.resize(v[f.name], 108) + 1
    msgs = [encode(message, **v) for v in msgs]
    assert len({len(m) for m in msgs}) == 1
    if spacing == "even":
        buf, starts, ends = _pack(msgs)
    else:
        gaps = [bytes(int(g)) for g in rng.integers(1, 9, len(msgs) + 1)]
        raw = b"".join(g + m for g, m in zip(gaps, msgs, strict=False)) + gaps[-1]
        lens = np.array([len(g) + len(m) for g, m in zip(gaps, msgs, strict=False)])
        ends = np.cumsum(lens)
        starts = ends - len(msgs[0])
        buf = np.frombuffer(raw, np.uint8)
    taken = []
    real = fw._uniform_layout
    monkeypatch.setattr(fw, "_uniform_layout", lambda *a: taken.append(real(*a)) or taken[-1])
    got = decode_batch(message, buf, starts, ends)
    assert got is not None and taken == [True]
    _assert_results_equal(got.result(), _reference(message, msgs))


def test_decode_batch_scalars_extremes():
    msgs = [
        encode("Event", t_ns=-(2**63), kind="é" * 200, sample_index=-1, lost_samples=2**63 - 1),
        encode("Event"),
        encode("Event", t_ns=127, detail="x" * 128, sample_index=128, lost_samples=16384),
    ]
    msgs.append(encode("ImuBatch", first_sample_index=2**64 - 1, host_time_ns=-5, t_ns=[1]))
    buf, starts, ends = _pack(msgs[:3])
    _assert_results_equal(decode_batch("Event", buf, starts, ends).result(), _reference("Event", msgs[:3]))
    buf, starts, ends = _pack(msgs[3:])
    _assert_results_equal(
        decode_batch("ImuBatch", buf, starts, ends).result(), _reference("ImuBatch", msgs[3:])
    )
    got = decode_batch("ImuBatch", buf, starts, ends).result()[1]
    assert got["first_sample_index"] == [2**64 - 1] and got["host_time_ns"] == [-5]
    empty = decode_batch("ImuBatch", buf, starts[:0], ends[:0])
    _assert_results_equal(empty.result(), _reference("ImuBatch", []))


def _key(number: int, wire: int) -> bytes:
    return bytes([(number << 3) | wire])


@pytest.mark.parametrize(
    "bad",
    [
        encode("ImuBatch", t_ns=[5]) + encode("ImuBatch", first_sample_index=3),  # field order 2, 1
        encode("ImuBatch", t_ns=[5]) + encode("ImuBatch", t_ns=[6]),  # repeated field
        encode("ImuBatch", t_ns=[5]) + _key(15, 0) + b"\x01",  # unknown field
        _key(1, 2) + b"\x00",  # wrong wire type for a varint field
        _key(2, 2) + b"\x04" + b"\0" * 4,  # packed sfixed64 of 4 bytes
        _key(2, 2) + b"\x10" + b"\0" * 8,  # length past the end of the message
        _key(1, 0) + b"\xff" * 10 + b"\x01",  # varint longer than 64 bits
        _key(1, 0) + b"\xff\xff",  # varint cut by the end of the message
        _key(6, 5) + b"\0" * 4,  # fixed32 wire type
        bytes([0x80 | 8, 0x01]) + b"\x05",  # two-byte key (non-minimal encoding of field 1)
    ],
)
def test_decode_batch_refuses_non_canonical(bad):
    good = encode("ImuBatch", first_sample_index=7, t_ns=[1, 2], accel_counts=np.ones(6, np.int32))
    buf, starts, ends = _pack([good, bad, good])
    assert decode_batch("ImuBatch", buf, starts, ends) is None
    buf, starts, ends = _pack([good, good])
    assert decode_batch("ImuBatch", buf, starts, ends) is not None


def test_decode_batch_refuses_bad_utf8():
    bad = _key(2, 2) + b"\x02\xc3\x28"
    buf, starts, ends = _pack([encode("Event", kind="ok"), bad])
    assert decode_batch("Event", buf, starts, ends) is None


def test_gather_bytes_paths():
    rng = np.random.default_rng(3)
    buf = rng.integers(0, 256, 100_000, dtype=np.uint8)
    for lengths in (
        np.full(50, 12),  # one length: whole rows
        rng.choice([0, 12, 24, 432], 500),  # few lengths (and empty pieces)
        rng.integers(0, 400, 500) * 4,  # more lengths than groups: 4-byte items
    ):
        offsets = rng.integers(0, 100_000 - 2000, lengths.shape[0])
        got = gather_bytes(buf, offsets, lengths, 4)
        ref = np.concatenate([buf[o : o + n] for o, n in zip(offsets, lengths, strict=True)])
        assert np.array_equal(got, ref)
    assert gather_bytes(buf, offsets[:0], lengths[:0]).shape == (0,)


@pytest.mark.parametrize("done_scale", [1.0, 0.25, 4.0])  # exact, too small (grows), too large (trims)
def test_batch_accumulator_joins_parts(done_scale):
    rng = np.random.default_rng(5)
    msgs = [
        encode("ImuBatch", **_random_values("ImuBatch", rng, int(rng.integers(1, 40)))) for _ in range(200)
    ]
    acc = BatchAccumulator("ImuBatch")
    cuts = [0, 1, 50, 51, 120, 200]
    for a, b in itertools.pairwise(cuts):
        buf, starts, ends = _pack(msgs[a:b])
        acc.add(decode_batch("ImuBatch", buf, starts, ends), min(1.0, b / 200 * done_scale))
    _assert_results_equal(acc.finish().result(), _reference("ImuBatch", msgs))
