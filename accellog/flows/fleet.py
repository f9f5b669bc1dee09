"""Fleet run: one pipeline applied to many sessions as independent tasks on Dask (dask.distributed).

    accellog fleet run PIPELINE.toml 'SESSIONS/**/*.mcap' -o FLEET/

Each session is one call of ``session_task``: the worker reads the file with accellog's reader
(fastread for finished files), runs the pipeline with every input role bound to that file, and
returns a few rows (one per model: parameters +- 1 sigma, chi2/dof, held-out RMS, noise) plus the
calibration dicts: a few kB, never samples. A Dask task runs a batch of sessions
(``session_batch``; batch sizes: accellog.flows.fleet_dask.batches). A file that cannot be read or
fitted becomes one error row with its one-line message. The workers of a local cluster (and the
serial loop, which runs the workers' code) write FLEET/cal/<device>/<session>_<model>.json
themselves, a batch at a time; for a remote cluster the client writes them as each result arrives,
unless told that FLEET/ is shared (``workers_write``). FLEET/fleet.parquet is written atomically
(temp + rename) at the end.

Re-runs: a session whose content SHA-256 and pipeline hash (pipeline spec + accellog version) are
already in fleet.parquet is skipped (its rows are kept); ``force`` recomputes everything.

Cluster: a LocalCluster bound to 127.0.0.1 (one single-threaded worker process per core) unless
a scheduler address (tcp://HOST:8786) is given; the input paths must then be readable by the
workers under the same names (shared filesystem). Dask is imported only in
accellog.flows.fleet_dask and in accellog.flows.fleet_worker (what the fork server of local workers
imports before it forks them).
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from accellog.calibrate.calfile.calibration import sha256_file
from accellog.core.errors import AccellogError, InputError
from accellog.core.jsonio import dumps
from accellog.core.session import Session
from accellog.core.version import __version__
from accellog.flows.fleet_dask import batches, close_own, is_local, run_batches, start_client
from accellog.flows.fleet_field import field_priors, field_result, lab_calibrations, stale_field_sessions
from accellog.flows.fleet_inputs import find_sessions, unique_files
from accellog.flows.fleet_table import (
    CAL_DIR,
    TABLE_NAME,
    read_table,
    stage_result,
    store_results,
    write_table,
)
from accellog.store.atomic import AtomicOutput, commit_all, folder_output

__all__ = [
    "CAL_DIR",
    "TABLE_NAME",
    "FleetRunResult",
    "find_sessions",
    "read_table",
    "run_fleet",
    "session_task",
]

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
    on the windows left out (same session; see calibrate.diagnosis.transfer.predictive_stats)."""
    from accellog.calibrate.diagnosis.transfer import predictive_stats
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
        st = predictive_stats(res, take(test), norm=False)
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


def session_task(path: str, content_sha256: str | None, spec: dict, pipe_sha256: str) -> dict[str, Any]:
    """Run the pipeline on one session; returns {'rows': [...], 'cals': {model: dict}} (small).
    `content_sha256` None: the task hashes the file itself (a run where every session runs: the
    worker reads the file anyway, the client does not read it first).

    Never raises for bad input: an AccellogError (or any exception) becomes one error row."""
    from accellog.flows.pipeline import run_pipeline
    from accellog.flows.stages import load_input

    pin_blas()
    t0, c0 = time.perf_counter(), time.process_time()
    if content_sha256 is None:
        content_sha256 = sha256_file(path) or ""
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
        if not isinstance(data, Session):
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
        if not data.poses:  # a field session: it updates the device's calibration (fleet_field)
            r = field_result(data, base, spec.get("field_priors", {}))
            r["rows"][0]["task_s"], r["rows"][0]["task_cpu_s"] = (
                time.perf_counter() - t0,
                time.process_time() - c0,
            )
            return r
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
        return dumps(self.to_dict())


