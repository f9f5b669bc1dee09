"""Where every field of many protobuf messages is, found at once with numpy (``decode_batch``'s walk).

``walk_fields`` tries, in order: ``_uniform_layout`` (every message laid out as the first: a few column
checks), ``_sequence_walk`` (every message with the first one's keys in its order, lengths free: one
field of all messages per step), ``_general_walk`` (any layout: one field of every unfinished message
per step). Each fills
offsets/lengths of the length-delimited fields and the values of the others, or returns False at the
first break of the canonical rules (the caller then decodes message by message).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from accellog.store.codec import FieldCodec
from accellog.store.mcap.byte_views import read_le

WIRE = {"packed": 2, "string": 2, "bytes": 2, "varint_u": 0, "varint_s": 0, "double": 1}


class Walk(NamedTuple):
    """The messages buf[pos[k] : end[k]] of one type (key byte -> field index, field numbers, codecs)
    and what a walk fills: offs/lens of the length-delimited fields, vals of the others (zeros:
    absent)."""

    buf: np.ndarray
    pos: np.ndarray
    end: np.ndarray
    key_to_field: np.ndarray
    numbers: np.ndarray
    field_codecs: list[FieldCodec]
    offs: dict[str, np.ndarray]
    lens: dict[str, np.ndarray]
    vals: dict[str, np.ndarray]


def _varints(buf: np.ndarray, pos: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Vectorised base-128 varints at byte offsets ``pos``: (values uint64, offsets after them).

    Byte k of all varints still running is read in one numpy pass (so a few passes in all). None if
    one runs past ``end`` (its message's end) or does not fit in 64 bits.
    """
    top = buf.shape[0] - 1
    val = np.zeros(pos.shape[0], np.uint64)
    after = pos.copy()
    run = None  # the varints still running; None: all of them (slices, no index arrays)
    shift = 0
    while True:
        if shift > 63:
            return None
        b = buf[np.minimum(after if run is None else after[run], top)]
        if shift == 63 and np.any(b > 1):
            return None
        bits = (b & 0x7F).astype(np.uint64) << np.uint64(shift)
        more = b >= 0x80
        if run is None:
            val |= bits
            after += 1
        else:
            val[run] |= bits
            after[run] += 1
        if not more.any():
            break
        if run is not None:
            run = run[more]
        elif not more.all():
            run = np.flatnonzero(more)
        shift += 7
    if np.any(after > end):
        return None
    return val, after


def _first_layout(
    t: bytes, key_to_field: np.ndarray, numbers: np.ndarray, field_codecs: list[FieldCodec], offs
):
    """The first message's layout under the canonical rules, for ``_uniform_layout``: (offsets of the
    key and length bytes, varints (field, offset, bytes), doubles (field, offset), packed spans (field,
    data offset, length)); None if it breaks a rule the vectorised check relies on."""
    size = len(t)
    fixed: list[int] = []  # offsets of bytes every message must share (keys, lengths)
    varint_at: list[tuple[str, int, int]] = []  # (field, offset, bytes)
    double_at: list[tuple[str, int]] = []
    span_at: list[tuple[str, int, int]] = []  # (field, data offset, length)
    p, last = 0, 0
    while p < size:
        f = int(key_to_field[t[p]])
        if f < 0 or int(numbers[f]) <= last:
            return None
        last = int(numbers[f])
        c = field_codecs[f]
        fixed.append(p)
        p += 1
        if c.kind == "double":
            if p + 8 > size:
                return None
            double_at.append((c.name, p))
            p += 8
            continue
        q = p
        while q < size and t[q] >= 0x80:
            q += 1
        if q >= size or q - p >= 9:  # runs past the message, or over 63 bits: the general walk decides
            return None
        if c.name in offs:
            if c.kind != "packed":  # strings need a UTF-8 check per message
                return None
            ln = sum((t[p + j] & 0x7F) << (7 * j) for j in range(q + 1 - p))
            fixed += range(p, q + 1)
            p = q + 1
            if p + ln > size:
                return None
            span_at.append((c.name, p, ln))
            p += ln
        else:
            varint_at.append((c.name, p, q + 1 - p))
            p = q + 1
    return fixed, varint_at, double_at, span_at


def _rows(buf: np.ndarray, pos: np.ndarray, size: int) -> Callable[[np.ndarray | slice], np.ndarray]:
    """cols -> (n, ...) uint8 array of the bytes at columns ``cols`` of every message buf[pos[k]:][:size].

    Evenly spaced messages (the usual case: equal records back to back) are one strided (n, size) view,
    read by column without an index array per byte; others are gathered by offset."""
    step = int(pos[1] - pos[0]) if pos.shape[0] > 1 else size
    if step >= size and np.all(np.diff(pos) == step):
        view = np.lib.stride_tricks.as_strided(
            buf[int(pos[0]) :], shape=(pos.shape[0], size), strides=(step, 1)
        )
        return lambda cols: view[:, cols]
    offsets = pos[:, None]
    return lambda cols: buf[offsets + (np.arange(cols.start, cols.stop) if isinstance(cols, slice) else cols)]


