"""Hostile inputs cost what a tiny valid input costs (issue 27, item 3): CPU time and peak memory.

Each row runs one `accellog` command in a fresh process on a hostile input and reports its CPU
time (user + sys, os.wait4) and peak RSS (the child's own VmHWM), beside the baseline of the
same run: `accellog segment` on the 300 KB head of a recording cut short (read, salvage, refuse).
The ratio is hostile / baseline CPU time; the goal is <= 2x for every input refused before it is
parsed (no per-byte scan, nothing read whole), and peak memory <= 500 MB for all, including a JSON
input at its size limit (which is parsed). Big inputs are sparse files (zeros cost no disk).

    python benchmarks/bench_hostile_input.py [--repeat 3] [--dir /tmp/accellog_hostile]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

GB = 1024**3
MIB = 1024**2


def _sparse(path: Path, size: int, head: bytes = b"") -> Path:
    with path.open("wb") as f:
        f.write(head)
        f.truncate(size)
    return path


def make_inputs(d: Path) -> dict[str, Path]:
    from support.sessions import synth_session

    from accellog.store.writer import write_session

    d.mkdir(parents=True, exist_ok=True)
    s = synth_session(seed=3, hold_s=20.0, move_s=1.0, rate_hz=200.0)
    data = write_session(d / "full.mcap", s, chunk_size=64 * 1024).read_bytes()
    head = data[: len(data) * 2 // 3]
    (d / "cut.mcap").write_bytes(head)
    return {
        "cut": d / "cut.mcap",
        "zeros20": _sparse(d / "zeros20.mcap", len(head) + 20 * MIB, head),
        "zeros2g": _sparse(d / "zeros2g.mcap", len(head) + 2 * GB, head),
        "nulcsv": _sparse(d / "nul.csv", 2 * GB),
        "bigjson": _sparse(d / "big.json", 2 * GB, b"{"),
        "deepjson": _write(d / "deep.json", "[" * 200_000 + "]" * 200_000),
        "bigtoml": _sparse(d / "big.toml", 2 * GB),
        "floats32": _write(d / "floats.json", "[" + "1.5," * ((32 * MIB - 5) // 4) + "1.5]"),
    }


def _write(p: Path, text: str) -> Path:
    p.write_text(text)
    return p


_CHILD = (
    "import atexit, sys\n"
    "def hwm():\n"
    "    kb = [l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM')][0]\n"
    "    open(sys.argv[1], 'w').write(kb)\n"
    "atexit.register(hwm)\n"
    "from accellog.cli import main\n"
    "sys.exit(main(sys.argv[2:]))\n"
)


def run(argv: list[str], hwm_file: Path) -> tuple[float, float, int]:
    """(CPU s, peak RSS MB from the child's own VmHWM, exit code) of one accellog command in a
    fresh process (rusage's ru_maxrss would count the parent's memory at fork)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(hwm_file), *argv],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    _pid, status, ru = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return ru.ru_utime + ru.ru_stime, int(hwm_file.read_text()) / 1024.0, proc.returncode


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--dir", type=Path, default=Path("/tmp/accellog_hostile"))
    a = ap.parse_args()
    f = make_inputs(a.dir)
    out = a.dir / "never_written"
    rows = {
        "baseline: segment, 300 KB cut head": ["segment", str(f["cut"]), "-o", f"{out}.json"],
        "doctor, head + 20 MiB zeros": ["doctor", str(f["zeros20"])],
        "doctor, head + 2 GB zeros": ["doctor", str(f["zeros2g"])],
        "fit, head + 2 GB zeros": ["fit", str(f["zeros2g"]), "-o", f"{out}.json"],
        "fit, 2 GB NUL .csv": ["fit", str(f["nulcsv"]), "-o", f"{out}.json"],
        "import csv, 2 GB NUL": ["import", "csv", str(f["nulcsv"]), "-o", f"{out}.mcap"],
        "evaluate --cal 2 GB JSON": ["evaluate", str(f["cut"]), "--cal", str(f["bigjson"])],
        "fit, 32 MiB JSON of floats (the limit)": ["fit", str(f["floats32"]), "-o", f"{out}.json"],
        "evaluate --cal JSON nested 200k deep": ["evaluate", str(f["cut"]), "--cal", str(f["deepjson"])],
        "simulate --scenario 2 GB TOML": ["simulate", "--scenario", str(f["bigtoml"]), "-o", f"{out}.mcap"],
        "simulate --hold inf": ["simulate", "--hold", "inf", "-o", f"{out}.mcap"],
        "simulate --fault fifo_glitch_rate=1": [
            "simulate",
            "--fault",
            "fifo_glitch_rate=1",
            "-o",
            f"{out}.mcap",
        ],
    }
    res: dict[str, list[tuple[float, float, int]]] = {k: [] for k in rows}
    for _ in range(a.repeat):  # interleaved: the load of the machine hits every row alike
        for name, argv in rows.items():
            res[name].append(run(argv, a.dir / "hwm.txt"))
    base = statistics.median(r[0] for r in res[next(iter(rows))])
    print(f"{'command':40s} {'exit':>4s} {'CPU s':>7s} {'x base':>7s} {'peak MB':>8s}")
    table = []
    for name, rs in res.items():
        cpu = statistics.median(r[0] for r in rs)
        mem = max(r[1] for r in rs)
        table.append({"row": name, "exit": rs[0][2], "cpu_s": cpu, "ratio": cpu / base, "peak_mb": mem})
        print(f"{name:40s} {rs[0][2]:4d} {cpu:7.2f} {cpu / base:7.2f} {mem:8.0f}")
    assert not list(a.dir.glob("never_written*")), "a hostile input wrote an output"
    print(json.dumps({"repeat": a.repeat, "rows": table}))


if __name__ == "__main__":
    main()
