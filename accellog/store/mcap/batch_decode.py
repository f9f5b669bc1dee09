"""Vectorised decoding of many messages at once (the fast MCAP read-back).

Payloads of one channel are gathered into one uint8 buffer; field offsets are found for all messages at
once (``field_walk``) and packed arrays are read with strided views straight into preallocated
accumulators.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from accellog.store.codec import DOUBLE, FieldCodec, codecs_of
from accellog.store.mcap.byte_views import byte_window, void_window
from accellog.store.mcap.field_walk import WIRE, Walk, walk_fields

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
    scalars: dict[str, list | np.ndarray]  # lists, or arrays with scalar_arrays
    counts: dict[str, np.ndarray]
    placed: frozenset[str] = frozenset()  # arrays already written in place by BatchAccumulator.reserve
    derived: dict[str, np.ndarray] | None = None  # columns converted while reading (reader.ImuAccumulator)

    def result(self) -> tuple[dict[str, np.ndarray], dict[str, list | np.ndarray], dict[str, np.ndarray]]:
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
        scalars: dict[str, list | np.ndarray] = dict(self._scalars)  # the lists shared
        return DecodedBatch(self.message, self.n_messages, arrays, scalars, counts)


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
        key_to_field[(num << 3) | WIRE[c.kind]] = i
        numbers[i] = num
    field_codecs = list(by_number.values())
    offs = {c.name: np.zeros(n, np.int64) for c in codecs if c.kind in ("packed", "string", "bytes")}
    lens = {name: np.zeros(n, np.int64) for name in offs}
    vals = {c.name: np.zeros(n, np.uint64) for c in codecs if c.kind not in offs}
    if not walk_fields(Walk(buf, pos, end, key_to_field, numbers, field_codecs, offs, lens, vals)):
        return None
    return _assemble(message, n, codecs, buf, offs, lens, vals, reserve, scalar_arrays)


def _classes_of(items: np.ndarray, shared: list):
    """length_classes of a packed field's items per message, once for all fields whose items are
    proportional (ImuBatch: k, 3k, 3k, k samples a message: equal k, equal 3k)."""
    if items.shape[0] < 2 or np.all(items == items[0]):
        return None
    s = shared[0]
    a, b = (0, 0) if s is None or s.shape != items.shape else (int(s[0]), int(items[0]))
    if not (a and b and np.array_equal(items * a, s * b)):
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
    arrays: dict[str, np.ndarray] = {}
    scalars: dict[str, list | np.ndarray] = {}
    counts: dict[str, np.ndarray] = {}
    placed: list[str] = []
    shared: list = [None, None]  # (items per message, their length_classes) of the last packed field
    for c in codecs:
        if c.kind == "packed":
            dtype = c.packed_dtype
            size = dtype.itemsize
            ln = lens[c.name]
            if np.any(ln % size):
                return None
            classes = _classes_of(ln // size, shared)
            if reserve is None:
                arrays[c.name] = gather_bytes(buf, offs[c.name], ln, size, classes=classes).view(dtype)
            else:
                dst = reserve(c.name, dtype, int(ln.sum()) // size)
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
                    scalars[c.name] = [b.decode("utf-8") for b in items]
                except UnicodeDecodeError:
                    return None
            else:
                scalars[c.name] = items
        else:
            v = vals[c.name]  # a fresh array per call
            v = v.view(np.int64) if c.kind == "varint_s" else v.view(DOUBLE) if c.kind == "double" else v
            scalars[c.name] = v if scalar_arrays else v.tolist()
    return DecodedBatch(message, n, arrays, scalars, counts, frozenset(placed))
