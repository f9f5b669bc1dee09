"""Vectorised decoding of many messages at once (the fast MCAP read-back).

Payloads of one channel are gathered into one uint8 buffer; field offsets are found for all messages at
once (``_uniform_layout``: checked guesses for runs of equal-layout messages) and packed arrays are read
with strided views straight into preallocated accumulators.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from accellog.store.codec import DOUBLE, FieldCodec, codecs_of


def byte_window(buf: np.ndarray, width: int) -> np.ndarray:
    """Overlapping (len(buf) - width + 1, width) uint8 view of ``buf``: row i is buf[i : i + width].

    Fancy-indexing its rows with byte offsets gathers ``width``-byte records at arbitrary (unaligned)
    offsets in one C loop, without copying ``buf``.
    """
    return np.lib.stride_tricks.as_strided(buf, shape=(buf.shape[0] - width + 1, width), strides=(1, 1))


def void_window(buf: np.ndarray, width: int) -> np.ndarray:
    """``byte_window`` as ``width``-byte void items: fancy-indexing it copies each record with one
    memcpy (byte_window rows are copied byte by byte: ~1.7x slower for message-sized records)."""
    return np.ndarray((buf.shape[0] - width + 1,), np.dtype(f"V{width}"), buf, 0, (1,))


def read_le(buf: np.ndarray, offsets: np.ndarray, dtype: str | np.dtype) -> np.ndarray:
    """Little-endian values of ``dtype`` (e.g. '<u8') stored at the byte ``offsets`` of uint8 ``buf``."""
    dt = np.dtype(dtype)
    if offsets.shape[0] == 0:
        return np.empty(0, dt)
    return byte_window(buf, dt.itemsize)[offsets].view(dt)[:, 0]


_MAX_LENGTH_GROUPS = 64  # gather_bytes: message-sized copies per distinct length up to this many lengths


def length_classes(counts: np.ndarray) -> tuple[np.ndarray, list[int]] | None:
    """Messages grouped by ``counts`` (e.g. items per message) once, for ``gather_bytes`` of every
    field: (message order, stable by count; class bounds in it). None if there are too many classes."""
    order = np.argsort(counts, kind="stable")
    s = counts[order]
    cut = np.flatnonzero(s[1:] != s[:-1]) + 1
    if cut.shape[0] >= _MAX_LENGTH_GROUPS:
        return None
    return order, [0, *cut.tolist(), int(s.shape[0])]


def gather_bytes(
    buf: np.ndarray,
    offsets: np.ndarray,
    lengths: np.ndarray,
    unit: int = 1,
    out: np.ndarray | None = None,
    classes: tuple[np.ndarray, list[int]] | None = None,
) -> np.ndarray:
    """Concatenation of buf[offsets[k] : offsets[k] + lengths[k]] over k (uint8 array).

    Written into ``out`` (contiguous uint8, lengths.sum() bytes) if given, else into a new array.
    Messages of equal length are copied as whole records (one fancy-indexing pass per distinct
    length; ``classes``: ``length_classes`` of something proportional to the lengths, shared by
    fields); with more than a few distinct lengths, ``unit``-byte items (every length a multiple of
    unit) are gathered instead.
    """
    total = int(lengths.sum())
    if out is None:
        out = np.empty(total, np.uint8)
    elif out.shape != (total,):
        raise ValueError(f"gather_bytes: out has {out.shape} bytes, expected {total}")
    if total == 0:
        return out
    if classes is not None and len(classes[1]) > 2:
        out_start = np.cumsum(lengths) - lengths
        order, bounds = classes
        dst, src, ln = out_start[order], offsets[order], lengths[order]
        for a, b in itertools.pairwise(bounds):
            size = int(ln[a])
            if size:
                void_window(out, size)[dst[a:b]] = void_window(buf, size)[src[a:b]]
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
            np.ndarray(offsets.shape, np.dtype(f"V{size}"), out)[...] = void_window(buf, size)[offsets]
        return out
    sizes = np.unique(lengths)
    out_start = np.cumsum(lengths) - lengths
    if sizes.shape[0] <= _MAX_LENGTH_GROUPS:
        for size in sizes.tolist():
            k = np.flatnonzero(lengths == size)
            void_window(out, size)[out_start[k]] = void_window(buf, size)[offsets[k]]
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
    derived: dict[str, np.ndarray] | None = None  # columns converted while reading (imu_arrays)

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

    scalar_arrays = False  # decode_batch gives this accumulator numeric scalars as arrays (not lists)

    def add(self, part: DecodedBatch, done: float) -> None:
        for name, a in part.arrays.items():
            self._dtypes.setdefault(name, a.dtype)
            if name in part.placed or a.shape[0] == 0:
                continue
            self.reserve(name, a.dtype, a.shape[0], done)[:] = a
        self._add_scalars(part)
        for name, c in part.counts.items():
            self._counts.setdefault(name, []).append(c)
        self.n_messages += part.n_messages

    def _add_scalars(self, part: DecodedBatch) -> None:
        for name, v in part.scalars.items():
            self._scalars.setdefault(name, []).extend(v)

    def close(self) -> None:
        """Stop any worker thread of a subclass (after an error; ``finish`` does it otherwise)."""

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


def _uniform_layout(
    buf: np.ndarray,
    pos: np.ndarray,
    end: np.ndarray,
    key_to_field: np.ndarray,
    numbers: np.ndarray,
    field_codecs: list[FieldCodec],
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


def decode_batch(
    message: str,
    buf: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    reserve: Callable[[str, np.dtype, int], np.ndarray] | None = None,
    scalar_arrays: bool = False,
) -> DecodedBatch | None:
    """Decode the messages buf[starts[k] : ends[k]] (uint8 array) all at once, field by field with numpy.

    ``reserve(name, dtype, count)`` (e.g. ``BatchAccumulator.reserve`` with ``done`` bound), if given,
    provides the destination of each packed field: the payloads are gathered straight into it and the
    field is listed in ``placed`` of the result (if None is returned, what was reserved is garbage).
    scalar_arrays: numeric scalars as arrays (uint64, int64, float64) instead of lists.

    Accepts the canonical encoding (what ``encode`` and the stock runtime write): one-byte keys with the
    schema's wire type, field numbers strictly increasing within a message (no repeats, no unknown
    fields), varints of at most 64 bits, packed lengths a multiple of the item size, UTF-8 strings.
    Anything else returns None: use ``BatchDecoder`` then. When it returns, the result equals that of
    ``BatchDecoder`` fed the same messages in order, exactly.
    """
    codecs, by_number = codecs_of(message)
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
    walk = (buf, pos, end, key_to_field, numbers, field_codecs, offs, lens, vals)
    if not (_uniform_layout(*walk) or _general_walk(*walk)):
        return None
    return _assemble(message, n, codecs, buf, offs, lens, vals, reserve, scalar_arrays)


def _general_walk(
    buf: np.ndarray,
    pos: np.ndarray,
    end: np.ndarray,
    key_to_field: np.ndarray,
    numbers: np.ndarray,
    field_codecs: list[FieldCodec],
    offs: dict[str, np.ndarray],
    lens: dict[str, np.ndarray],
    vals: dict[str, np.ndarray],
) -> bool:
    """``decode_batch``'s field walk for any layouts: one field of every unfinished message per step
    (grouped by field), filling offs/lens/vals; False at the first break of the canonical rules."""
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


def _classes_of(items: np.ndarray, shared: list):
    """length_classes of a packed field's items per message, once for all fields alike (ImuBatch's)."""
    if items.shape[0] < 2 or np.all(items == items[0]):
        return None
    if shared[0] is None or not np.array_equal(shared[0], items):
        shared[:] = [items, length_classes(items)]
    return shared[1]


def _assemble(
    message: str,
    n: int,
    codecs: tuple[FieldCodec, ...],
    buf: np.ndarray,
    offs: dict[str, np.ndarray],
    lens: dict[str, np.ndarray],
    vals: dict[str, np.ndarray],
    reserve: Callable[[str, np.dtype, int], np.ndarray] | None,
    scalar_arrays: bool = False,
) -> DecodedBatch | None:
    """The batch from the walked offsets and values: packed fields gathered (into ``reserve`` when
    given), strings decoded, scalars as lists; None if a packed length or a string is invalid."""
    arrays, scalars, counts = {}, {}, {}
    placed: list[str] = []
    shared: list = [None, None]  # (items per message, their length_classes) of the last packed field
    for c in codecs:
        if c.kind == "packed":
            size = c.dtype.itemsize
            ln = lens[c.name]
            if np.any(ln % size):
                return None
            classes = _classes_of(ln // size, shared)
            if reserve is None:
                arrays[c.name] = gather_bytes(buf, offs[c.name], ln, size, classes=classes).view(c.dtype)
            else:
                dst = reserve(c.name, c.dtype, int(ln.sum()) // size)
                gather_bytes(buf, offs[c.name], ln, size, out=dst.view(np.uint8), classes=classes)
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
        else:
            v = vals[c.name]  # a fresh array per call
            v = v.view(np.int64) if c.kind == "varint_s" else v.view(DOUBLE) if c.kind == "double" else v
            scalars[c.name] = v if scalar_arrays else v.tolist()
    return DecodedBatch(message, n, arrays, scalars, counts, frozenset(placed))
