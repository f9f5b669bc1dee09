"""The Dask side of `accellog fleet run`: the local cluster, its settings, batches of sessions as
tasks, and shutdown. Dask is imported only here (inside the functions).

Where the time goes and why these choices: docs/fleet.md ("Scaling model"), measured with
benchmarks/bench_fleet_model.py.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Sequence

__all__ = [
    "MAX_BATCH_BYTES",
    "WORKER_CONFIG",
    "batches",
    "close_own",
    "local_cluster",
    "prestart_workers",
    "run_batches",
    "start_client",
    "stop_fork_server",
]


MALLOC_TRIM_THRESHOLD = 1 << 30
"""glibc's M_TRIM_THRESHOLD in a worker (bytes): WORKER_CONFIG below."""
MALLOC_MMAP_THRESHOLD = 1 << 25
"""glibc's M_MMAP_THRESHOLD in a worker (bytes): WORKER_CONFIG below."""

WORKER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.admin.system-monitor.gil.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": MALLOC_TRIM_THRESHOLD,
    "distributed.nanny.pre-spawn-environ.MALLOC_MMAP_THRESHOLD_": MALLOC_MMAP_THRESHOLD,
}
"""Dask settings of local workers (the same keys belong in a real cluster's dask config, docs/fleet.md):

- no statistical profiler (a thread sampling the task thread's stack every 10 ms), a slower system
  monitor, event-loop health checks every 1 s instead of 20 ms and the memory monitor every 1 s
  instead of 100 ms: an idle worker then costs 2.9 instead of 17 ms of CPU per second and the
  scheduler 7 instead of 42 (benchmarks/bench_fleet_model.py measures it);
- glibc's malloc trim threshold raised from Dask's 64 KiB to 1 GiB: with Dask's value every freed
  numpy array went back to the kernel and came back as page faults (a task cost 172 vs 92 ms);
- the mmap threshold fixed at 32 MiB: setting the trim threshold switches off glibc's sliding mmap
  threshold, so every array above 128 KiB was mmap'd and faulted in afresh (375 page faults per
  session instead of 20; a task 8-12 % more CPU than in the serial loop, now the same)."""


PRELOAD = "accellog.flows.fleet_worker"
"""The module the fork server of local workers imports before it forks them."""


def prestart_workers() -> bool:
    """Start the fork server that local workers are forked from, with PRELOAD imported in it, unless
    it runs: called as ``fleet run`` starts, it imports while the command does (accellog.flows.
    fleet_worker). False where there is no fork server (not POSIX): workers are then spawned."""
    import multiprocessing
    import multiprocessing.forkserver

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return False
    multiprocessing.set_forkserver_preload([PRELOAD])  # no effect on a server already running
    multiprocessing.forkserver.ensure_running()
    return True


def local_cluster(n_workers: int | None = None):
    """A dask LocalCluster on 127.0.0.1: n_workers single-threaded processes (default: cores),
    no dashboard, WORKER_CONFIG; its workers forked from the fork server (``prestart_workers``)."""
    import logging

    import dask
    import distributed.utils
    from dask.distributed import LocalCluster

    n = n_workers or os.cpu_count() or 1
    config = dict(WORKER_CONFIG)
    if prestart_workers():
        config["distributed.worker.multiprocessing-method"] = "forkserver"
        # Dask would otherwise import pandas & co. here (in the client) to set a preload of its own,
        # which a running server ignores: ours (PRELOAD) is set
        if hasattr(distributed.utils, "_forkserver_preload_set"):
            distributed.utils._forkserver_preload_set = True
    with dask.config.set(config):
        return LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",  # Dask's HTTP endpoints on a free local port
            silence_logs=logging.ERROR,
        )


def _quiet(dask_worker) -> None:
    """No more heartbeats from this worker (run on it before its scheduler retires it)."""
    for name in ("heartbeat", "keep-alive"):
        pc = dask_worker.periodic_callbacks.get(name)
        if pc is not None:
            pc.stop()


def close_own(client) -> None:
    """Close a client and the cluster accellog started for it, workers first, their heartbeats
    stopped before: a heartbeat in flight while the scheduler retired its worker, or a worker whose
    scheduler went first, logged 'Failed to communicate with scheduler during heartbeat' with a
    traceback on stderr after a successful run (3 of ~30 runs at 3 workers without the stop, 0 of 15 with it). The
    wait is for the worker processes to end (the cluster's `workers` empties when their nannies
    closed)."""
    cluster = client.cluster
    if cluster is not None:
        try:
            client.run(_quiet)
            cluster.scale(0)  # the nannies stop their workers while the scheduler still answers
            end = time.monotonic() + 30.0
            while cluster.workers and time.monotonic() < end:
                time.sleep(0.02)
        except Exception:  # a cluster that is already going away: closing below is enough
            pass
    client.close()
    if cluster is not None:
        cluster.close()
        stop_fork_server()