Progress = Callable[[int, int, dict[str, Any]], None]
"""on_progress(done, total, task_result): once before the first task (0, total, {}), then after each."""


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
    returns the pid. scipy.optimize (imported lazily by the first fit) is half of it: 0.15 s of CPU
    that the first task of every worker paid before."""
    pin_blas()
    import accellog.calibrate.diagnosis.diagnose
    import accellog.calibrate.gyro.calibrate
    import accellog.calibrate.model.fit
    import accellog.calibrate.model.variance
    import accellog.flows.pipeline
    import accellog.store.reader  # noqa: F401
    from accellog.core.numeric import load_solver

    load_solver()
    return os.getpid()


def session_batch(
    paths: Sequence[str],
    hashes: Sequence[str | None],
    spec: dict,
    pipe_sha256: str,
    out_dir: str | None = None,
) -> list[dict]:
    """``session_task`` on each session of a batch, in order (one Dask task). With `out_dir` (the fleet
    folder, on a filesystem the client shares) the worker writes each calibration file itself and
    returns the rows pointing to them ("stored": True); else the calibrations come back as the JSON
    text of their files, for the client to write. Either way the client's work per session, which
    bounds how many workers it keeps busy, stays small (docs/fleet.md, Scaling model)."""
    out, staged = [], dict[Path, AtomicOutput]()
    try:
        for p, h in zip(paths, hashes, strict=True):
            r = session_task(p, h, spec, pipe_sha256)
            if out_dir is not None:
                out.append({"rows": stage_result(Path(out_dir), r, staged), "cals": {}, "stored": True})
            else:
                out.append({**r, "cals": {m: dumps(c) + "\n" for m, c in r["cals"].items()}})
        commit_all(list(staged.values()))
    except BaseException:
        for ao in staged.values():
            ao.abort()
        raise
    return out


def _run_serial(todo, hashes, spec, ph, out: Path, on_result) -> None:
    """The serial loop (workers=0): the batches a single worker would get, run here by the workers'
    own code, storing as a worker does (one folder sync per batch, no writer threads)."""
    sizes = [os.path.getsize(p) if os.path.isfile(p) else 0 for p in todo]
    for part in batches(sizes, 1):
        paths = todo[part.start : part.stop]
        for r in session_batch(paths, [hashes[p] for p in paths], spec, ph, str(out.absolute())):
            on_result(r)


def run_fleet(
    pipeline: str | os.PathLike | dict,
    sessions: str | Sequence[str],
    out_dir: str | os.PathLike,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    client: Any = None,
    force: bool = False,
    workers_write: bool | None = None,
    on_progress: Progress | None = None,
) -> FleetRunResult:
    """Run `pipeline` on every session (a glob or a list of files) and update OUT/fleet.parquet.

    Execution: `client` (an existing dask Client), else `scheduler` ('tcp://HOST:8786'), else a
    LocalCluster of `workers` processes (default: cores); workers=0 runs the serial loop in this
    process (the baseline of the benchmark). workers_write: the workers write the calibration files
    under OUT themselves (OUT must be on a filesystem they share under the same path); default: with
    a local cluster only, else the client writes them."""
    with folder_output(out_dir, create=False):  # an OUT made by this run goes if it fails (a full disk)
        return _run_fleet(pipeline, sessions, Path(out_dir), scheduler, workers, client, force,
                          workers_write, on_progress)  # fmt: skip


def _run_fleet(pipeline, sessions, out: Path, scheduler, workers, client, force, workers_write, on_progress):
    from accellog.flows.pipeline import load_pipeline

    spec = pipeline if isinstance(pipeline, dict) else load_pipeline(pipeline)
    ph = pipeline_hash(spec)
    files = find_sessions(sessions) if isinstance(sessions, str) else unique_files(sessions)
    table_path = out / TABLE_NAME
    need = client is None and workers != 0  # a client to make: of `scheduler`, else a local cluster
    local = need and not scheduler
    # every session will run: start the local cluster now (its workers import meanwhile)
    early = local and files and (force or not table_path.exists())
    starting = start_client(None, workers) if early else None
    own = None
    try:
        prev = read_table(table_path) if table_path.exists() else []
        if prev and not force:  # the content hashes decide what runs
            hashes: dict[str, str | None] = {p: sha256_file(p) or "" for p in files}
            done = {(r["session"], r["content_sha256"], r["pipeline_sha256"]) for r in prev}
            todo = [p for p in files if (p, hashes[p], ph) not in done]
        else:  # everything runs: each task hashes its file (read there anyway)
            hashes, todo = dict.fromkeys(files), list(files)
        if on_progress:
            on_progress(0, len(todo), {})  # the total, before the cluster start (no "0/?" meanwhile)
        if todo and need:
            own = client = (starting or start_client(scheduler, workers)).result()
        res = FleetRunResult(
            out_dir=str(out),
            table=str(table_path),
            pipeline=spec["pipeline"]["name"],
            n_sessions=len(files),
            n_run=len(todo),
            n_skipped=len(files) - len(todo),
        )
        if workers_write is None:
            workers_write = client is not None and is_local(client)
        new_rows, sums = _run(res, client, out, todo, hashes, spec, ph, on_progress, workers_write)
        new_rows = _field_pass(res, client, out, prev, new_rows, spec, ph, on_progress, workers_write, sums)
    finally:
        if own is None and starting is not None and starting.exception() is None:
            own = starting.result()  # started for sessions that did not run (an error above)
        if own is not None:
            close_own(own)
    res.sum_task_s, res.sum_task_cpu_s = float(sums[0]), float(sums[1])
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


def _field_pass(
    res, client, out: Path, prev, new_rows, spec, ph, on_progress, workers_write, sums
) -> list[dict]:
    """The second pass (accellog.flows.fleet_field): the field sessions whose rows did not update their
    device's latest lab calibration, run with it; returns the new rows with theirs replaced."""
    redone = {r["session"] for r in new_rows}
    rows = [r for r in prev if r["session"] not in redone] + new_rows
    labs = lab_calibrations(rows)
    todo = stale_field_sessions(rows, labs)
    if not todo:
        return new_rows
    again = [r for r in rows if r["session"] in set(todo)]
    spec2 = {**spec, "field_priors": field_priors(again, labs, out)}
    hashes = {r["session"]: r["content_sha256"] for r in again}
    wall = res.wall_s
    rows2, sums2 = _run(res, client, out, todo, hashes, spec2, ph, on_progress, workers_write)
    res.wall_s += wall
    sums[0], sums[1] = sums[0] + sums2[0], sums[1] + sums2[1]
    res.n_run += len(set(todo) - redone)
    res.n_skipped -= len(set(todo) - redone)
    return [r for r in new_rows if r["session"] not in set(todo)] + rows2


