"""Protobuf wire format of accellog MCAP files (package ``accellog.v1``), encoded and decoded with numpy.

The schemas are described here in Python (``MESSAGES``); ``schemas/accellog_v1.proto`` is the same
description rendered as .proto text (a test checks they agree) and the binary FileDescriptorSet stored
in every MCAP schema record is built from it at runtime with ``google.protobuf.descriptor_pb2``.

Encoding never touches the protobuf runtime: repeated numeric fields are *packed* (tag, byte length,
raw little-endian array), so ``encode`` writes ``ndarray.tobytes()`` straight into the message and
``decode`` / ``BatchDecoder`` read them back with ``np.frombuffer``. Scalars equal to their proto3
default (0, "", empty) are omitted, exactly as the stock runtime does, so ``SerializeToString()`` of the
same message gives the same bytes (tests check this; it is what makes the files open in Foxglove).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np

PACKAGE = "accellog.v1"
SCHEMA_VERSION = "accellog.v1"
PROTO_FILE_NAME = "accellog_v1.proto"

# field type -> (wire type, numpy dtype for packed arrays or None)
_SCALAR_TYPES = {
    "uint64": (0, None),
    "int64": (0, None),
    "uint32": (0, None),
    "int32": (0, None),
    "double": (1, None),
    "string": (2, None),
    "bytes": (2, None),
}
_PACKED_TYPES = {"sfixed64": np.dtype("<i8"), "sfixed32": np.dtype("<i4"), "double": np.dtype("<f8")}


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
        "// Generated from accellog/messages.py (python -m accellog.store.messages > schemas/accellog_v1.proto);",
        "// tests/test_messages.py checks that this file and the runtime descriptors agree.",
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


# ---------------------------------------------------------------------------------------------
# wire format


def _varint(v: int) -> bytes:
    if v < 0:
        v += 1 << 64
    out = bytearray()
    while v >= 0x80:
        out.append((v & 0x7F) | 0x80)
        v >>= 7
    out.append(v)
    return bytes(out)


def _read_varint(buf: bytes, pos: int) -> tuple[int, int]:
    b = buf[pos]
    if b < 0x80:
        return b, pos + 1
    result = b & 0x7F
    shift = 7
    pos += 1
    while True:
        b = buf[pos]
        result |= (b & 0x7F) << shift
        pos += 1
        if b < 0x80:
            return result, pos
        shift += 7


@dataclass(frozen=True)
class _FieldCodec:
    name: str
    tag: bytes
    kind: str  # 'packed', 'varint_u', 'varint_s', 'double', 'string', 'bytes'
    dtype: np.dtype | None


@cache
def _codecs(message: str) -> tuple[tuple[_FieldCodec, ...], dict[int, _FieldCodec]]:
    m = MESSAGE_DEFS[message]
    codecs = []
    for f in m.fields:
        if f.repeated:
            kind, wire, dtype = "packed", 2, _PACKED_TYPES[f.type]
        else:
            wire = _SCALAR_TYPES[f.type][0]
            kind = {
                "uint64": "varint_u",
                "uint32": "varint_u",
                "int64": "varint_s",
                "int32": "varint_s",
                "double": "double",
                "string": "string",
                "bytes": "bytes",
            }[f.type]
            dtype = None
        codecs.append(_FieldCodec(f.name, _varint((f.number << 3) | wire), kind, dtype))
    by_number = {f.number: c for f, c in zip(m.fields, codecs, strict=True)}
    return tuple(codecs), by_number


_DOUBLE = np.dtype("<f8")


def encode(message: str, **values) -> bytes:
    """Wire bytes of ``message`` with the given field values (arrays for repeated fields).

    Repeated fields accept any array-like (flattened, cast to the field's little-endian dtype);
    omitted fields and proto3 defaults are not written.
    """
    codecs, _ = _codecs(message)
    parts: list[bytes] = []
    for c in codecs:
        v = values.pop(c.name, None)
        if v is None:
            continue
        if c.kind == "packed":
            arr = np.ascontiguousarray(v, dtype=c.dtype).reshape(-1)
            if arr.size:
                parts += (c.tag, _varint(arr.nbytes), arr.tobytes())
        elif c.kind in ("varint_u", "varint_s"):
            iv = int(v)
            if iv:
                parts += (c.tag, _varint(iv))
        elif c.kind == "double":
            b = _DOUBLE.type(v).tobytes()
            if b != b"\0" * 8:
                parts += (c.tag, b)
        else:
            b = v.encode("utf-8") if c.kind == "string" else bytes(v)
            if b:
                parts += (c.tag, _varint(len(b)), b)
    if values:
        raise TypeError(f"{message} has no field(s) {sorted(values)}")
    return b"".join(parts)


def _scan(message: str, data: bytes):
    """Yield (codec, value) for each field of the wire bytes; packed values are (offset, length)."""
    _, by_number = _codecs(message)
    pos, end = 0, len(data)
    while pos < end:
        key, pos = _read_varint(data, pos)
        number, wire = key >> 3, key & 7
        c = by_number.get(number)
        if wire == 2:
            ln, pos = _read_varint(data, pos)
            if c is not None:
                yield c, (pos, ln)
            pos += ln
        elif wire == 0:
            v, pos = _read_varint(data, pos)
            if c is not None:
                yield c, v
        elif wire == 1:
            if c is not None:
                yield c, (pos, 8)
            pos += 8
        elif wire == 5:
            if c is not None:
                yield c, (pos, 4)
            pos += 4
        else:
            raise ValueError(f"{message}: unsupported wire type {wire} at byte {pos}")
    if pos != end:
        raise ValueError(f"{message}: truncated message")


def _scalar(c: _FieldCodec, data: bytes, v):
    if c.kind == "varint_u":
        return v
    if c.kind == "varint_s":
        return v - (1 << 64) if v >= 1 << 63 else v
    off, ln = v
    if c.kind == "double":
        return float(np.frombuffer(data, _DOUBLE, 1, off)[0])
    raw = data[off : off + ln]
    return raw.decode("utf-8") if c.kind == "string" else bytes(raw)


def decode(message: str, data: bytes) -> dict:
    """Field values of one message: numpy arrays for repeated fields, Python scalars otherwise.

    Absent fields get their proto3 default (0, 0.0, '', b'', empty array).
    """
    codecs, _ = _codecs(message)
    out: dict = {}
    packed: dict[str, list[bytes]] = {}
    for c, v in _scan(message, data):
        if c.kind == "packed":
            off, ln = v if isinstance(v, tuple) else (None, None)
            if off is None:  # unpacked varint element: not produced for our packed types
                raise ValueError(f"{message}.{c.name}: unexpected varint for a packed field")
            packed.setdefault(c.name, []).append(data[off : off + ln])
        else:
            out[c.name] = _scalar(c, data, v)
    for c in codecs:
        if c.kind == "packed":
            out[c.name] = np.frombuffer(b"".join(packed.get(c.name, ())), c.dtype)
        elif c.name not in out:
            out[c.name] = {"string": "", "bytes": b"", "double": 0.0}.get(c.kind, 0)
    return out


class BatchDecoder:
    """Decode many messages of one type and concatenate each field once (fast read-back).

    ``add(data)`` records byte slices of packed fields and scalar values (one tight loop per
    message, no per-sample work); ``result()`` returns, per field, one concatenated array (packed
    fields), a list of per-message values (scalars), and ``counts[field]``: elements contributed by
    each message (packed fields).
    """

    def __init__(self, message: str) -> None:
        self.message = message
        self.codecs, by_number = _codecs(message)
        # field number -> (is_packed, name, codec)
        self._fields = {num: (c.kind == "packed", c.name, c) for num, c in by_number.items()}
        self._packed: dict[str, list] = {c.name: [] for c in self.codecs if c.kind == "packed"}
        self._owner: dict[str, list[int]] = {c.name: [] for c in self.codecs if c.kind == "packed"}
        self._rows: list[dict] = []
        self.n_messages = 0

    def add(self, data: bytes) -> None:
        fields, packed, owner = self._fields, self._packed, self._owner
        k = self.n_messages
        row: dict = {}
        mv = memoryview(data)
        pos, end = 0, len(data)
        while pos < end:
            key = data[pos]
            if key < 0x80:
                pos += 1
            else:
                key, pos = _read_varint(data, pos)
            wire = key & 7
            f = fields.get(key >> 3)
            if wire == 2:
                ln = data[pos]
                if ln < 0x80:
                    pos += 1
                else:
                    ln, pos = _read_varint(data, pos)
                if f is not None:
                    if f[0]:
                        packed[f[1]].append(mv[pos : pos + ln])
                        owner[f[1]].append(k)
                    else:
                        row[f[1]] = _scalar(f[2], data, (pos, ln))
                pos += ln
            elif wire == 0:
                v, pos = _read_varint(data, pos)
                if f is not None:
                    row[f[1]] = _scalar(f[2], data, v)
            elif wire == 1:
                if f is not None:
                    row[f[1]] = _scalar(f[2], data, (pos, 8))
                pos += 8
            elif wire == 5:
                pos += 4
            else:
                raise ValueError(f"{self.message}: unsupported wire type {wire} at byte {pos}")
        if pos != end:
            raise ValueError(f"{self.message}: truncated message")
        self._rows.append(row)
        self.n_messages += 1

    def result(self) -> tuple[dict[str, np.ndarray], dict[str, list], dict[str, np.ndarray]]:
        """(arrays, scalars, counts): concatenated packed fields, per-message scalars, per-message sizes."""
        arrays, counts = {}, {}
        for c in self.codecs:
            if c.kind != "packed":
                continue
            parts = self._packed[c.name]
            arrays[c.name] = np.frombuffer(bytearray().join(parts), c.dtype)  # writable
            sizes = np.fromiter((len(p) for p in parts), np.int64, len(parts)) // c.dtype.itemsize
            counts[c.name] = np.bincount(
                np.asarray(self._owner[c.name], dtype=np.int64), weights=sizes, minlength=self.n_messages
            ).astype(np.int64)
        defaults = {"string": "", "bytes": b"", "double": 0.0}
        scalars = {
            c.name: [r.get(c.name, defaults.get(c.kind, 0)) for r in self._rows]
            for c in self.codecs
            if c.kind != "packed"
        }
        return arrays, scalars, counts


# ---------------------------------------------------------------------------------------------
# vectorised decoding of many messages at once (fast MCAP read-back)


def byte_window(buf: np.ndarray, width: int) -> np.ndarray:
    """Overlapping (len(buf) - width + 1, width) uint8 view of ``buf``: row i is buf[i : i + width].

    Fancy-indexing its rows with byte offsets gathers ``width``-byte records at arbitrary (unaligned)
    offsets in one C loop, without copying ``buf``.
    """
    return np.lib.stride_tricks.as_strided(buf, shape=(buf.shape[0] - width + 1, width), strides=(1, 1))


def read_le(buf: np.ndarray, offsets: np.ndarray, dtype: str | np.dtype) -> np.ndarray:
    """Little-endian values of ``dtype`` (e.g. '<u8') stored at the byte ``offsets`` of uint8 ``buf``."""
    dt = np.dtype(dtype)
    if offsets.shape[0] == 0:
        return np.empty(0, dt)
    return byte_window(buf, dt.itemsize)[offsets].view(dt)[:, 0]


_MAX_LENGTH_GROUPS = 64  # gather_bytes: message-sized copies per distinct length up to this many lengths


def gather_bytes(
    buf: np.ndarray, offsets: np.ndarray, lengths: np.ndarray, unit: int = 1, out: np.ndarray | None = None
) -> np.ndarray:
    """Concatenation of buf[offsets[k] : offsets[k] + lengths[k]] over k (uint8 array).

    Written into ``out`` (contiguous uint8, lengths.sum() bytes) if given, else into a new array.
    Messages of equal length are copied as whole rows (one fancy-indexing pass per distinct length);
    with more than a few distinct lengths, ``unit``-byte items (every length a multiple of unit) are
    gathered instead.
    """
    total = int(lengths.sum())
    if out is None:
        out = np.empty(total, np.uint8)
    elif out.shape != (total,):
        raise ValueError(f"gather_bytes: out has {out.shape} bytes, expected {total}")
    if total == 0:
        return out
    keep = lengths > 0
    if not keep.all():
        offsets, lengths = offsets[keep], lengths[keep]
    if np.all(lengths == lengths[0]):
        size = int(lengths[0])
        step = int(offsets[1] - offsets[0]) if offsets.shape[0] > 1 else size
        if step >= size and np.all(np.diff(offsets) == step):  # evenly spaced: one strided copy
            rows = np.lib.stride_tricks.as_strided(
                buf[int(offsets[0]) :], shape=(offsets.shape[0], size), strides=(step, 1)
            )
            out.reshape(-1, size)[...] = rows
        else:
            out.reshape(-1, size)[...] = byte_window(buf, size)[offsets]
        return out
    sizes = np.unique(lengths)
    out_start = np.cumsum(lengths) - lengths
    if sizes.shape[0] <= _MAX_LENGTH_GROUPS:
        for size in sizes.tolist():
            k = np.flatnonzero(lengths == size)
            byte_window(out, size)[out_start[k]] = byte_window(buf, size)[offsets[k]]
        return out
    items = np.repeat(offsets - out_start, lengths // unit) + np.arange(0, total, unit)
    out.reshape(-1, unit)[...] = byte_window(buf, unit)[items]
    return out


@dataclass
class DecodedBatch:
    """Decoded fields of many messages of one type; ``result()`` is that of ``BatchDecoder``."""

    message: str
    n_messages: int
    arrays: dict[str, np.ndarray]
    scalars: dict[str, list]
    counts: dict[str, np.ndarray]
    placed: frozenset[str] = frozenset()  # arrays already written in place by BatchAccumulator.reserve

    def result(self) -> tuple[dict[str, np.ndarray], dict[str, list], dict[str, np.ndarray]]:
        """(arrays, scalars, counts), as ``BatchDecoder.result()`` (new dicts; the arrays are shared)."""
        return dict(self.arrays), dict(self.scalars), dict(self.counts)


class BatchAccumulator:
    """Joins DecodedBatch parts of one message type as they come, into arrays sized once.

    ``add(part, done)``: ``done`` (0..1] is the fraction of the input read so far; the first part sizes
    each array for the whole input (its size / done, plus 2 %), so a steady stream costs one
    allocation per field and no concatenation pass (arrays grow in place if the guess was short).
    ``finish()`` trims them in place and returns the DecodedBatch of all parts, in order.
    """

    def __init__(self, message: str) -> None:
        self.message = message
        self.n_messages = 0
        self._store: dict[str, np.ndarray] = {}
        self._used: dict[str, int] = {}
        self._dtypes: dict[str, np.dtype] = {}
        self._scalars: dict[str, list] = {}
        self._counts: dict[str, list[np.ndarray]] = {}

    def reserve(self, name: str, dtype: np.dtype, count: int, done: float) -> np.ndarray:
        """The next ``count`` items of array ``name``, to be filled in place (then ``add`` the part
        with ``name`` in ``placed``): the decoder writes straight into the final array, no copy.

        The view is valid until the next ``reserve``/``add`` (the array may be reallocated)."""
        self._dtypes.setdefault(name, np.dtype(dtype))
        used = self._used.get(name, 0)
        need = used + count
        store = self._store.get(name)
        if store is None or need > store.shape[0]:
            cap = max(need, int(need / max(done, 1e-6) * 1.02) + 64)
            if store is None:
                store = self._store[name] = np.empty(cap, dtype)
            else:
                store.resize(cap, refcheck=False)  # realloc: views handed out before are dead
        self._used[name] = need
        return store[used:need]

    def add(self, part: DecodedBatch, done: float) -> None:
        for name, a in part.arrays.items():
            self._dtypes.setdefault(name, a.dtype)
            if name in part.placed or a.shape[0] == 0:
                continue
            self.reserve(name, a.dtype, a.shape[0], done)[:] = a
        for name, v in part.scalars.items():
            self._scalars.setdefault(name, []).extend(v)
        for name, c in part.counts.items():
            self._counts.setdefault(name, []).append(c)
        self.n_messages += part.n_messages

    def finish(self) -> DecodedBatch:
        arrays = {}
        for name, dtype in self._dtypes.items():
            store = self._store.pop(name, None)
            if store is None:
                store = np.empty(0, dtype)
            elif store.shape[0] != self._used[name]:
                store.resize(self._used[name], refcheck=False)
            arrays[name] = store
        counts = {name: np.concatenate(c) for name, c in self._counts.items()}
        return DecodedBatch(self.message, self.n_messages, arrays, self._scalars, counts)


_WIRE = {"packed": 2, "string": 2, "bytes": 2, "varint_u": 0, "varint_s": 0, "double": 1}


def _varints(buf: np.ndarray, pos: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Vectorised base-128 varints at byte offsets ``pos``: (values uint64, offsets after them).

    Byte k of all varints still running is read in one numpy pass (so a few passes in all). None if
    one runs past ``end`` (its message's end) or does not fit in 64 bits.
    """
    top = buf.shape[0] - 1
    b = buf[np.minimum(pos, top)]
    val = b.astype(np.uint64)
    run = np.flatnonzero(b >= 0x80)
    after = pos + 1
    if run.shape[0]:
        val[run] &= np.uint64(0x7F)
        shift = 7
        while run.shape[0]:
            if shift > 63:
                return None
            b = buf[np.minimum(after[run], top)]
            if shift == 63 and np.any(b > 1):
                return None
            val[run] |= (b & 0x7F).astype(np.uint64) << np.uint64(shift)
            after[run] += 1
            run = run[b >= 0x80]
            shift += 7
    if np.any(after > end):
        return None
    return val, after


def _uniform_layout(
    buf: np.ndarray,
    pos: np.ndarray,
    end: np.ndarray,
    key_to_field: np.ndarray,
    numbers: np.ndarray,
    field_codecs: list[_FieldCodec],
    offs: dict[str, np.ndarray],
    lens: dict[str, np.ndarray],
    vals: dict[str, np.ndarray],
) -> bool:
    """``decode_batch``'s field walk when every message has the layout of the first one (the usual case).

    The first message is walked in Python under the canonical rules; then every message is checked to
    have the same length, the same key and length bytes at the same places, and varints of the same byte
    count (continuation bits) there, with a few vectorised column reads. Fills offs/lens/vals as the
    general walk would and returns True; False (nothing filled) if any of this does not hold.
    """
    n = pos.shape[0]
    if n < 2:
        return False
    size = int(end[0] - pos[0])
    if size <= 0 or np.any(end - pos != size):
        return False
    t = bytes(buf[int(pos[0]) : int(pos[0]) + size])
    fixed: list[int] = []  # offsets of bytes every message must share (keys, lengths)
    varint_at: list[tuple[str, int, int]] = []  # (field, offset, bytes)
    double_at: list[tuple[str, int]] = []
    span_at: list[tuple[str, int, int]] = []  # (field, data offset, length)
    p, last = 0, 0
    while p < size:
        f = int(key_to_field[t[p]])
        if f < 0 or int(numbers[f]) <= last:
            return False
        last = int(numbers[f])
        c = field_codecs[f]
        fixed.append(p)
        p += 1
        if c.kind == "double":
            if p + 8 > size:
                return False
            double_at.append((c.name, p))
            p += 8
            continue
        q = p
        while q < size and t[q] >= 0x80:
            q += 1
        if q >= size or q - p >= 9:  # runs past the message, or over 63 bits: the general walk decides
            return False
        if c.name in offs:
            if c.kind != "packed":  # strings need a UTF-8 check per message
                return False
            ln = sum((t[p + j] & 0x7F) << (7 * j) for j in range(q + 1 - p))
            fixed += range(p, q + 1)
            p = q + 1
            if p + ln > size:
                return False
            span_at.append((c.name, p, ln))
            p += ln
        else:
            varint_at.append((c.name, p, q + 1 - p))
            p = q + 1
    rel = np.asarray(fixed, dtype=np.int64)
    if np.any(buf[pos[:, None] + rel] != np.frombuffer(t, np.uint8)[rel]):
        return False
    columns = {}
    for name, o, k in varint_at:
        cols = buf[pos[:, None] + np.arange(o, o + k)]
        if np.any(cols[:, :-1] < 0x80) or np.any(cols[:, -1] >= 0x80):
            return False
        columns[name] = cols
    for name, cols in columns.items():
        v = np.zeros(n, np.uint64)
        for j in range(cols.shape[1]):
            v |= (cols[:, j] & 0x7F).astype(np.uint64) << np.uint64(7 * j)
        vals[name][:] = v
    for name, o in double_at:
        vals[name][:] = read_le(buf, pos + o, "<u8")
    for name, o, ln in span_at:
        offs[name][:] = pos + o
        lens[name][:] = ln
    return True


def decode_batch(
    message: str,
    buf: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    reserve: Callable[[str, np.dtype, int], np.ndarray] | None = None,
) -> DecodedBatch | None:
    """Decode the messages buf[starts[k] : ends[k]] (uint8 array) all at once, field by field with numpy.

    ``reserve(name, dtype, count)`` (e.g. ``BatchAccumulator.reserve`` with ``done`` bound), if given,
    provides the destination of each packed field: the payloads are gathered straight into it and the
    field is listed in ``placed`` of the result (if None is returned, what was reserved is garbage).

    Accepts the canonical encoding (what ``encode`` and the stock runtime write): one-byte keys with the
    schema's wire type, field numbers strictly increasing within a message (no repeats, no unknown
    fields), varints of at most 64 bits, packed lengths a multiple of the item size, UTF-8 strings.
    Anything else returns None: use ``BatchDecoder`` then. When it returns, the result equals that of
    ``BatchDecoder`` fed the same messages in order, exactly.
    """
    codecs, by_number = _codecs(message)
    n = int(starts.shape[0])
    pos = np.asarray(starts, dtype=np.int64).copy()
    end = np.asarray(ends, dtype=np.int64)
    if n and (np.any(end < pos) or int(end.max()) > buf.shape[0]):
        return None
    key_to_field = np.full(256, -1, np.int64)
    numbers = np.zeros(len(codecs), np.int64)
    for i, (num, c) in enumerate(by_number.items()):
        key_to_field[(num << 3) | _WIRE[c.kind]] = i
        numbers[i] = num
    field_codecs = list(by_number.values())
    offs = {c.name: np.zeros(n, np.int64) for c in codecs if c.kind in ("packed", "string", "bytes")}
    lens = {name: np.zeros(n, np.int64) for name in offs}
    vals = {c.name: np.zeros(n, np.uint64) for c in codecs if c.kind not in offs}
    last = np.zeros(n, np.int64)  # field number read last in each message
    uniform = _uniform_layout(buf, pos, end, key_to_field, numbers, field_codecs, offs, lens, vals)
    active = pos[:0] if uniform else np.flatnonzero(pos < end)
    while active.shape[0]:
        p = pos[active]
        field = key_to_field[buf[p]]
        if np.any(field < 0):
            return None  # unknown field, wrong wire type or multi-byte key
        num = numbers[field]
        if np.any(num <= last[active]):
            return None  # out of order or repeated
        last[active] = num
        present = np.flatnonzero(np.bincount(field, minlength=len(field_codecs)))
        for f in present.tolist():
            c = field_codecs[f]
            if present.shape[0] == 1:
                idx, q = active, p + 1
            else:
                sel = field == f
                idx, q = active[sel], p[sel] + 1
            e = end[idx]
            if c.kind == "double":
                after = q + 8
                if np.any(after > e):
                    return None
                vals[c.name][idx] = read_le(buf, q, "<u8")
            else:
                got = _varints(buf, q, e)
                if got is None:
                    return None
                v, after = got
                if c.name in offs:
                    ln = v.astype(np.int64)
                    if np.any((v > np.uint64(1 << 62)) | (after + ln > e)):
                        return None
                    offs[c.name][idx], lens[c.name][idx] = after, ln
                    after = after + ln
                else:
                    vals[c.name][idx] = v
            pos[idx] = after
        active = active[pos[active] < end[active]]

    arrays, scalars, counts = {}, {}, {}
    placed: list[str] = []
    for c in codecs:
        if c.kind == "packed":
            size = c.dtype.itemsize
            ln = lens[c.name]
            if np.any(ln % size):
                return None
            if reserve is None:
                arrays[c.name] = gather_bytes(buf, offs[c.name], ln, size).view(c.dtype)
            else:
                dst = reserve(c.name, c.dtype, int(ln.sum()) // size)
                gather_bytes(buf, offs[c.name], ln, size, out=dst.view(np.uint8))
                arrays[c.name] = dst
                placed.append(c.name)
            counts[c.name] = ln // size
        elif c.kind in ("string", "bytes"):
            ln = lens[c.name]
            raw = gather_bytes(buf, offs[c.name], ln).tobytes()
            bounds = np.cumsum(ln).tolist()
            items = [raw[a:b] for a, b in zip([0, *bounds[:-1]], bounds, strict=True)]
            if c.kind == "string":
                try:
                    items = [b.decode("utf-8") for b in items]
                except UnicodeDecodeError:
                    return None
            scalars[c.name] = items
        elif c.kind == "varint_s":
            scalars[c.name] = vals[c.name].view(np.int64).tolist()
        elif c.kind == "double":
            scalars[c.name] = vals[c.name].view(_DOUBLE).tolist()
        else:
            scalars[c.name] = vals[c.name].tolist()
    return DecodedBatch(message, n, arrays, scalars, counts, frozenset(placed))


if __name__ == "__main__":  # pragma: no cover
    print(render_proto(), end="")