def _uniform_layout(w: Walk) -> bool:
    """``decode_batch``'s field walk when every message has the layout of the first one (the usual case).

    The first message is walked in Python under the canonical rules; then every message is checked to
    have the same length, the same key and length bytes at the same places, and varints of the same byte
    count (continuation bits) there, with a few vectorised column reads. Fills offs/lens/vals as the
    general walk would and returns True; False (nothing filled) if any of this does not hold.
    """
    buf, pos, end, key_to_field, numbers, field_codecs, offs, lens, vals = w
    n = pos.shape[0]
    if n < 2:
        return False
    size = int(end[0] - pos[0])
    if size <= 0 or np.any(end - pos != size):
        return False
    t = bytes(buf[int(pos[0]) : int(pos[0]) + size])
    layout = _first_layout(t, key_to_field, numbers, field_codecs, offs)
    if layout is None:
        return False
    fixed, varint_at, double_at, span_at = layout
    rel = np.asarray(fixed, dtype=np.int64)
    rows = _rows(buf, pos, size)
    if np.any(rows(rel) != np.frombuffer(t, np.uint8)[rel]):
        return False
    columns = {}
    for name, o, k in varint_at:
        cols = rows(slice(o, o + k))
        if np.any(cols[:, :-1] < 0x80) or np.any(cols[:, -1] >= 0x80):
            return False
        columns[name] = cols
    for name, cols in columns.items():
        v = np.zeros(n, np.uint64)
        for j in range(cols.shape[1]):
            v |= (cols[:, j] & 0x7F).astype(np.uint64) << np.uint64(7 * j)
        vals[name][:] = v
    for name, o in double_at:
        vals[name][:] = np.ascontiguousarray(rows(slice(o, o + 8))).view("<u8")[:, 0]
    for name, o, ln in span_at:
        offs[name][:] = pos + o
        lens[name][:] = ln
    return True


def walk_fields(w: Walk) -> bool:
    """Fill w's offs/lens (length-delimited fields) and vals (the others); False if a message breaks
    the canonical rules (see module doc). w.pos is consumed."""
    return _uniform_layout(w) or _sequence_walk(w) or _general_walk(w)


def _key_sequence(t: bytes, key_to_field: np.ndarray, numbers: np.ndarray, field_codecs: list[FieldCodec]):
    """The keys of message t with their field index, [(key byte, field)], read in Python under the
    canonical rules; None if t breaks one (the general walk then says where)."""
    keys, p, last = [], 0, 0
    while p < len(t):
        f = int(key_to_field[t[p]])
        if f < 0 or int(numbers[f]) <= last:
            return None
        last, kind = int(numbers[f]), field_codecs[f].kind
        keys.append((t[p], f))
        p += 1
        if kind == "double":
            p += 8
            continue
        v, shift = 0, 0
        while p < len(t) and t[p] >= 0x80:
            v, shift, p = v | (t[p] & 0x7F) << shift, shift + 7, p + 1
        if p >= len(t):
            return None
        v, p = v | t[p] << shift, p + 1
        if kind in ("packed", "string", "bytes"):
            p += v
    return keys if p == len(t) else None


def _sequence_walk(w: Walk) -> bool:
    """``walk_fields`` when every message has the first one's keys in its order, whatever the lengths
    (recorder batches of varying FIFO reads): one field of all messages per step, its key checked at
    once, each message ending after its last. False if any message differs; what was filled by then
    is what the general walk fills (a field is filled only once every message holds it there)."""
    buf, pos, end, key_to_field, numbers, field_codecs, offs, lens, vals = w
    if pos.shape[0] < 2:
        return False
    keys = _key_sequence(bytes(buf[int(pos[0]) : int(end[0])]), key_to_field, numbers, field_codecs)
    p = pos
    for key, f in keys or ():
        c = field_codecs[f]
        if np.any(p >= end) or np.any(buf[p] != key):
            break
        if c.kind == "double":
            after = p + 9
            if np.any(after > end):
                break
            vals[c.name][:] = read_le(buf, p + 1, "<u8")
            p = after
            continue
        got = _varints(buf, p + 1, end)
        if got is None:
            break
        v, after = got
        if c.name in offs:
            ln = v.astype(np.int64)
            if np.any((v > np.uint64(1 << 62)) | (after + ln > end)):
                break
            offs[c.name][:], lens[c.name][:] = after, ln
            p = after + ln
        else:
            vals[c.name][:] = v
            p = after
    else:
        return bool(keys) and np.array_equal(p, end)
    return False


def _general_walk(w: Walk) -> bool:
    """``decode_batch``'s field walk for any layouts: one field of every unfinished message per step
    (grouped by field), filling offs/lens/vals; False at the first break of the canonical rules."""
    buf, pos, end, key_to_field, numbers, field_codecs, offs, lens, vals = w
    last = np.zeros(pos.shape[0], np.int64)  # field number read last in each message
    active = np.flatnonzero(pos < end)
    while active.shape[0]:
        p = pos[active]
        field = key_to_field[buf[p]]
        if np.any(field < 0):
            return False  # unknown field, wrong wire type or multi-byte key
        num = numbers[field]
        if np.any(num <= last[active]):
            return False  # out of order or repeated
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
                    return False
                vals[c.name][idx] = read_le(buf, q, "<u8")
            else:
                got = _varints(buf, q, e)
                if got is None:
                    return False
                v, after = got
                if c.name in offs:
                    ln = v.astype(np.int64)
                    if np.any((v > np.uint64(1 << 62)) | (after + ln > e)):
                        return False
                    offs[c.name][idx], lens[c.name][idx] = after, ln
                    after = after + ln
                else:
                    vals[c.name][idx] = v
            pos[idx] = after
        active = active[pos[active] < end[active]]
    return True
