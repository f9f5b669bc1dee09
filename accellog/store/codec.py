"""Protobuf wire format of single messages, encoded and decoded with numpy (no protobuf runtime).

Repeated numeric fields are *packed* (tag, byte length, raw little-endian array), so ``encode`` writes
``ndarray.tobytes()`` straight into the message and ``decode`` / ``BatchDecoder`` read them back with
``np.frombuffer``. Scalars equal to their proto3 default (0, "", empty) are omitted, exactly as the stock
runtime does, so ``SerializeToString()`` of the same message gives the same bytes (tests check this; it
is what makes the files open in Foxglove).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from accellog.store.schema import MESSAGE_DEFS, PACKED_TYPES, SCALAR_TYPES

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
class FieldCodec:
    name: str
    tag: bytes
    kind: str  # 'packed', 'varint_u', 'varint_s', 'double', 'string', 'bytes'
    dtype: np.dtype | None

    @property
    def packed_dtype(self) -> np.dtype:
        """The element dtype of a packed field (the other kinds have none)."""
        if self.dtype is None:
            raise TypeError(f"field {self.name!r} is {self.kind}, not packed")
        return self.dtype


@cache
def codecs_of(message: str) -> tuple[tuple[FieldCodec, ...], dict[int, FieldCodec]]:
    m = MESSAGE_DEFS[message]
    codecs = []
    for f in m.fields:
        if f.repeated:
            kind, wire, dtype = "packed", 2, PACKED_TYPES[f.type]
        else:
            wire = SCALAR_TYPES[f.type][0]
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
        codecs.append(FieldCodec(f.name, _varint((f.number << 3) | wire), kind, dtype))
    by_number = {f.number: c for f, c in zip(m.fields, codecs, strict=True)}
    return tuple(codecs), by_number


DOUBLE = np.dtype("<f8")


def encode(message: str, **values) -> bytes:
    """Wire bytes of ``message`` with the given field values (arrays for repeated fields).

    Repeated fields accept any array-like (flattened, cast to the field's little-endian dtype);
    omitted fields and proto3 defaults are not written.
    """
    codecs, _ = codecs_of(message)
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
            b = DOUBLE.type(v).tobytes()
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
    _, by_number = codecs_of(message)
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


def _scalar(c: FieldCodec, data: bytes, v):
    if c.kind == "varint_u":
        return v
    if c.kind == "varint_s":
        return v - (1 << 64) if v >= 1 << 63 else v
    off, ln = v
    if c.kind == "double":
        return float(np.frombuffer(data, DOUBLE, 1, off)[0])
    raw = data[off : off + ln]
    return raw.decode("utf-8") if c.kind == "string" else bytes(raw)


def decode(message: str, data: bytes) -> dict:
    """Field values of one message: numpy arrays for repeated fields, Python scalars otherwise.

    Absent fields get their proto3 default (0, 0.0, '', b'', empty array).
    """
    codecs, _ = codecs_of(message)
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
        self.codecs, by_number = codecs_of(message)
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
        got: list = []  # (name, packed bytes) kept only if the whole message parses
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
                        got.append((f[1], mv[pos : pos + ln]))
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
        for name, part in got:  # a message that fails above leaves nothing behind (salvage goes on)
            packed[name].append(part)
            owner[name].append(k)
        self._rows.append(row)
        self.n_messages += 1

    def result(self) -> tuple[dict[str, np.ndarray], dict[str, list], dict[str, np.ndarray]]:
        """(arrays, scalars, counts): concatenated packed fields, per-message scalars, per-message sizes."""
        arrays, counts = {}, {}
        for c in self.codecs:
            if c.kind != "packed":
                continue
            parts = self._packed[c.name]
            arrays[c.name] = np.frombuffer(bytearray().join(parts), c.packed_dtype)  # writable
            sizes = np.fromiter((len(p) for p in parts), np.int64, len(parts)) // c.packed_dtype.itemsize
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
