"""Fleet run throughput: 2 local Dask workers vs the serial loop, scheduler overhead, worker memory.

Usage: python benchmarks/bench_fleet.py [--sessions 1000] [--workers 2] [--rounds 5] [--dir /tmp/accellog_bench_fleet]

Data: a simulated fleet (accellog.flows.fleet_sim: 6 poses x 3 s at 200 Hz per session, 4 sessions
per device; simulated once into --dir and reused on later runs). Both variants run the same
library call, `run_fleet(pipelines/fleet.toml, files, out)`, on the same files in the same run:

- serial: workers=0, the plain loop over `session_task` in this process;
- dask: a LocalCluster of --workers single-threaded processes on 127.0.0.1 (started and warmed up
  before timing; its start-up time is printed apart).

The sessions are cut into --rounds chunks and the two variants alternate chunk by chunk (serial
first, then dask first, ...), so that load from other processes on a shared machine hits both alike.

Figures: wall time of the task phase (hashing of the inputs, done before, is excluded for both),
speed-up = serial wall / dask wall (goal >= 1.7x on 2 workers), tasks/s per worker, the overhead
fraction (workers x wall - sum of task times) / sum of task times (scheduling + transfer + idle,
an upper bound), the scheduler's own per-task cost measured with 2000 no-op tasks as a fraction of
the mean task time (goal < 5 %), and the peak RSS of each worker process (ru_maxrss) after warm-up
and after the run. The machine is shared: the load average is printed with every figure.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import time
from pathlib import Path

import numpy as np

from accellog.flows.fleet import run_fleet
from accellog.flows.fleet_dask import local_cluster
from accellog.flows.fleet_sim import FleetSpec, simulate_fleet

REPO = Path(__file__).resolve().parents[1]
PIPELINE = REPO / "pipelines" / "fleet.toml"


def _load() -> str:
    return "load avg " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _noop(i: int) -> int:
    return i


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=1000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--dir", type=Path, default=Path("/tmp/accellog_bench_fleet"))
    args = ap.parse_args()
    per_device = 4
    n_dev = -(-args.sessions // per_device)
    sdir = args.dir / f"sessions_{n_dev}x{per_device}"
    if not (sdir / "fleet_truth.json").exists():
        t = time.perf_counter()
        simulate_fleet(FleetSpec(n_devices=n_dev, sessions_per_device=per_device), sdir, jobs=args.workers)
        print(f"simulated {n_dev * per_device} sessions in {time.perf_counter() - t:.1f} s ({_load()})")
    files = sorted(str(p) for p in sdir.rglob("*.mcap"))[: args.sessions]
    size_mb = sum(os.path.getsize(f) for f in files) / 1e6
    print(
        f"{len(files)} sessions, {size_mb:.0f} MB, pipeline {PIPELINE.name}; {os.cpu_count()} cores ({_load()})"
    )

    for sub in ("out_serial", "out_dask"):
        shutil.rmtree(args.dir / sub, ignore_errors=True)

    from dask.distributed import Client

    from accellog.flows.fleet import warm_worker

    t = time.perf_counter()
    cluster = local_cluster(args.workers)
    client = Client(cluster)
    start_s = time.perf_counter() - t
    chunks = np.array_split(np.array(files), args.rounds)
    wall = {"serial": 0.0, "dask": 0.0}
    task = {"serial": [0.0, 0.0], "dask": [0.0, 0.0]}  # sum wall, sum cpu of the tasks
    loads = []
    try:
        warm_worker()
        client.run(warm_worker)
        rss_warm = client.run(_maxrss_mb)
        rss0 = _maxrss_mb()
        print(f"dask: LocalCluster of {args.workers} started in {start_s:.1f} s ({_load()})")
        for k, chunk in enumerate(chunks):  # interleaved rounds: both variants see the same load
            order = ["serial", "dask"] if k % 2 == 0 else ["dask", "serial"]
            for v in order:
                r = run_fleet(
                    PIPELINE,
                    list(chunk),
                    args.dir / f"out_{v}",
                    **({"workers": 0} if v == "serial" else {"client": client}),
                )
                assert not r.errors, r.errors[:3]
                wall[v] += r.wall_s
                task[v][0] += r.sum_task_s
                task[v][1] += r.sum_task_cpu_s
                loads.append(os.getloadavg()[0])
                print(
                    f"  round {k + 1}/{args.rounds} {v:6s}: {len(chunk)} tasks in {r.wall_s:.1f} s ({_load()})"
                )
        rss_after = client.run(_maxrss_mb)
        # the scheduler's own cost per task: no-op tasks, same submission path
        t = time.perf_counter()
        futs = client.map(_noop, range(2000), pure=False)
        client.gather(futs)
        noop_s = (time.perf_counter() - t) / 2000
        del futs
    finally:
        client.close()
        cluster.close()

    n = len(files)
    w = args.workers
    ser_task, das_task = task["serial"][0] / n, task["dask"][0] / n
    ser_cpu, das_cpu = task["serial"][1] / n, task["dask"][1] / n
    overhead = (w * wall["dask"] - task["dask"][0]) / task["dask"][0]
    print()
    print(
        f"| figure | value | goal |  (load avg during the runs {min(loads):.1f}-{max(loads):.1f}; {_load()}; shared machine)"
    )
    print("|---|---|---|")
    print(f"| sessions | {n} ({size_mb:.0f} MB), {args.rounds} interleaved rounds | 1000 |")
    print(
        f"| serial loop wall | {wall['serial']:.1f} s ({1000 * ser_task:.0f} ms/task wall, {1000 * ser_cpu:.0f} ms CPU) | baseline |"
    )
    print(
        f"| dask {w} workers wall | {wall['dask']:.1f} s ({1000 * das_task:.0f} ms/task wall, {1000 * das_cpu:.0f} ms CPU on the workers) | |"
    )
    print(f"| speed-up (serial / dask) | {wall['serial'] / wall['dask']:.2f}x | >= 1.7x |")
    print(f"| tasks/s per worker | {n / wall['dask'] / w:.2f} | |")
    print(f"| overhead fraction (workers x wall - sum task) / sum task | {100 * overhead:.1f} % | |")
    print(
        f"| scheduler cost per task (2000 no-op tasks) | {noop_s * 1000:.2f} ms = {100 * noop_s / das_task:.2f} % of a task | < 5 % |"
    )
    print(f"| LocalCluster start-up | {start_s:.1f} s | |")
    for addr in sorted(rss_after):
        print(
            f"| worker {addr} peak RSS | {rss_warm[addr]:.0f} MB after warm-up -> {rss_after[addr]:.0f} MB after ~{n // w} tasks | bounded |"
        )
    print(f"| client (serial loop) peak RSS | {rss0:.0f} MB after warm-up -> {_maxrss_mb():.0f} MB | |")
    same = np.array_equal(_values(args.dir / "out_serial"), _values(args.dir / "out_dask"))
    print(f"| serial and dask parameters identical | {same} | True |")


def _values(out: Path) -> list[float]:
    from accellog.flows.fleet import read_table

    rows = sorted(read_table(out / "fleet.parquet"), key=lambda r: (r["session"], r["model"]))
    return [v for r in rows for v in r["values"]]


if __name__ == "__main__":
    main()