def stop_fork_server() -> None:
    """Stop the fork server the local workers came from and wait for it: it has reaped the workers,
    so their CPU time joins this process's children's (``time accellog fleet run`` missed 60-75 % of
    a 2-worker run's CPU while the server was left to die unreaped at exit). The standard
    library has no public call for it: ``ForkServer._stop`` (CPython's own tests use it), skipped
    where it is missing."""
    import multiprocessing.forkserver

    server = getattr(multiprocessing.forkserver, "_forkserver", None)
    stop = getattr(server, "_stop", None)
    if stop is not None and getattr(server, "_forkserver_pid", None) is not None:
        with contextlib.suppress(OSError):  # already gone: nothing left to count
            stop()


MAX_BATCH_BYTES = 4 << 20
"""Largest batch of sessions in one Dask task, bytes of session files (16 short sessions of 250 kB,
~0.3 s of CPU; a long session is a task of its own)."""


def batches(sizes: Sequence[int], n_workers: int, most: int = MAX_BATCH_BYTES) -> list[range]:
    """Consecutive index ranges of ``sizes`` (file sizes, bytes), one Dask task each: guided
    self-scheduling, every batch at most ``most`` bytes and at most 1 / (2 n_workers) of the bytes
    still unassigned, so batches shrink towards the end and the workers finish together."""
    out, i, left = [], 0, sum(sizes)
    while i < len(sizes):
        budget = min(most, left / (2 * max(n_workers, 1)))
        j, got = i + 1, sizes[i]
        while j < len(sizes) and got + sizes[j] <= budget:
            got += sizes[j]
            j += 1
        out.append(range(i, j))
        left -= got
        i = j
    return out


def run_batches(
    client, batch_fn: Callable, todo: list[str], hashes: list[str], args: tuple, on_result
) -> None:
    """``batch_fn(paths, hashes, *args)`` (a list of one result per session) as Dask tasks over
    batches of `todo` (see ``batches``), larger batches first; ``on_result`` gets each session's
    result in the client as its batch ends. A task that fails as a whole (a lost worker) gives each
    of its sessions an error row."""
    from dask.distributed import as_completed

    n_workers = max(len(client.scheduler_info()["workers"]), 1)
    parts = batches([os.path.getsize(p) if os.path.isfile(p) else 0 for p in todo], n_workers)
    futs, where = {}, dict(zip(todo, hashes, strict=True))
    for k, part in enumerate(parts):  # larger batches first (higher priority), the small ones last
        paths = todo[part.start : part.stop]
        fut = client.submit(batch_fn, paths, [where[p] for p in paths], *args,
                            priority=len(parts) - k, pure=False)  # fmt: skip
        futs[fut] = paths
    # the task function catches its own errors; a lost worker still surfaces here as error rows
    for fut in as_completed(list(futs)):
        paths = futs.pop(fut)
        try:
            results = fut.result()
        except Exception as exc:
            msg = f"task failed: {type(exc).__name__}: {exc}".splitlines()[0]
            results = [{"rows": [{"session": p, "model": "", "error": msg}], "cals": {}} for p in paths]
        fut.release()
        for r in results:
            on_result(r)


def is_local(client) -> bool:
    """Whether `client`'s cluster is a LocalCluster (its workers share this machine's files)."""
    from dask.distributed import LocalCluster

    return isinstance(getattr(client, "cluster", None), LocalCluster)


def start_client(scheduler: str | None, workers: int | None):
    """A Future of a dask Client: of the scheduler at `scheduler`, else of a new LocalCluster of
    `workers` processes, made in a thread (the caller goes on meanwhile)."""
    from concurrent.futures import ThreadPoolExecutor

    def make():
        from dask.distributed import Client

        return Client(scheduler) if scheduler else Client(local_cluster(workers))

    ex = ThreadPoolExecutor(1, thread_name_prefix="fleet-cluster")
    try:
        return ex.submit(make)
    finally:
        ex.shutdown(wait=False)  # the thread ends when the client is made