def _run(res: FleetRunResult, client, out: Path, todo, hashes, spec, ph, on_progress, workers_write=False):
    """The task phase: `todo` on `client` (None: the serial loop here); each result is stored as it
    arrives, by the workers (workers_write) or by WRITERS threads here. Returns (new table rows, [sum
    of task wall s, sum of task CPU s, sessions done]); the task phase's wall time (to the last result
    stored, s) goes to res.wall_s."""
    from concurrent.futures import Future, ThreadPoolExecutor

    stored: list = []  # the rows of each stored result, or the future of a writer storing it
    path_locks: dict[Path, threading.Lock] = {}  # two sessions with one file name are written in turn
    sums = [0.0, 0.0, 0]

    def on_result(r: dict) -> None:
        """Hand one session's result to the writers (its calibration files are written while the
        tasks go on) unless a worker wrote them, and count it."""
        stored.append(r["rows"] if r.get("stored") else writers.submit(store_results, out, [r], path_locks))
        sums[0] += r["rows"][0].get("task_s") or 0.0
        sums[1] += r["rows"][0].get("task_cpu_s") or 0.0
        sums[2] += 1
        if on_progress:
            on_progress(sums[2], len(todo), r)

    with ThreadPoolExecutor(WRITERS, thread_name_prefix="fleet-write") as writers:
        if todo and client is not None:
            res.scheduler = client.scheduler.address
            res.n_workers = len(client.scheduler_info()["workers"])
            client.run(warm_worker)  # imports (scipy, ...) once per worker, outside the timed phase
            t0 = time.perf_counter()
            args = (spec, ph, str(out.absolute()) if workers_write else None)
            run_batches(client, session_batch, todo, [hashes[p] for p in todo], args, on_result)
        elif todo:
            res.scheduler, res.n_workers = "serial", 1
            warm_worker()
            t0 = time.perf_counter()
            _run_serial(todo, hashes, spec, ph, out, on_result)
    if todo:
        res.wall_s = time.perf_counter() - t0
    return [row for f in stored for row in (f.result() if isinstance(f, Future) else f)], sums


WRITERS = 8
"""Threads writing calibration files in the client, when it stores them (a remote cluster without
--workers-write). Each file is written atomically with two fsyncs (accellog.store.atomic): one
after another they took 12-15 ms of wall time per session on the 2-core test host (2 ms of CPU),
more than a task; 8 writers bring it to 1.8 ms."""
