"""Start-up time of the command line, as a ratio to `python -c pass` measured in the same run (#9).

Goals (quiet 2-core machine): `accellog --help` < 0.3 s and `accellog effects` < 0.5 s. Each command is
run --repeat times in a fresh interpreter (the installed `accellog` script when on PATH, else
`python -m accellog`); the median wall time is reported with the modules the command imported that
the goals single out as heavy (scipy, rerun, pyarrow, protobuf, mcap): none should load for --help.

    python benchmarks/bench_startup.py [--repeat 9]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time

HEAVY = ("scipy", "rerun", "pyarrow", "google.protobuf", "mcap", "dask")


def _wall_s(cmd: list[str], repeat: int) -> tuple[float, float]:
    """Median wall time and median CPU time (user + sys of the child, s): on a loaded machine the
    CPU time is the steadier figure (waiting for a core counts in wall time only)."""
    times, cpu = [], []
    for _ in range(repeat):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        times.append(time.perf_counter() - t0)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu.append(r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime)
    return statistics.median(times), statistics.median(cpu)


def _heavy_imported(args: list[str]) -> list[str]:
    code = (
        "import sys, io, contextlib\n"
        "from accellog.cli import main\n"
        f"with contextlib.redirect_stdout(io.StringIO()): main({args!r})\n"
        f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    return out.split()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=9)
    a = ap.parse_args()
    script = shutil.which("accellog")
    base = [script] if script else [sys.executable, "-m", "accellog"]
    load = os.getloadavg()
    print(
        f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores"
        + ("  (LOADED: figures inflated)" if load[0] > 0.5 * (os.cpu_count() or 1) else "")
    )
    floor, floor_cpu = _wall_s([sys.executable, "-c", "pass"], a.repeat)
    print(
        f"{'command':<22} {'median s':>9} {'x python -c pass':>17} {'CPU s':>7} {'x CPU':>6} {'goal s':>7}"
        "  heavy modules loaded"
    )
    print(f"{'python -c pass':<22} {floor:9.3f} {1.0:17.1f} {floor_cpu:7.3f} {1.0:6.1f} {'':>7}")
    for args, goal in ((["--help"], 0.3), (["effects"], 0.5)):
        t, c = _wall_s(base + args, a.repeat)
        heavy = _heavy_imported(args)
        name = "accellog " + " ".join(args)
        print(
            f"{name:<22} {t:9.3f} {t / floor:17.1f} {c:7.3f} {c / floor_cpu:6.1f} {goal:7.2f}"
            f"  {', '.join(heavy) or 'none'}"
        )


if __name__ == "__main__":
    main()
