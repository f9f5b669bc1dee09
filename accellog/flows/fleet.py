"""Fleet run: one pipeline applied to many sessions as independent tasks on Dask (dask.distributed).

    accellog fleet run PIPELINE.toml 'SESSIONS/**/*.mcap' -o FLEET/

Each session is one task (``session_task``): the worker reads the file with accellog's reader
(fastread for finished files), runs the pipeline with every input role bound to that file, and
returns a few rows (one per model: parameters +- 1 sigma, chi2/dof, held-out RMS, noise) plus the
calibration dicts: a few kB, never samples. A file that cannot be read or fitted becomes one error
row with its one-line message. The client writes FLEET/fleet.parquet atomically (temp + rename)
and FLEET/cal/<device>/<session>_<model>.json.

Re-runs: a session whose content SHA-256 and pipeline hash (pipeline spec + accellog version) are
already in fleet.parquet is skipped (its rows are kept); ``force`` recomputes everything.

Cluster: a LocalCluster bound to 127.0.0.1 (one single-threaded worker process per core) unless
a scheduler address (tcp://HOST:8786) is given; the input paths must then be readable by the
workers under the same names (shared filesystem). Dask is imported only here.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from accellog.calibrate.calfile.calibration import sha256_file, write_json_atomic
from accellog.core.errors import AccellogError, InputError
from accellog.core.version import __version__
from accellog.flows.fleet_inputs import find_sessions, safe_part, unique_files
from accellog.flows.fleet_table import TABLE_NAME, read_table, write_table

__all__ = [
    "CAL_DIR",
    "TABLE_NAME",
    "FleetRunResult",
    "find_sessions",
    "read_table",
    "run_fleet",
    "session_task",
]

CAL_DIR = "cal"


# ------------------------------------------------------------------------------------------ inputs
# (session globs and safe path parts: accellog.flows.fleet_inputs)


def pipeline_hash(spec: dict) -> str:
    """SHA-256 of the pipeline spec (canonical JSON, without its path) and the accellog version."""
    body = {k: v for k, v in spec.items() if k != "_path"}
    text = json.dumps({"pipeline": body, "accellog": __version__}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


# ------------------------------------------------------------------------------------------ one task


def _heldout(fo) -> tuple[float, float]:
    """Held-out residual RMS and noise floor (g): refit on every other window of each hold, score
    on the windows left out (same session; see calibrate.diagnose.heldout_stats)."""
    from accellog.calibrate.diagnosis.diagnose import heldout_stats
    from accellog.calibrate.model.fit import fit_model
    from accellog.core.session import ObsTable

    obs = fo.obs
    if fo.fit.method != "labelled":  # orientation-free fits have no labelled truth to score against
        return float("nan"), float("nan")
    rank = np.zeros(obs.n, int)
    for p in np.unique(obs.pose_id):
        idx = np.flatnonzero(obs.pose_id == p)
        rank[idx] = np.arange(idx.size)
    test = rank % 2 == 1
    if test.sum() < 1 or (~test).sum() * 3 <= fo.fit.model.n_params:
        return float("nan"), float("nan")

    def take(mask: np.ndarray) -> ObsTable:
        kw = {}
        for name, v in vars(obs).items():
            kw[name] = v[mask] if isinstance(v, np.ndarray) and v.shape[:1] == (obs.n,) else v
        return ObsTable(**kw)

    try:
        res = fit_model(take(~test), fo.fit.model, weighted=fo.fit.weighted, gravity_g=fo.fit.gravity_g)
        st = heldout_stats(res, take(test))
    except AccellogError:
        return float("nan"), float("nan")
    return st["heldout_rms_g"], st["heldout_noise_g"]


def _device_columns(meta) -> dict[str, Any]:
    key = meta.device
    return {
        "device": key.id,
        "serial": key.serial,
        "who_am_i": key.who_am_i,
        "ak8963_wia": key.ak8963_wia,
        "i2c_bus": key.i2c_bus,
        "i2c_address": key.i2c_address,
        "host": key.host,
    }


def session_task(path: str, content_sha256: str, spec: dict, pipe_sha256: str) -> dict[str, Any]:
    """Run the pipeline on one session; returns {'rows': [...], 'cals': {model: dict}} (small).

    Never raises for bad input: an AccellogError (or any exception) becomes one error row."""
    from accellog.flows.pipeline import run_pipeline
    from accellog.flows.stages import load_input

    pin_blas()
    t0, c0 = time.perf_counter(), time.process_time()
    base = {
        "session": str(path),
        "session_name": Path(path).stem,
        "content_sha256": content_sha256,
        "pipeline": spec["pipeline"]["name"],
        "pipeline_sha256": pipe_sha256,
        "worker_pid": os.getpid(),
    }
    try:
        data = load_input(path)
        if not hasattr(data, "meta"):
            raise InputError("fleet run needs recorded sessions (samples), not pose tables", where=path)
        meta = data.meta
        base.update(_device_columns(meta))
        base.update(
            start_time_unix_ns=int(meta.start_time_unix_ns),
            n_samples=int(data.n),
            duration_s=float(data.t_s[-1] - data.t_s[0]) if data.n else 0.0,
            lost_samples=int(data.lost_samples()),
            temp_mean_degC=float(np.mean(data.temp_degC)) if data.temp_degC is not None else float("nan"),
        )
        roles = spec["pipeline"]["inputs"]
        spec_run = {**spec, "report": {k: v for k, v in spec.get("report", {}).items() if k != "output_dir"}}
        res = run_pipeline(spec_run, [path] * len(roles), preloaded={str(path): data})
    except Exception as exc:  # one bad file = one error row, never a stopped fleet
        msg = str(exc) if isinstance(exc, AccellogError) else f"{type(exc).__name__}: {exc}"
        row = {**base, "model": "", "error": msg.splitlines()[0] if msg else type(exc).__name__}
        row["task_s"], row["task_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
        return {"rows": [row], "cals": {}}
    rows, cals = [], {}
    for mname, fo in res.fits.items():
        ho_rms, ho_noise = _heldout(fo)
        flags = list(fo.fit.warnings)
        if base.get("lost_samples"):
            flags.append(f"{base['lost_samples']} lost samples")
        rows.append(
            {
                **base,
                "model": mname,
                "param_names": list(fo.cal.param_names),
                "param_units": list(fo.cal.param_units),
                "values": [float(v) for v in fo.cal.theta],
                "sigmas": [float(v) for v in fo.cal.sigma],
                "chi2_dof": float(fo.fit.chi2_dof),
                "rms_g": float(fo.fit.rms_g),
                "heldout_rms_g": ho_rms,
                "heldout_noise_g": ho_noise,
                "noise_std_g": [float(v) for v in np.mean(fo.obs.std_g, axis=0)],
                "n_obs": int(fo.obs.n),
                "flags": flags,
                "error": "",
            }
        )
        cals[mname] = fo.cal.to_dict()
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    for r in rows:
        r["task_s"], r["task_cpu_s"] = dt, dc
    return {"rows": rows, "cals": cals}


# ------------------------------------------------------------------------------------------ the run


@dataclass
class FleetRunResult:
    """Outcome of run_fleet: counts, errors (session, message), timing and where things went."""

    out_dir: str
    table: str
    pipeline: str
    n_sessions: int
    n_run: int
    n_skipped: int
    errors: list[tuple[str, str]] = field(default_factory=list)
    n_rows: int = 0
    cal_files: int = 0
    scheduler: str = ""
    n_workers: int = 0
    wall_s: float = 0.0
    """Client wall time of the task phase (submit to last result), s."""
    sum_task_s: float = 0.0
    """Sum of the tasks' own run times on the workers, s."""
    sum_task_cpu_s: float = 0.0
    """Sum of the tasks' CPU times (process_time) on the workers, s (insensitive to other load)."""

    @property
    def tasks_per_s(self) -> float:
        return self.n_run / self.wall_s if self.wall_s > 0 else float("nan")

    @property
    def overhead_fraction(self) -> float:
        """(workers x wall - sum of task times) / sum of task times: scheduling, transfer and idle
        time per unit of useful work (an upper bound on the scheduler's share)."""
        if self.sum_task_s <= 0:
            return float("nan")
        return (max(self.n_workers, 1) * self.wall_s - self.sum_task_s) / self.sum_task_s

    def to_dict(self) -> dict[str, Any]:
        return {
            "out_dir": self.out_dir,
            "table": self.table,
            "pipeline": self.pipeline,
            "n_sessions": self.n_sessions,
            "n_run": self.n_run,
            "n_skipped": self.n_skipped,
            "n_errors": len(self.errors),
            "errors": [{"session": s, "error": e} for s, e in self.errors],
            "n_rows": self.n_rows,
            "cal_files": self.cal_files,
            "scheduler": self.scheduler,
            "n_workers": self.n_workers,
            "wall_s": self.wall_s,
            "sum_task_s": self.sum_task_s,
            "sum_task_cpu_s": self.sum_task_cpu_s,
            "tasks_per_s": self.tasks_per_s,
            "overhead_fraction": self.overhead_fraction,
        }

    def to_json(self) -> str:
        from accellog.core.jsonio import dumps

        return dumps(self.to_dict())


