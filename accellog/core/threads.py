"""Worker threads only where they pay.

accellog overlaps reading, decompressing and reducing on helper threads (numpy, lz4 and zstd release
the GIL), which pays on long sessions. On a short one there is nothing to overlap, and each
``ThreadPoolExecutor`` costs a thread start and a hand-over per call: a 250 kB fleet session (6
poses x 3 s at 200 Hz) started five threads and spent ~3 ms of its 25 ms in them
(benchmarks/bench_fleet_model.py). ``pool(workers, threaded)`` gives a real pool, or an
``InlineExecutor`` that runs each call at ``submit`` in the caller's thread, behind the same
``concurrent.futures.Executor`` interface.
"""

from __future__ import annotations

from concurrent.futures import Executor, Future, ThreadPoolExecutor


class InlineExecutor(Executor):
    """An Executor that runs each call at submit, in the calling thread; its Future is done on return
    (an Exception is kept in it, as a pool would; KeyboardInterrupt and SystemExit propagate)."""

    def submit(self, fn, /, *args, **kwargs) -> Future:
        f: Future = Future()
        try:
            f.set_result(fn(*args, **kwargs))
        except Exception as exc:
            f.set_exception(exc)
        return f


def pool(workers: int, threaded: bool) -> Executor:
    """A ThreadPoolExecutor of `workers` threads, or an InlineExecutor when not `threaded`."""
    return ThreadPoolExecutor(workers) if threaded else InlineExecutor()
