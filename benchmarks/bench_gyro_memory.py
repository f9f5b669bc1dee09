"""Peak RSS of the streamed gyro calibration and of the whole fit on long MCAP sessions.

    python benchmarks/bench_gyro_memory.py /tmp/memwork/h1.mcap /tmp/memwork/h4.mcap

Each figure comes from a fresh process (ru_maxrss); the load average is printed with it. Sessions
come from ``python benchmarks/synth_long.py``. The baseline is the same script run with PYTHONPATH
on an export of the commit before (``git archive COMMIT accellog | tar -x -C DIR``).
"""

from __future__ import annotations

import os
import subprocess
import sys

_CHILD = """
import os, resource, sys, time
from threadpoolctl import threadpool_limits
import numpy
threadpool_limits(1, "blas")
from accellog.calibrate.gyro.stream import calibrate_blocks
from accellog.flows.stages import run_fit
from accellog.store.source import open_source
path, what = sys.argv[1], sys.argv[2]
t0 = time.perf_counter()
if what == "gyro":
    src = open_source(path)
    calibrate_blocks(src, src.poses)
else:
    run_fit(path)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(f"{peak:.0f} {time.perf_counter() - t0:.1f}")
"""


def main(paths: list[str]) -> None:
    for path in paths:
        for what in ("gyro", "run_fit"):
            out = subprocess.run([sys.executable, "-c", _CHILD, path, what], capture_output=True, text=True)
            if out.returncode:
                sys.exit(out.stderr)
            peak, secs = out.stdout.split()
            load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
            print(f"{os.path.basename(path)} {what}: peak RSS {peak} MB, {secs} s (load {load})", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
