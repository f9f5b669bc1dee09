"""Local fleet workers are forked from a fork server that imported what a task needs
(accellog.flows.fleet_worker), instead of each spawned worker importing it: a real LocalCluster."""

from __future__ import annotations

import os
import sys


def _state() -> tuple[bool, bool, int, str]:
    """On a worker: (preload module imported, scipy.optimize imported, parent pid, cwd)."""
    return (
        "accellog.flows.fleet_worker" in sys.modules,
        "scipy.optimize" in sys.modules,
        os.getppid(),
        os.getcwd(),
    )


def test_local_workers_are_forked_ready_from_the_fork_server(tmp_path, monkeypatch):
    from dask.distributed import Client

    from accellog.flows.fleet_dask import close_own, local_cluster

    monkeypatch.chdir(tmp_path)  # a worker works in the client's folder as a spawned one does
    client = Client(local_cluster(2))
    try:
        got = list(client.run(_state).values())
    finally:
        close_own(client)
    assert len(got) == 2
    for preloaded, solver, parent, cwd in got:
        assert preloaded and solver  # imported before the worker existed: no warm-up left to pay
        assert parent != os.getpid()  # forked by the server, not spawned by this process's nanny
        assert cwd == str(tmp_path)


def test_closing_reaps_the_fork_server_so_the_workers_cpu_is_counted():
    """After close_own the fork server has ended and been waited for: the workers' CPU time is in
    this process's RUSAGE_CHILDREN (what `time accellog fleet run` and the benchmarks read)."""
    import multiprocessing.forkserver
    import resource

    from dask.distributed import Client

    from accellog.flows.fleet_dask import close_own, local_cluster

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    client = Client(local_cluster(2))
    try:
        spent = sum(client.run(_burn).values())  # CPU seconds the two workers spent
    finally:
        close_own(client)
    assert multiprocessing.forkserver._forkserver._forkserver_pid is None
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    counted = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    assert counted >= 0.9 * spent, (counted, spent)


def _burn() -> float:
    """On a worker: spend ~0.3 s of CPU, return the worker's CPU time so far (s)."""
    import time

    end = time.process_time() + 0.3
    while time.process_time() < end:
        pass
    return time.process_time()