Progress = Callable[[int, int, dict[str, Any]], None]
"""on_progress(done, total, task_result): once before the first task (0, total, {}), then after each."""


WORKER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.admin.system-monitor.gil.enabled": False,
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": 1 << 30,
}
"""Dask settings of local workers: no statistical profiler (a thread sampling the task thread's
stack every 10 ms), a slower system monitor, and glibc's malloc trim threshold raised from Dask's
64 KiB to 1 GiB: with Dask's value every freed numpy array went back to the kernel and came back as
page faults, which doubled the CPU time of a task (172 vs 92 ms; 2 workers ran at 0.94x the serial
loop, 1.78x with this setting, benchmarks/bench_fleet.py). On a real cluster set the same keys in the
workers' dask config (docs/fleet.md)."""


def local_cluster(n_workers: int | None = None):
    """A dask LocalCluster on 127.0.0.1: n_workers single-threaded processes (default: cores),
    no dashboard, WORKER_CONFIG."""
    import logging

    import dask
    from dask.distributed import LocalCluster

    n = n_workers or os.cpu_count() or 1
    with dask.config.set(WORKER_CONFIG):
        return LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",  # Dask's HTTP endpoints on a free local port
            silence_logs=logging.ERROR,
        )


def _n_workers(dask_scheduler) -> int:
    return len(dask_scheduler.workers)


