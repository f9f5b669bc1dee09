"""The quantities of the fleet scaling model (docs/fleet.md) and its prediction next to the measured point.

Usage: python benchmarks/bench_fleet_model.py [--sessions 300] [--workers 2] [--inner 100] [--repeat 3]
                                              [--predict 3000] [--at 2 16 64] [--dir /tmp/accellog_bench]

Sessions: the simulated fleet benchmarks/run_all.py uses for its `fleet` row (D/fleet_N, 4 short
sessions per device, made once). Measured, in this process (the client) and on a LocalCluster:

- t_s: CPU per session of `session_task` in the serial loop (warm), and c_s: the client's own CPU
  per session around it (storing the calibration files, the table), from run_fleet(workers=0);
- t_w: CPU per session on the workers when --workers run in parallel: the task itself and the
  worker process as a whole (its Dask event loop, per-task handling); c_p: the client's CPU per
  session meanwhile (scheduler + storing), from run_fleet on the cluster;
- the scheduler's cost per Dask task: 1000 no-op tasks, CPU in the client+scheduler and workers;
- the cluster's fixed cost: start (processes, imports), warm-up, shutdown, in this process; and end
  to end from the CLI: `fleet run` on 1 session and on all, serial and with --workers, interleaved.

Model: T_serial(N) = A + N (t_s + c_s); T_par(N, W) = A + F + phase + tail, with F the cluster's
fixed cost (CLI on 1 session, parallel - serial) and phase = max(N u_w / W, N u_c) on a cluster
(client and scheduler on their own core) or max(N u_w / W, N (u_w + u_c) / cores) here; u_w and u_c
are the per-session worker and client CPU with the Dask per-task cost spread over the batch size
of that run (accellog.flows.fleet_dask.batches); tail = one session. CPU times stand for idle wall
times of the CPU-bound parts (the machine may be shared: the load average is printed).
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import sys
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))

from run_all import ROOT, accellog, fleet_sessions, run_once  # noqa: E402

PIPELINE = ROOT / "pipelines" / "fleet.toml"


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _noop(i: int) -> int:
    return i


def _load() -> str:
    return "load avg " + " ".join(f"{x:.1f}" for x in os.getloadavg())


def measure_inner(files: list[str], workers: int, scratch: Path, repeat: int) -> dict[str, float]:
    """Per-session and fixed quantities measured in this process and on a LocalCluster (the
    per-session ones: medians of `repeat` interleaved rounds)."""
    from accellog.flows.fleet import run_fleet, warm_worker
    from accellog.flows.fleet_dask import batches, close_own, start_client

    m: dict[str, float] = {}
    n = len(files)
    from accellog.flows.fleet import pipeline_hash, session_task
    from accellog.flows.pipeline import load_pipeline

    warm_worker()
    run_fleet(PIPELINE, files[:5], scratch / "warm", workers=0)  # first-call caches
    spec = load_pipeline(PIPELINE)

    t0, c0 = time.perf_counter(), _cpu()
    client = start_client(None, workers).result()
    m["start_wall"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    client.run(warm_worker)
    m["warm_wall"] = time.perf_counter() - t0
    wcpu = lambda: sum(client.run(_cpu).values())  # noqa: E731
    w0 = wcpu()
    m["start_cpu_worker"] = w0 / workers
    m["start_cpu_client"] = _cpu() - c0
    try:
        run_fleet(PIPELINE, files[: 2 * workers], scratch / "pwarm", client=client)
        runs: dict[str, list[float]] = {}
        for _ in range(repeat):  # interleaved: a change of the host's speed hits every figure alike
            c0 = _cpu()
            for f in files:  # the task alone (no writer threads running beside it)
                session_task(f, None, spec, pipeline_hash(spec))
            runs.setdefault("t_s", []).append((_cpu() - c0) / n)
            c0 = _cpu()
            run_fleet(PIPELINE, files, scratch / "serial", workers=0, force=True)
            runs.setdefault("c_s", []).append((_cpu() - c0) / n - runs["t_s"][-1])
            w0, c0 = wcpu(), _cpu()
            r = run_fleet(PIPELINE, files, scratch / "parallel", client=client, force=True)
            runs.setdefault("t_w_task", []).append(r.sum_task_cpu_s / n)
            runs.setdefault("t_w", []).append((wcpu() - w0) / n)
            runs.setdefault("c_p", []).append((_cpu() - c0) / n)
        m.update({k: statistics.median(v) for k, v in runs.items()})
        sizes = [os.path.getsize(f) for f in files]
        m["size"] = sum(sizes) / n
        m["tasks_per_session"] = len(batches(sizes, workers)) / n
        k = 1000
        w0, c0, t0 = wcpu(), _cpu(), time.perf_counter()
        client.gather(client.map(_noop, range(k), pure=False))
        m["noop_wall"] = (time.perf_counter() - t0) / k
        m["noop_worker"] = (wcpu() - w0) / k
        m["noop_client"] = (_cpu() - c0) / k
        t0 = time.perf_counter()  # the fixed cost on a running cluster: connect, warm-up, close
        other = type(client)(client.scheduler.address)
        other.run(warm_worker)
        other.close()
        m["f_running"] = time.perf_counter() - t0
    finally:
        t0 = time.perf_counter()
        close_own(client)
        m["close_wall"] = time.perf_counter() - t0
    return m


def measure_cli(folder: Path, n_all: int, workers: int, repeat: int, scratch: Path) -> dict[str, tuple]:
    """Median (wall s, CPU s) of `accellog fleet run` on 1 session and on all, serial and parallel."""
    one = scratch / "one"
    one.mkdir(parents=True, exist_ok=True)
    first = sorted(folder.rglob("*.mcap"))[0]
    if not (one / first.name).exists():
        shutil.copy(first, one / first.name)
    runs: dict[str, list] = {}
    for _ in range(repeat):  # interleaved: a change of load hits every variant alike
        for name, src, w in (("1 serial", one, 0), ("1 par", one, workers),
                             (f"{n_all} serial", folder, 0), (f"{n_all} par", folder, workers)):  # fmt: skip
            cmd = accellog("fleet", "run", PIPELINE, f"{src}/**/*.mcap", "--force", "-o",
                           scratch / f"cli_{w}", "--workers", w)  # fmt: skip
            runs.setdefault(name, []).append(run_once(cmd, scratch)[:2])
    return {k: tuple(statistics.median(x[i] for x in v) for i in range(2)) for k, v in runs.items()}


def predict(
    m: dict, a_s: float, fixed: float, n: int, w: int, local_cores: int | None
) -> tuple[float, float]:
    """(T_serial, T_par) of the model for n sessions on w workers (local_cores: client and workers
    share that many cores; None: a cluster, the client on a core of its own)."""
    from accellog.flows.fleet_dask import batches

    per_task = len(batches([round(m["size"])] * n, w)) / n  # Dask tasks per session at this size
    u_w = m["t_w"] + m["noop_worker"] * (per_task - m["tasks_per_session"])
    u_c = m["c_p"] + m["noop_client"] * (per_task - m["tasks_per_session"])
    t_ser = a_s + n * (m["t_s"] + m["c_s"])
    phase = max(n * u_w / w, n * u_c)
    if local_cores:
        phase = max(phase, n * (u_w + u_c) / local_cores)
    return t_ser, a_s + fixed + phase + u_w


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=300)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--inner", type=int, default=100, help="sessions for the in-process figures")
    ap.add_argument(
        "--repeat",
        type=int,
        default=3,
        help="interleaved rounds of the in-process figures and CLI runs of each variant",
    )
    ap.add_argument("--predict", type=int, default=3000, help="sessions of the prediction")
    ap.add_argument("--at", type=int, nargs="+", default=[2, 16, 64], help="workers of the prediction")
    ap.add_argument("--dir", type=Path, default=Path("/tmp/accellog_bench"))
    a = ap.parse_args()
    folder = fleet_sessions(a.dir, a.sessions)
    files = sorted(str(p) for p in folder.rglob("*.mcap"))
    scratch = a.dir / "fleet_model"
    shutil.rmtree(scratch, ignore_errors=True)
    print(f"{len(files)} sessions in {folder}; {os.cpu_count()} cores ({_load()})", flush=True)
    m = measure_inner(files[: a.inner], a.workers, scratch, a.repeat)
    print(f"in-process figures done ({_load()})", flush=True)
    cli = measure_cli(folder, len(files), a.workers, a.repeat, scratch)
    n, w = len(files), a.workers
    t1s, t1p = cli["1 serial"][0], cli["1 par"][0]
    a_s = t1s - m["t_s"]  # the serial CLI's fixed part: start-up, imports, table
    fixed = t1p - t1s  # what the cluster adds on 1 session: start, warm-up, shutdown
    ms = 1000
    print(f"\n| quantity | measured | ({_load()}; CPU times stand for idle wall times) |\n|---|---|---|")
    print(f"| t_s: CPU per session, serial loop | {ms * m['t_s']:.1f} ms | session_task |")
    print(f"| c_s: client CPU per session around it (store, table) | {ms * m['c_s']:.2f} ms | serial |")
    print(f"| t_w: CPU per session on a worker, {w} in parallel | {ms * m['t_w']:.1f} ms "
          f"(task {ms * m['t_w_task']:.1f} ms) | the worker process as a whole |")  # fmt: skip
    print(f"| c_p: client + scheduler CPU per session, parallel | {ms * m['c_p']:.2f} ms | "
          f"{m['tasks_per_session']:.3f} Dask tasks per session |")  # fmt: skip
    print(f"| Dask cost per task (1000 no-op tasks) | client+scheduler {ms * m['noop_client']:.2f} ms, "
          f"worker {ms * m['noop_worker']:.2f} ms CPU; round trip {ms * m['noop_wall']:.2f} ms | |")  # fmt: skip
    print(f"| cluster start / warm-up / shutdown (wall) | {m['start_wall']:.2f} / {m['warm_wall']:.2f} / "
          f"{m['close_wall']:.2f} s | start CPU {m['start_cpu_worker']:.2f} s per worker (imports) |")  # fmt: skip
    print(f"| CLI, 1 session: serial / {w} workers | {t1s:.2f} / {t1p:.2f} s wall "
          f"(CPU {cli['1 serial'][1]:.2f} / {cli['1 par'][1]:.2f} s) | A = {a_s:.2f} s, F = {fixed:.2f} s "
          f"(goal < 2 s; CPU {cli['1 par'][1] - cli['1 serial'][1]:.2f} s) |")  # fmt: skip
    ws, wp = cli[f"{n} serial"][0], cli[f"{n} par"][0]
    print(f"| CLI, {n} sessions: serial / {w} workers | {ws:.2f} / {wp:.2f} s wall "
          f"(CPU {cli[f'{n} serial'][1]:.2f} / {cli[f'{n} par'][1]:.2f} s) | measured speed-up {ws / wp:.2f}x |")  # fmt: skip
    ts, tp = predict(m, a_s, fixed, n, w, os.cpu_count())
    print(f"| model, {n} sessions on {w} local workers | {ts:.2f} / {tp:.2f} s | predicted {ts / tp:.2f}x |")
    print(f"| fixed cost on a running cluster (connect, warm-up) | {m['f_running']:.2f} s | F_run |")
    print(f"\n| {a.predict} sessions, cluster | T_serial | T_par, cluster started (F) | speed-up "
          "| T_par, running cluster (F_run) | speed-up |\n|---|---|---|---|---|---|")  # fmt: skip
    for wk in a.at:
        ts, tp = predict(m, a_s, fixed, a.predict, wk, None)
        _, tr = predict(m, a_s, m["f_running"], a.predict, wk, None)
        print(f"| {wk} workers | {ts:.1f} s | {tp:.1f} s | {ts / tp:.1f}x | {tr:.1f} s | {ts / tr:.1f}x |")


if __name__ == "__main__":
    main()
