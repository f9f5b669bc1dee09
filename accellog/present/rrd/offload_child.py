"""The child side of ``present.rrd.offload``: a process that writes one .rrd file with ``RunRecording``,
so that the ~0.5 s of ``import rerun`` and the writing run beside the command instead of in it
(``replay --rrd`` 1 h: 1.33-1.43x the replay alone in-process, 1.17-1.26x with this child;
``python benchmarks/run_all.py --rows replay --repeat 5``, figures in present.rrd.offload).

It reads calls from its stdin (frames of ``send``: pickle protocol 5, numpy arrays as out-of-band
buffers) and runs them on a real ``RunRecording`` saving to the temporary file its parent reserved
(``AtomicOutput.begin`` in the parent: the parent checks and locks the output and renames the file on
success). A reader thread drains the pipe from the first moment, chunk by chunk, while the main thread
imports ``rerun`` (~0.5 s), so the parent never waits for the import. At the top only the standard library is
imported: the reader runs before numpy and rerun are loaded.

Replies (to ``get`` and ``close``, or the first failure) go back on the file descriptor given as
argv[1]. The child stops, removes the temporary file and exits when its stdin ends without a
``close`` (the parent died or gave up), and after the first failure (which it reports once).
"""

from __future__ import annotations

import contextlib
import os
import pickle
import queue
import struct
import sys
import threading
from typing import Any

HEADER = struct.Struct("<IQ")
"""A frame: (number of out-of-band buffers, pickle length), the buffer lengths (<Q each), the pickle,
the buffers."""
IOV_MAX = 512
CHUNK_BYTES = 1 << 20


def frame(obj: Any) -> list[memoryview]:
    """obj as one frame: the header, the pickle and its out-of-band buffers (views, not copies)."""
    bufs: list[pickle.PickleBuffer] = []
    data = pickle.dumps(obj, protocol=5, buffer_callback=bufs.append)
    raws = [b.raw() for b in bufs]
    head = HEADER.pack(len(raws), len(data)) + struct.pack(f"<{len(raws)}Q", *(r.nbytes for r in raws))
    return [v for v in (memoryview(head), memoryview(data), *raws) if v.nbytes]


def write_all(fd: int, parts: list[memoryview]) -> None:
    """Write every part to fd (blocking until all of it is in the pipe)."""
    views = list(parts)
    while views:
        n = os.writev(fd, views[:IOV_MAX])
        while n:
            if n >= views[0].nbytes:
                n -= views[0].nbytes
                views.pop(0)
            else:
                views[0] = views[0][n:]
                n = 0


def send(fd: int, obj: Any) -> None:
    """Write obj as one frame to fd."""
    write_all(fd, frame(obj))


def _read_into(fd: int, buf) -> bool:
    """Fill buf from fd; False at the end of the stream."""
    mv = memoryview(buf).cast("B")
    got = 0
    while got < mv.nbytes:
        n = os.readv(fd, [mv[got:]])
        if n == 0:
            return False
        got += n
    return True


def recv_raw(fd: int) -> tuple[bytes, list] | None:
    """One frame from fd as (pickle bytes, buffers), None at the end of the stream (or mid-frame)."""
    head = bytearray(HEADER.size)
    if not _read_into(fd, head):
        return None
    n_buf, n_data = HEADER.unpack(head)
    sizes = bytearray(8 * n_buf)
    if n_buf and not _read_into(fd, sizes):
        return None
    data = bytearray(n_data)
    if not _read_into(fd, data):
        return None
    bufs = []
    for size in struct.unpack(f"<{n_buf}Q", sizes):
        b = bytearray(size)
        if size and not _read_into(fd, b):
            return None
        bufs.append(b)
    return bytes(data), bufs


def recv(fd: int) -> Any:
    """One object from fd; EOFError at the end of the stream."""
    frame = recv_raw(fd)
    if frame is None:
        raise EOFError
    return pickle.loads(frame[0], buffers=frame[1])


