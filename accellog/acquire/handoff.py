"""Hand the recording loop's writes and callbacks to one helper thread, in order.

The reading thread must come back to the FIFO within 36 ms at 1 kHz (512 bytes). Encoding and
compressing MCAP chunks, the ``write`` of a chunk (which can block behind another process's
``fsync`` on the same file system), the live view and the running calibration take that time
away from it on a busy host. ``Handoff.post(fn, *args)`` queues the call instead; one thread runs
the calls in the order they were posted, so the file gets exactly what the inline loop would
have written. ``close()`` runs everything still queued before it returns.

A failed call (disk full, a closed writer) stops the helper: the calls queued after it are not
run, and the error is raised on the reading thread at its next ``post`` or at ``close``, so the
recording stops as it would have inline and the writer's context finishes the file.

The thread starts at the first ``post`` (after the caller raised the reading thread's priority:
Linux threads inherit it, so the helper is not held off while it holds the GIL the reader waits for).
Used by ``Recorder(write_thread=True)``; ``accellog record`` keeps its writes inline (measured:
no lower loss on a loaded 2-core host, benchmarks/bench_record_load.py).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable


class Handoff:
    """Runs posted calls in order on one daemon thread (``threaded=False``: at once, inline)."""

    def __init__(self, *, threaded: bool = True, name: str = "accellog-writer") -> None:
        self.threaded = threaded
        self.name = name
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._reported = False
        self.posted = 0
        self.peak_backlog = 0
        """Most calls waiting at once (seen at post time)."""

    def post(self, fn: Callable, *args, **kwargs) -> None:
        """Run fn(*args, **kwargs) after every call posted before it; raises a helper's earlier error
        (again at every later post: nothing runs after a failed call)."""
        if self._error is not None:
            self._reported = True
            raise self._error
        self.posted += 1
        if not self.threaded:
            fn(*args, **kwargs)
            return
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
            self._thread.start()
        self._q.put((fn, args, kwargs))
        self.peak_backlog = max(self.peak_backlog, self._q.qsize())

    def _run(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            if self._error is not None:
                continue  # drain without running: the reading thread stops at its next post
            fn, args, kwargs = item
            try:
                fn(*args, **kwargs)
            except BaseException as exc:  # handed to the reading thread
                self._error = exc

    def close(self) -> None:
        """Run every queued call, stop the thread; raise a helper's error not yet raised by post."""
        t, self._thread = self._thread, None
        if t is not None:
            self._q.put(None)
            t.join()
        if self._error is not None and not self._reported:
            self._reported = True
            raise self._error
