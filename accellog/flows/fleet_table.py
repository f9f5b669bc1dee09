"""The fleet table FLEET/fleet.parquet: its Arrow schema, atomic writing and validated reading.

One row per (session, model) of a fleet run, or one error row per session that could not be
calibrated (see accellog.flows.fleet and docs/fleet.md for the columns).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from accellog.core.errors import InputError

TABLE_NAME = "fleet.parquet"


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