def _close_own(client) -> None:
    """Close a client and the cluster accellog started for it, workers first: a worker whose
    scheduler went first logged 'Failed to communicate with scheduler during heartbeat' with a
    traceback on stderr after a successful run."""
    cluster = client.cluster
    if cluster is not None:
        try:
            cluster.scale(0)  # the nannies stop their workers while the scheduler still answers
            end = time.monotonic() + 30.0
            while client.run_on_scheduler(_n_workers) and time.monotonic() < end:
                time.sleep(0.05)
        except Exception:  # a cluster that is already going away: closing below is enough
            pass
    client.close()
    if cluster is not None:
        cluster.close()


_PINNED = False


def pin_blas() -> None:
    """BLAS on one thread in this process, once, wherever the worker was started (a `dask worker` of an
    external cluster does not get the OPENBLAS_NUM_THREADS=1 accellog gives the workers it starts:
    each task's small matrices then cost 1.6x the CPU on threads fighting for the cores)."""
    global _PINNED
    if not _PINNED:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1, user_api="blas")  # kept for the life of the process
        _PINNED = True


def warm_worker() -> int:
    """Import what a task needs and pin BLAS to one thread (run once on each worker before timing);
    returns the pid."""
    pin_blas()
    import accellog.calibrate.diagnosis.diagnose
    import accellog.calibrate.gyro.calibrate
    import accellog.calibrate.model.fit
    import accellog.flows.pipeline
    import accellog.store.reader  # noqa: F401

    return os.getpid()


def _run_serial(todo, hashes, spec, ph, on_progress) -> list[dict]:
    out = []
    for k, path in enumerate(todo):
        r = session_task(path, hashes[path], spec, ph)
        out.append(r)
        if on_progress:
            on_progress(k + 1, len(todo), r)
    return out


def _run_dask(client, todo, hashes, spec, ph, on_progress) -> list[dict]:
    from dask.distributed import as_completed

    [spec_f] = client.scatter([spec], broadcast=True)
    futs = client.map(session_task, todo, [hashes[p] for p in todo], spec=spec_f, pipe_sha256=ph, pure=False)
    out = []
    # the task function catches its own errors; a lost worker still surfaces here as an error row
    for k, fut in enumerate(as_completed(futs)):
        try:
            r = fut.result()
        except Exception as exc:
            path = todo[futs.index(fut)]
            r = {
                "rows": [{"session": path, "model": "", "error": f"task failed: {type(exc).__name__}: {exc}"}]
            }
            r["cals"] = {}
        out.append(r)
        fut.release()
        if on_progress:
            on_progress(k + 1, len(todo), r)
    return out


