"""What a fleet run writes under FLEET/: the table fleet.parquet (its Arrow schema, atomic writing and
validated reading) and the calibration files cal/<device>/<session>_<sha8>_<model>.json the rows
point to (written by the client's writer threads, or staged by a worker and committed per batch).

One row per (session, model) of a fleet run, or one error row per session that could not be
calibrated (see accellog.flows.fleet and docs/fleet.md for the columns).
"""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Any

from accellog.core.errors import InputError
from accellog.core.jsonio import dumps
from accellog.flows.fleet_inputs import safe_part
from accellog.store.atomic import AtomicOutput, LockBusy, commit_all, write_text_atomic

TABLE_NAME = "fleet.parquet"
CAL_DIR = "cal"


def table_schema():
    """Arrow schema of fleet.parquet: one row per (session, model), or one error row per session."""
    import pyarrow as pa

    s, i, f = pa.string(), pa.int64(), pa.float64()
    return pa.schema(
        [
            ("device", s),
            ("serial", s),
            ("who_am_i", i),
            ("ak8963_wia", i),
            ("i2c_bus", s),
            ("i2c_address", i),
            ("host", s),
            ("session", s),
            ("session_name", s),
            ("content_sha256", s),
            ("pipeline", s),
            ("pipeline_sha256", s),
            ("time", pa.timestamp("ns", tz="UTC")),
            ("start_time_unix_ns", i),
            ("model", s),
            ("param_names", pa.list_(s)),
            ("param_units", pa.list_(s)),
            ("values", pa.list_(f)),
            ("sigmas", pa.list_(f)),
            ("chi2_dof", f),
            ("rms_g", f),
            ("heldout_rms_g", f),
            ("heldout_noise_g", f),
            ("noise_std_g", pa.list_(f)),
            ("n_obs", i),
            ("n_samples", i),
            ("duration_s", f),
            ("lost_samples", i),
            ("temp_mean_degC", f),
            ("flags", pa.list_(s)),
            ("error", s),
            ("calibration", s),
            ("field", pa.bool_()),
            ("prior_calibration", s),
            ("task_s", f),
            ("task_cpu_s", f),
            ("worker_pid", i),
        ]
    )


def read_table(path: str | os.PathLike) -> list[dict[str, Any]]:
    """Rows of a fleet.parquet (InputError naming the file when it is not one)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        t = pq.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        raise InputError(f"not a readable fleet table: {str(exc).splitlines()[0]}", where=str(path)) from None
    missing = {"device", "session", "model", "values", "sigmas", "error"} - set(t.column_names)
    if missing:
        raise InputError(f"not a fleet table (missing columns {sorted(missing)})", where=str(path))
    rows = t.drop_columns(["time"]).to_pylist() if "time" in t.column_names else t.to_pylist()
    return rows


def write_table(path: str | os.PathLike, rows: list[dict[str, Any]]) -> None:
    """Write rows as Parquet atomically (temp file beside it + rename)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    for r in rows:
        r["time"] = r.get("start_time_unix_ns")
    table = pa.Table.from_pylist(rows, schema=table_schema())
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    try:
        pq.write_table(table, tmp, compression="zstd")
        os.replace(tmp, p)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def cal_name(row: dict) -> Path:
    """OUT-relative name of a row's calibration file: cal/<device>/<session>_<sha8>_<model>.json."""
    name = f"{safe_part(row['session_name'])}_{row['content_sha256'][:8]}_{safe_part(row['model'])}.json"
    return Path(CAL_DIR) / safe_part(row["device"]) / name


def store_results(out: Path, results: list[dict], path_locks: dict[Path, threading.Lock]) -> list[dict]:
    """Write each calibration JSON under OUT/cal/<device>/ (the client's writer threads) and return
    the rows pointing to them. path_locks: one lock per file name, shared by the writer threads: two
    sessions whose files have one name (byte-identical copies in two folders) are written one after
    the other, the later replacing the earlier as in a serial run, instead of the second failing on
    the first's lock."""
    rows = []
    for r in results:
        for row in r["rows"]:
            cal = r["cals"].get(row.get("model"))
            if cal is not None:
                rel = cal_name(row)
                text = cal if isinstance(cal, str) else dumps(cal) + "\n"  # str: encoded by a worker
                with path_locks.setdefault(rel, threading.Lock()):
                    write_text_atomic(out / rel, text, mkdir=True)
                row["calibration"] = str(rel)
            rows.append(row)
    return rows


def stage_result(out: Path, r: dict, staged: dict[Path, AtomicOutput]) -> list[dict]:
    """A worker's storing of one session's calibrations: each file begun (locked) and written under
    its temporary name; returns the rows pointing to them. ``commit_all(staged)`` at the end of the
    batch makes them durable and visible together. A name another worker is writing (two copies of
    one session) is waited for, but only after this batch's staged files are committed (their locks
    released): a worker never waits holding a lock, so two workers cannot wait for each other."""
    rows = []
    for row in r["rows"]:
        cal = r["cals"].get(row.get("model"))
        if cal is not None:
            rel = cal_name(row)
            ao = AtomicOutput(out / rel, mkdir=True)
            try:
                if rel in staged:
                    raise LockBusy("staged in this batch", where=str(rel))
                tmp = ao.begin()
            except LockBusy:
                commit_all(list(staged.values()))
                staged.clear()
                ao = AtomicOutput(out / rel, mkdir=True, wait=True)
                tmp = ao.begin()
            staged[rel] = ao
            tmp.write_text(dumps(cal) + "\n")
            row["calibration"] = str(rel)
        rows.append(row)
    return rows
