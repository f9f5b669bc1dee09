"""Protobuf schema of accellog MCAP files (package ``accellog.v1``), described in Python.

``MESSAGES`` is the description; ``schemas/accellog_v1.proto`` is it rendered as .proto text (a test checks
they agree) and the binary FileDescriptorSet stored in every MCAP schema record is built from it at
runtime with ``google.protobuf.descriptor_pb2``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

PACKAGE = "accellog.v1"
SCHEMA_VERSION = "accellog.v1"
PROTO_FILE_NAME = "accellog_v1.proto"

# field type -> (wire type, numpy dtype for packed arrays or None)
SCALAR_TYPES = {
    "uint64": (0, None),
    "int64": (0, None),
    "uint32": (0, None),
    "int32": (0, None),
    "double": (1, None),
    "string": (2, None),
    "bytes": (2, None),
}
PACKED_TYPES: dict[str, np.dtype] = {
    "sfixed64": np.dtype("<i8"),
    "sfixed32": np.dtype("<i4"),
    "double": np.dtype("<f8"),
}


@dataclass(frozen=True)
class Field:
    """One protobuf field: ``repeated`` fields are packed numeric arrays (sfixed64, sfixed32, double)."""

    name: str
    number: int
    type: str
    repeated: bool = False
    doc: str = ""


@dataclass(frozen=True)
class MessageDef:
    name: str
    doc: str
    fields: tuple[Field, ...]


MESSAGES: tuple[MessageDef, ...] = (
    MessageDef(
        "ImuBatch",
        "One FIFO read of the accelerometer/gyro/temperature stream (topic /imu). Sample k of the batch "
        "has device sample index first_sample_index + k. Raw counts are lossless; the conversions "
        "(accel_lsb_per_g, gyro_lsb_per_dps) are in the MCAP metadata record 'session'. Sources "
        "without counts fill the value fields instead.",
        (
            Field("first_sample_index", 1, "uint64", doc="device sample index of the first sample"),
            Field("t_ns", 2, "sfixed64", True, "sensor time of each sample, ns since session start"),
            Field("accel_counts", 3, "sfixed32", True, "accelerometer counts, interleaved x,y,z"),
            Field("gyro_counts", 4, "sfixed32", True, "gyro counts, interleaved x,y,z"),
            Field("temp_counts", 5, "sfixed32", True, "TEMP_OUT counts (degC = counts/333.87 + 21)"),
            Field(
                "host_time_ns", 6, "int64", doc="host clock when the batch was read, ns since session start"
            ),
            Field("accel_g", 7, "double", True, "acceleration in g, interleaved x,y,z (no counts)"),
            Field("gyro_dps", 8, "double", True, "angular rate in deg/s, interleaved x,y,z (no counts)"),
            Field("temp_degC", 9, "double", True, "die temperature in degC (no counts)"),
        ),
    ),
    MessageDef(
        "MagBatch",
        "Magnetometer (AK8963) samples (topic /mag): uT = counts * asa_factor * ut_per_lsb.",
        (
            Field("first_sample_index", 1, "uint64", doc="index of the first magnetometer sample"),
            Field("t_ns", 2, "sfixed64", True, "sensor time of each sample, ns since session start"),
            Field("mag_counts", 3, "sfixed32", True, "raw HX,HY,HZ counts, interleaved x,y,z"),
            Field("st2", 4, "bytes", doc="ST2 status byte of each sample (bit 3 HOFL overflow, bit 4 BITM)"),
            Field("asa_factor", 5, "double", True, "sensitivity adjustment (ASA-128)/256+1 per axis (3)"),
            Field("ut_per_lsb", 6, "double", doc="uT per LSB (0.15 at 16 bit, 0.6 at 14 bit)"),
            Field("mag_uT", 7, "double", True, "field in uT after ASA, interleaved x,y,z (no counts)"),
            Field(
                "host_time_ns", 8, "int64", doc="host clock when the batch was read, ns since session start"
            ),
        ),
    ),
    MessageDef(
        "PoseLabel",
        "A labelled static hold (topic /poses): the sensor reads +1 g along up_sensor at rest.",
        (
            Field("name", 1, "string", doc="pose name, e.g. '+z' or '+z@90'"),
            Field("start_ns", 2, "int64", doc="start of the hold, ns since session start"),
            Field("end_ns", 3, "int64", doc="end of the hold (exclusive), ns since session start"),
            Field("up_sensor", 4, "double", True, "unit up vector in the sensor frame (x,y,z)"),
            Field("q_sensor_to_world", 5, "double", True, "nominal orientation (w,x,y,z); empty if unknown"),
            Field("hold_index", 6, "uint32", doc="index of the hold in the protocol"),
        ),
    ),
    MessageDef(
        "Event",
        "Something that happened while recording (topic /events): gaps, overflows, notes, prompts.",
        (
            Field("t_ns", 1, "int64", doc="sensor time, ns since session start"),
            Field("kind", 2, "string", doc="gap, fifo_overflow, misaligned, i2c_error, retry, note, ..."),
            Field("detail", 3, "string", doc="human-readable detail"),
            Field("sample_index", 4, "int64", doc="device sample index concerned (-1: none)"),
            Field("lost_samples", 5, "int64", doc="samples lost by this event"),
        ),
    ),
    MessageDef(
        "TruthBatch",
        "Ground truth of a simulated session (topic /truth); vectors interleaved per sample.",
        (
            Field("t_ns", 1, "sfixed64", True, "time, ns since session start"),
            Field("specific_force_g", 2, "double", True, "perfect accelerometer reading, sensor frame (g)"),
            Field("omega_dps", 3, "double", True, "angular rate, sensor frame (deg/s)"),
            Field("position_m", 4, "double", True, "position, world frame z up (m)"),
            Field("velocity_mps", 5, "double", True, "velocity, world frame (m/s)"),
            Field("q_sensor_to_world", 6, "double", True, "orientation quaternion (w,x,y,z)"),
            Field("temp_degC", 7, "double", True, "die temperature (degC)"),
        ),
    ),
    MessageDef(
        "Vector3Batch",
        "A derived 3-vector channel (topics /derived/...), e.g. calibrated acceleration.",
        (
            Field("t_ns", 1, "sfixed64", True, "time, ns since session start"),
            Field("values", 2, "double", True, "values, interleaved x,y,z"),
            Field("unit", 3, "string", doc="unit of values, e.g. 'g', 'm/s^2', 'deg/s'"),
            Field("frame", 4, "string", doc="frame of values, e.g. 'sensor', 'world'"),
        ),
    ),
)

MESSAGE_DEFS: dict[str, MessageDef] = {m.name: m for m in MESSAGES}


def full_name(message: str) -> str:
    """Fully qualified protobuf name, e.g. 'accellog.v1.ImuBatch' (the MCAP schema name)."""
    return f"{PACKAGE}.{message}"


# ---------------------------------------------------------------------------------------------
# descriptors and .proto text


@cache
def file_descriptor_proto():
    """``google.protobuf.descriptor_pb2.FileDescriptorProto`` of all messages (proto3)."""
    from google.protobuf import descriptor_pb2 as d

    types = {
        "uint64": d.FieldDescriptorProto.TYPE_UINT64,
        "int64": d.FieldDescriptorProto.TYPE_INT64,
        "uint32": d.FieldDescriptorProto.TYPE_UINT32,
        "int32": d.FieldDescriptorProto.TYPE_INT32,
        "double": d.FieldDescriptorProto.TYPE_DOUBLE,
        "string": d.FieldDescriptorProto.TYPE_STRING,
        "bytes": d.FieldDescriptorProto.TYPE_BYTES,
        "sfixed64": d.FieldDescriptorProto.TYPE_SFIXED64,
        "sfixed32": d.FieldDescriptorProto.TYPE_SFIXED32,
    }
    fdp = d.FileDescriptorProto(name=PROTO_FILE_NAME, package=PACKAGE, syntax="proto3")
    for m in MESSAGES:
        mp = fdp.message_type.add(name=m.name)
        for f in m.fields:
            mp.field.add(
                name=f.name,
                number=f.number,
                type=types[f.type],
                label=d.FieldDescriptorProto.LABEL_REPEATED
                if f.repeated
                else d.FieldDescriptorProto.LABEL_OPTIONAL,
                json_name=_json_name(f.name),
            )
    return fdp


def _json_name(name: str) -> str:
    parts = name.split("_")
    return parts[0] + "".join(p[:1].upper() + p[1:] for p in parts[1:])


@cache
def file_descriptor_set_bytes() -> bytes:
    """Serialized FileDescriptorSet: the MCAP schema data for every accellog.v1 message."""
    from google.protobuf import descriptor_pb2 as d

    return d.FileDescriptorSet(file=[file_descriptor_proto()]).SerializeToString()


def _wrap(text: str, indent: str, width: int = 100) -> list[str]:
    import textwrap

    return [indent + "// " + line for line in textwrap.wrap(text, width - len(indent) - 3)]


def render_proto() -> str:
    """The .proto text of ``MESSAGES`` (the content of schemas/accellog_v1.proto)."""
    out = [
        "// accellog MCAP message schemas, protobuf package accellog.v1.",
        "// Generated from accellog/store/schema.py (python -m accellog.store.schema > schemas/accellog_v1.proto);",
        "// tests/store/test_messages.py checks that this file and the runtime descriptors agree.",
        "// Times are int64 ns since the session start; vectors are interleaved per sample (x,y,z).",
        'syntax = "proto3";',
        "",
        f"package {PACKAGE};",
    ]
    for m in MESSAGES:
        out.append("")
        out += _wrap(m.doc, "")
        out.append(f"message {m.name} {{")
        for f in m.fields:
            if f.doc:
                out += _wrap(f.doc, "  ")
            rep = "repeated " if f.repeated else ""
            out.append(f"  {rep}{f.type} {f.name} = {f.number};")
        out.append("}")
    return "\n".join(out) + "\n"


@cache
def stock_message_class(message: str):
    """The stock protobuf runtime's class for ``message`` (built from the same descriptors)."""
    from google.protobuf import descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    pool.Add(file_descriptor_proto())
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(full_name(message)))


if __name__ == "__main__":  # pragma: no cover
    print(render_proto(), end="")
