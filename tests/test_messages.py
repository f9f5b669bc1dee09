"""Protobuf schemas: .proto file vs runtime descriptors, numpy wire codec vs the stock protobuf runtime."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from google.protobuf import descriptor_pb2

from accellog import messages as pb

PROTO = Path(__file__).resolve().parents[1] / "schemas" / "accellog_v1.proto"

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
    assert PROTO.read_text() == pb.render_proto(), (
        "regenerate: python -m accellog.messages > schemas/accellog_v1.proto"
    )


def test_proto_file_agrees_with_runtime_descriptor_pool():
    parsed = _parse_proto_file(PROTO.read_text())
    assert set(parsed) == {m.name for m in pb.MESSAGES}
    for name, fields in parsed.items():
        desc = pb.stock_message_class(name).DESCRIPTOR
        assert desc.full_name == f"accellog.v1.{name}"
        got = [(f.name, _TYPE_NAMES[f.type], f.number, f.is_repeated) for f in desc.fields]
        assert sorted(got, key=lambda x: x[2]) == sorted(fields, key=lambda x: x[2])
        for f in desc.fields:  # proto3 repeated scalars are packed: that is what the codec writes
            if f.is_repeated:
                assert f.is_packed


def test_file_descriptor_set_parses():
    fds = descriptor_pb2.FileDescriptorSet.FromString(pb.file_descriptor_set_bytes())
    assert [f.package for f in fds.file] == ["accellog.v1"]
    assert {m.name for m in fds.file[0].message_type} == set(pb.MESSAGE_DEFS)


def _random_values(message: str, rng: np.random.Generator, n: int) -> dict:
    vals: dict = {}
    for f in pb.MESSAGE_DEFS[message].fields:
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


@pytest.mark.parametrize("message", [m.name for m in pb.MESSAGES])
def test_stock_runtime_parses_what_we_write_identically(message):
    rng = np.random.default_rng(7)
    cls = pb.stock_message_class(message)
    for trial in range(20):
        vals = _random_values(message, rng, n=int(rng.integers(1, 40)))
        data = pb.encode(message, **vals)
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
        back = pb.decode(message, msg.SerializeToString())
        for name, v in vals.items():
            if isinstance(v, np.ndarray):
                assert np.array_equal(back[name], v)
            else:
                assert back[name] == v


def test_negative_and_default_scalars():
    data = pb.encode("Event", t_ns=-5, kind="", detail="d", sample_index=-1, lost_samples=0)
    msg = pb.stock_message_class("Event").FromString(data)
    assert (msg.t_ns, msg.sample_index, msg.lost_samples, msg.kind) == (-5, -1, 0, "")
    assert pb.decode("Event", data) == {
        "t_ns": -5,
        "kind": "",
        "detail": "d",
        "sample_index": -1,
        "lost_samples": 0,
    }


def test_unknown_field_is_rejected_on_encode():
    with pytest.raises(TypeError, match="no field"):
        pb.encode("ImuBatch", accel=np.zeros(3))


def test_batch_decoder_concatenates_and_counts():
    rng = np.random.default_rng(1)
    msgs, ref_t, ref_a = [], [], []
    for i in range(50):
        k = int(rng.integers(1, 37))
        t = rng.integers(0, 10**12, k)
        a = rng.integers(-32768, 32768, (k, 3)).astype(np.int32)
        msgs.append(pb.encode("ImuBatch", first_sample_index=i * 100, t_ns=t, accel_counts=a, host_time_ns=i))
        ref_t.append(t)
        ref_a.append(a)
    dec = pb.BatchDecoder("ImuBatch")
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
