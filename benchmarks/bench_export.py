"""The CSV rows of `accellog integrate` (t_s, vx, vy, vz, x, y, z: 7 float64 columns, one row per
sample) written three ways: core.numfmt.format_rows (the command's), np.savetxt(fmt="%.9g",
delimiter=",") and pyarrow.csv.write_csv (no header, no quotes). Reported per writer: CPU time (user +
sys of this process, all threads), wall time, bytes written, and whether the bytes are numfmt's, byte
for byte (the file format), else the first row that differs. Writers write into memory: the
formatting alone, no disk.

Input: the integrated rows of a static 1 kHz session, by default one hour synthesized with
benchmarks/synth_static.py in a temporary directory (or --session FILE, a static session).

    python benchmarks/bench_export.py [--hours 1] [--session FILE] [--repeat 3]
"""

from __future__ import annotations

import argparse
import io
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def integrated_rows(session: Path) -> np.ndarray:
    """(n, 7) t_s, v (m/s), d (m) of a static session, raw reading: what `integrate -o` writes."""
    from accellog.flows.stages import run_integrate

    res = run_integrate(session)
    ev = res.evaluation
    return np.column_stack([ev.t_s, res.velocity_mps, ev.disp_series_m])


def with_numfmt(a: np.ndarray) -> bytes:
    from accellog.core.numfmt import format_rows

    return format_rows(a)


def with_savetxt(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.savetxt(buf, a, fmt="%.9g", delimiter=",")
    return buf.getvalue()


def with_pyarrow(a: np.ndarray) -> bytes:
    import pyarrow as pa
    import pyarrow.csv as pacsv

    table = pa.table({f"c{j}": a[:, j] for j in range(a.shape[1])})
    sink = pa.BufferOutputStream()
    pacsv.write_csv(table, sink, pacsv.WriteOptions(include_header=False, quoting_style="none"))
    return sink.getvalue().to_pybytes()


WRITERS: dict[str, Callable[[np.ndarray], bytes]] = {
    "core.numfmt.format_rows": with_numfmt,
    'np.savetxt(fmt="%.9g")': with_savetxt,
    "pyarrow.csv.write_csv": with_pyarrow,
}


def timed(write: Callable[[np.ndarray], bytes], a: np.ndarray, repeat: int) -> tuple[float, float, bytes]:
    """Median CPU and wall time (s) of `repeat` runs, and the bytes of the last."""
    cpu, wall = [], []
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        out = write(a)
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return statistics.median(cpu), statistics.median(wall), out


def first_difference(got: bytes, want: bytes) -> str:
    g, w = got.split(b"\n"), want.split(b"\n")
    i = next((i for i in range(max(len(g), len(w))) if i >= len(g) or i >= len(w) or g[i] != w[i]), None)
    if i is None:
        return "same bytes"
    show = lambda rows: rows[i].decode() if i < len(rows) else "(none)"  # noqa: E731
    return f"row {i}: {show(g)}  vs numfmt  {show(w)}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0, help="length of the synthesized session")
    ap.add_argument("--session", type=Path, help="a static session instead of a synthesized one")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    load = os.getloadavg()
    print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        session = a.session
        if session is None:
            from synth_static import write_static

            session = write_static(Path(tmp) / "static.mcap", a.hours * 3600.0)
        rows = integrated_rows(session)
    hours = rows.shape[0] / 1000.0 / 3600.0
    print(f"{rows.shape[0]} rows x {rows.shape[1]} columns ({hours:.2f} h at 1 kHz), median of {a.repeat}")
    print(f"{'writer':<26} {'CPU s':>7} {'wall s':>7} {'x numfmt CPU':>13} {'MB':>7}  bytes")
    ref, ref_cpu = None, None
    for name, write in WRITERS.items():
        cpu, wall, out = timed(write, rows, a.repeat)
        ref, ref_cpu = (out, cpu) if ref is None else (ref, ref_cpu)
        same = first_difference(out, ref)
        print(f"{name:<26} {cpu:7.2f} {wall:7.2f} {cpu / ref_cpu:13.2f} {len(out) / 1e6:7.1f}  {same}")


if __name__ == "__main__":
    main()