def run_fleet(
    pipeline: str | os.PathLike | dict,
    sessions: str | Sequence[str],
    out_dir: str | os.PathLike,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    client: Any = None,
    force: bool = False,
    on_progress: Progress | None = None,
) -> FleetRunResult:
    """Run `pipeline` on every session (a glob or a list of files) and update OUT/fleet.parquet.

    Execution: `client` (an existing dask Client), else `scheduler` ('tcp://HOST:8786'), else a
    LocalCluster of `workers` processes (default: cores); workers=0 runs the serial loop in this
    process (the baseline of the benchmark)."""
    from accellog.flows.pipeline import load_pipeline

    spec = pipeline if isinstance(pipeline, dict) else load_pipeline(pipeline)
    ph = pipeline_hash(spec)
    files = find_sessions(sessions) if isinstance(sessions, str) else unique_files(sessions)
    out = Path(out_dir)
    table_path = out / TABLE_NAME
    prev = read_table(table_path) if table_path.exists() else []
    hashes = {p: sha256_file(p) or "" for p in files}
    done = {(r["session"], r["content_sha256"], r["pipeline_sha256"]) for r in prev}
    todo = [p for p in files if force or (p, hashes[p], ph) not in done]
    res = FleetRunResult(
        out_dir=str(out),
        table=str(table_path),
        pipeline=spec["pipeline"]["name"],
        n_sessions=len(files),
        n_run=len(todo),
        n_skipped=len(files) - len(todo),
    )
    if on_progress:
        on_progress(0, len(todo), {})  # the total is known before the first task ends (no "0/?")
    t0 = time.perf_counter()
    if not todo:
        results: list[dict] = []
    elif client is not None or (workers != 0):
        own = None
        if client is None:
            from dask.distributed import Client

            own = Client(scheduler) if scheduler else Client(local_cluster(workers))
            client = own
        try:
            res.scheduler = client.scheduler.address
            res.n_workers = len(client.scheduler_info()["workers"])
            client.run(warm_worker)  # imports (scipy, ...) once per worker, outside the timed phase
            t0 = time.perf_counter()
            results = _run_dask(client, todo, hashes, spec, ph, on_progress)
        finally:
            if own is not None:
                _close_own(own)
    else:
        res.scheduler, res.n_workers = "serial", 1
        warm_worker()
        t0 = time.perf_counter()
        results = _run_serial(todo, hashes, spec, ph, on_progress)
    res.wall_s = time.perf_counter() - t0 if todo else 0.0
    new_rows = _store_results(out, results)
    res.sum_task_s = float(sum(r["rows"][0].get("task_s") or 0.0 for r in results))
    res.sum_task_cpu_s = float(sum(r["rows"][0].get("task_cpu_s") or 0.0 for r in results))
    res.cal_files = sum(1 for r in new_rows if r.get("calibration"))
    redone = set(todo)
    rows = [r for r in prev if r["session"] not in redone] + new_rows
    rows.sort(
        key=lambda r: (r.get("device") or "", r.get("start_time_unix_ns") or 0, r["session"], r["model"])
    )
    write_table(table_path, rows)
    res.n_rows = len(rows)
    res.errors = sorted({(r["session"], r["error"]) for r in new_rows if r.get("error")})
    return res


def _store_results(out: Path, results: list[dict]) -> list[dict]:
    """Write each calibration JSON under OUT/cal/<device>/ and return the rows pointing to them."""
    rows = []
    for r in results:
        for row in r["rows"]:
            cal = r["cals"].get(row.get("model"))
            if cal is not None:
                rel = (
                    Path(CAL_DIR)
                    / safe_part(row["device"])
                    / (
                        f"{safe_part(row['session_name'])}_{row['content_sha256'][:8]}_{safe_part(row['model'])}.json"
                    )
                )
                write_json_atomic(out / rel, cal)
                row["calibration"] = str(rel)
            rows.append(row)
    return rows
