"""Start-up time of the command line, as a ratio to `python -c pass` measured in the same run (#9).

Goals (quiet 2-core machine): `accellog --help` < 0.3 s and `accellog effects` < 0.5 s. Each command is
run --repeat times in a fresh interpreter: the `accellog` script installed beside this interpreter
(the one `python -c pass` runs; a version manager's shim on PATH, e.g. pyenv's bash script, would add
its own ~0.1 s to accellog only), else `python -m accellog`. Reported: median wall and CPU time (user +
sys), peak RSS, and which heavy modules the command imported (numpy, pydantic, typer, scipy, rerun,
pyarrow, protobuf, mcap, dask): --help should load typer alone (it draws the help).

    python benchmarks/bench_startup.py [--repeat 9]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

HEAVY = ("numpy", "pydantic", "typer", "scipy", "rerun", "pyarrow", "google.protobuf", "mcap", "dask")


def _wall_s(cmd: list[str], repeat: int) -> tuple[float, float, float]:
    """Median wall time and median CPU time (user + sys of the child, s), and the largest peak RSS
    (MiB): on a loaded machine the CPU time is the steadier figure (waiting for a core counts in
    wall time only)."""
    times, cpu, rss = [], [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        child = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _, status, use = os.wait4(child.pid, 0)
        times.append(time.perf_counter() - t0)
        child.returncode = os.waitstatus_to_exitcode(status)
        if child.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)}: exit {child.returncode}")
        cpu.append(use.ru_utime + use.ru_stime)
        rss.append(use.ru_maxrss / 1024)  # KiB on Linux
    return statistics.median(times), statistics.median(cpu), max(rss)


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
    script = Path(sysconfig.get_path("scripts")) / "accellog"
    base = [str(script)] if script.is_file() else [sys.executable, "-m", "accellog"]
    load = os.getloadavg()
    print(
        f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores"
        + ("  (LOADED: figures inflated)" if load[0] > 0.5 * (os.cpu_count() or 1) else "")
    )
    print(f"accellog run as: {' '.join(base)}")
    floor, floor_cpu, floor_rss = _wall_s([sys.executable, "-c", "pass"], a.repeat)
    print(
        f"{'command':<22} {'median s':>9} {'x python -c pass':>17} {'CPU s':>7} {'x CPU':>6} {'peak MiB':>9}"
        f" {'goal s':>7}  heavy modules loaded"
    )
    print(f"{'python -c pass':<22} {floor:9.3f} {1.0:17.1f} {floor_cpu:7.3f} {1.0:6.1f} {floor_rss:9.1f}")
    for args, goal in ((["--help"], 0.3), (["effects"], 0.5)):
        t, c, rss = _wall_s(base + args, a.repeat)
        heavy = _heavy_imported(args)
        name = "accellog " + " ".join(args)
        print(
            f"{name:<22} {t:9.3f} {t / floor:17.1f} {c:7.3f} {c / floor_cpu:6.1f} {rss:9.1f} {goal:7.2f}"
            f"  {', '.join(heavy) or 'none'}"
        )


if __name__ == "__main__":
    main()