class Frames:
    """Frames cut out of a byte stream fed in chunks of any size."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.pos = 0

    def feed(self, chunk: bytes) -> None:
        if self.pos:
            del self.buf[: self.pos]
            self.pos = 0
        self.buf += chunk

    def next(self) -> tuple[bytes, list[bytearray]] | None:
        """The next complete frame as (pickle bytes, buffers: copies), None until more is fed."""
        with memoryview(self.buf) as mv:
            p = self.pos
            if len(mv) - p < HEADER.size:
                return None
            n_buf, n_data = HEADER.unpack_from(mv, p)
            a = p + HEADER.size + 8 * n_buf
            if len(mv) < a:
                return None
            sizes = struct.unpack_from(f"<{n_buf}Q", mv, p + HEADER.size)
            if len(mv) < a + n_data + sum(sizes):
                return None
            data, bufs = bytes(mv[a : a + n_data]), []
            a += n_data
            for size in sizes:
                bufs.append(bytearray(mv[a : a + size]))
                a += size
        self.pos = a
        return data, bufs


def _reader(fd: int, q: queue.SimpleQueue, gone: threading.Event) -> None:
    """Drain fd into q chunk by chunk (the GIL once a chunk: the main thread may be importing), then
    mark the end of the stream."""
    with contextlib.suppress(OSError):
        while chunk := os.read(fd, CHUNK_BYTES):
            q.put(chunk)
    gone.set()
    q.put(b"")


def _calls(q: queue.SimpleQueue):
    """The parent's calls in order; stops at the end of the stream."""
    frames = Frames()
    while chunk := q.get():  # b"": the end
        frames.feed(chunk)
        while (frame := frames.next()) is not None:
            yield pickle.loads(frame[0], buffers=frame[1])


def main() -> None:
    reply = int(sys.argv[1])
    chunks: queue.SimpleQueue = queue.SimpleQueue()
    gone = threading.Event()  # the parent closed the pipe (done, gave up or died)
    threading.Thread(target=_reader, args=(0, chunks, gone), daemon=True).start()
    rec = out = None
    try:
        from accellog.present.rrd import sdk

        sdk.FREEZE_AFTER_IMPORT = True  # a one-shot process: rerun's objects are never scanned again
        sdk.rerun_sdk()
        from accellog.present.rrd.recording import RunRecording
        from accellog.store.atomic import AtomicOutput

        class ParentsOutput(AtomicOutput):
            """The temporary file the parent reserved: the parent commits it (fsync, rename, unlock);
            here abort only removes it."""

            def __init__(self, tmp: str) -> None:
                super().__init__(tmp)
                self.tmp = self.out

            def commit(self):
                return self.tmp

        for op, *rest in _calls(chunks):  # to the end of the stream: no close, the parent is gone
            if op == "open":
                kw, tmp = rest
                out = ParentsOutput(tmp)
                if not gone.is_set():
                    rec = RunRecording(kw.pop("sink"), output=out, **kw)
            elif gone.is_set():
                continue  # the parent is gone: on to the end of the stream, then abort
            elif rec is None:
                raise RuntimeError(f"{op!r} before 'open'")
            elif op == "call":
                name, args, kwargs = rest
                getattr(rec, name)(*args, **kwargs)
            elif op == "get":
                (name,) = rest
                value = getattr(rec, name)
                send(reply, ("ok", value() if callable(value) else value))
            elif op == "close":
                rec.close()
                state = {"failures": rec.failures, "first_failure": rec.first_failure, "down": rec.down}
                rec = out = None
                send(reply, ("ok", state))
                os._exit(0)
    except BaseException as exc:  # reported to the parent, which prints it as one line
        _abort(rec, out)
        try:
            err: bytes | None = pickle.dumps(exc)
        except Exception:
            err = None
        with contextlib.suppress(OSError):
            send(reply, ("error", err, f"{type(exc).__name__}: {exc}"))
        os._exit(1)
    _abort(rec, out)
    os._exit(0)


def _abort(rec: Any, out: Any) -> None:
    """No file: the recording stopped (its temporary file removed), or the parent's temporary file
    removed when no recording was opened on it."""
    with contextlib.suppress(Exception):
        if rec is not None:
            rec.abort()
        elif out is not None:
            out.abort()


if __name__ == "__main__":
    main()
