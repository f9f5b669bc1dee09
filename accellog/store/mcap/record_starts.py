"""Where the Message records start in a group's decompressed chunk records (``fastread``'s walk).

``message_starts`` walks the record chain with checked guesses (runs of equal-length messages
checked at once with numpy); ``chunkwise_starts`` walks the chains of many small chunks side by side
(recorder files: ~15 records per 0.5 s chunk). Both raise ``NotFast`` on a record that crosses its
chunk end or a schema / channel record that does not fill its length: the generic reader decides.
"""

from __future__ import annotations

import itertools

import numpy as np

from accellog.store.mcap.byte_views import read_le
from accellog.store.mcap.index import (
    OP_CHANNEL,
    OP_MESSAGE,
    OP_SCHEMA,
    REC,
    NotFast,
    channel_at,
    equal_records,
    schema_at,
)

MANY_CHUNKS = 32  # chunks in a group from which chunkwise_starts walks them side by side
MAX_STEPS = 64  # chunkwise_starts gives up after this many records in one chunk


def chunkwise_starts(records: bytes | bytearray, usize: list[int]) -> np.ndarray | None:
    """``message_starts`` for groups of many small chunks (recorder files: ~15 records per 0.5 s
    chunk): the record chains of all chunks walked side by side, one record of every chunk per numpy
    step, so the steps are the records of the longest chunk whatever their lengths; the same checks
    (no record across its chunk end; schema and channel records fill their length). None if a chunk
    holds more than MAX_STEPS records (then the guessing walk does better). Chunks of equal-length
    Messages only (index.equal_records, all checked at once) are not walked."""
    size = np.asarray(usize, dtype=np.int64)
    end = np.cumsum(size)
    pos, end = (end - size)[size > 0], end[size > 0]
    rb = np.frombuffer(records, np.uint8)
    found, left = equal_records(rb, pos, end)
    pos, end = pos[left], end[left]
    for _ in range(MAX_STEPS):
        if not pos.shape[0]:
            return np.sort(np.concatenate(found)) if found else np.zeros(0, np.int64)
        op = rb[pos]
        room = end - pos - 9
        ln = read_le(rb, pos + 1, "<u8")
        if np.any(room < 0) or np.any(ln > room.astype(np.uint64)):
            raise NotFast("record across a chunk boundary")
        nxt = pos + 9 + ln.astype(np.int64)
        found.append(pos[op == OP_MESSAGE])
        for j in np.flatnonzero((op == OP_SCHEMA) | (op == OP_CHANNEL)).tolist():
            at = int(pos[j])  # read by content in mcap: length must agree
            if (schema_at if op[j] == OP_SCHEMA else channel_at)(records, at + 9)[1] != int(nxt[j]):
                raise NotFast("schema/channel record length in a chunk")
        more = nxt < end
        pos, end = nxt[more], end[more]
    return None


_STEP = 64  # message_starts: records walked one by one in Python after a short run of equal lengths
_SHORT = 32  # a run shorter than this did not pay for its numpy guess (~40 Python steps)


def message_starts(records: bytes | bytearray, usize: list[int]) -> np.ndarray:
    """Offsets of the Message records in the concatenated chunk records (each chunk must be whole).

    Walks the record chain; at a Message record of length L it guesses that the records that follow
    are Messages of the same length (the usual case: same fields, same varint sizes) and checks all
    those guesses at once with numpy (opcode, length, no record across a chunk end), keeping the run
    up to the first miss, so the Python walk only steps where the record layout changes. At most
    about twice the last run is guessed at a time, so short runs do not cost a scan to the end of the
    group each (linear in the records, not quadratic). After a short run (lengths that vary, as in
    recorder files with FIFO reads of varying size) the next _STEP records are stepped in Python, a
    fraction of a guess's cost each, until _SHORT/2 equal lengths in a row make guessing pay again.
    """
    unpack = REC.unpack_from
    ends = list(itertools.accumulate(usize))
    total = ends[-1] if ends else 0
    ends_arr = np.asarray(ends, dtype=np.int64)
    rb = np.frombuffer(records, np.uint8)
    runs: list[np.ndarray] = []
    single: list[int] = []  # messages stepped one by one since the last run (in order)
    pos, k, span = 0, 0, 64  # span: guesses checked at once, doubled while runs fill it (linear time)
    step, same, last = 0, 0, -1  # records left to step; equal lengths in a row while stepping
    while pos < total:
        while pos >= ends[k]:  # next chunk (a record never crosses a chunk end)
            k += 1
        op, ln = unpack(records, pos)
        nxt = pos + 9 + ln
        if nxt > ends[k]:
            raise NotFast("record across a chunk boundary")
        if op == OP_MESSAGE and step:
            single.append(pos)
            same = same + 1 if ln == last else 0
            step, last = (0 if same >= _SHORT // 2 else step - 1), ln
            pos = nxt
            continue
        if op == OP_MESSAGE:
            stride = 9 + ln
            stop = min(total - stride + 1, pos + stride * span)
            guess = np.arange(pos, stop, stride, dtype=np.int64)  # guess[0] == pos: checked
            ok = (rb[guess] == OP_MESSAGE) & (read_le(rb, guess + 1, "<u8") == ln)
            ok &= np.searchsorted(ends_arr, guess, "right") == np.searchsorted(
                ends_arr, guess + (stride - 1), "right"
            )
            m = guess.shape[0] if ok.all() else int(np.argmin(ok))
            if single:
                runs.append(np.asarray(single, dtype=np.int64))
                single = []
            runs.append(guess[:m])
            pos = int(guess[m - 1]) + stride
            span = 2 * m if m == guess.shape[0] else max(64, 2 * m)
            step, same, last = (_STEP if m < _SHORT else 0), 0, -1
            continue
        if op in (OP_SCHEMA, OP_CHANNEL):  # read by content in mcap: length must agree
            q = (schema_at if op == OP_SCHEMA else channel_at)(records, pos + 9)[1]
            if q != nxt:
                raise NotFast("schema/channel record length in a chunk")
        pos = nxt
    if single:
        runs.append(np.asarray(single, dtype=np.int64))
    return np.concatenate(runs) if runs else np.zeros(0, np.int64)
