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
