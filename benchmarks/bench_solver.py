"""What the solver change costs users: `accellog fit` on a 1 h session end to end, and the start-up of
`accellog --help` / `accellog fit --help`, this tree against a baseline tree, in the same run.

The baseline is another revision's source, e.g. the last one with the home-made solvers:

    mkdir -p /tmp/base && git archive <rev> accellog | tar -x -C /tmp/base
    python benchmarks/bench_solver.py --baseline /tmp/base [--current TREE] [--repeat 5] [--duration-s 3600]

Each command runs in a fresh interpreter with PYTHONPATH set to the tree (so `import accellog` takes
that tree's package), baseline and current alternating, --repeat times each. Reported per command:
median CPU time (user + sys of the child; steadier than wall time on a shared machine), median wall
time, peak RSS, and the ratio current / baseline, with `python -c pass` as the floor. The fit is the
session from benchmarks/synth_long.py (1 kHz accel + gyro + temperature, 12 labelled holds); the two
calibration files are compared number by number (largest absolute difference).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def run(cmd: list[str], tree: Path | None) -> tuple[float, float, float]:
    """(wall s, CPU s = user + sys, peak RSS MiB) of one child process."""
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    t0 = time.perf_counter()
    child = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, use = os.wait4(child.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status):
        raise SystemExit(f"{' '.join(cmd)} (PYTHONPATH={tree}): {child.stderr.read().decode()[-2000:]}")
    child.stderr.close()
    return wall, use.ru_utime + use.ru_stime, use.ru_maxrss / 1024


def _numbers(a, b, path="") -> float:
    """Largest absolute difference between the numbers of two JSON values of the same shape."""
    if isinstance(a, dict):
        return max(
            [_numbers(a[k], b[k], k) for k in a if k in b and k not in ("sources", "created_utc")] + [0.0]
        )
    if isinstance(a, list):
        return max([_numbers(x, y, path) for x, y in zip(a, b, strict=True)] + [0.0])
    if isinstance(a, float | int) and isinstance(b, float | int) and not isinstance(a, bool):
        return abs(float(a) - float(b)) if a == a and b == b else 0.0
    return 0.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", type=Path, required=True, help="a tree holding the baseline accellog/")
    ap.add_argument("--current", type=Path, default=HERE, help="the tree to compare (default: this one)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--duration-s", type=float, default=3600.0)
    a = ap.parse_args()
    trees = {"baseline": a.baseline.resolve(), "current": a.current.resolve()}
    load = os.getloadavg()
    print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as d:
        session = Path(d) / "s.mcap"  # written by a child: this process stays small (its forks' peak RSS)
        subprocess.run(
            [sys.executable, "-c", "import sys; from synth_long import write_long; "
             "write_long(sys.argv[1], float(sys.argv[2]), seed=1)", str(session), str(a.duration_s)],
            cwd=Path(__file__).resolve().parent, check=True,
        )  # fmt: skip
        outs = {k: Path(d) / f"{k}.json" for k in trees}
        fit = "import sys; from accellog.cli import main; sys.exit(main(['fit', sys.argv[1], '-o', sys.argv[2]]))"
        commands = {
            "python -c pass": lambda k: [sys.executable, "-c", "pass"],
            "accellog --help": lambda k: [sys.executable, "-m", "accellog", "--help"],
            "accellog fit --help": lambda k: [sys.executable, "-m", "accellog", "fit", "--help"],
            f"accellog fit ({a.duration_s:g} s)": lambda k: [
                sys.executable, "-c", fit, str(session), str(outs[k])
            ],
        }  # fmt: skip
        got: dict[tuple[str, str], list] = {}
        for name, cmd in commands.items():
            for _ in range(a.repeat):
                for k, tree in trees.items():  # alternating: both see the same load
                    got.setdefault((name, k), []).append(run(cmd(k), tree))
        diff = _numbers(json.loads(outs["baseline"].read_text()), json.loads(outs["current"].read_text()))
    print(f"median of {a.repeat} (baseline and current alternating); ratio = current / baseline")
    print(f"{'command':<24} {'tree':<9} {'CPU s':>7} {'wall s':>7} {'peak MiB':>9} {'CPU ratio':>10}")
    for name in commands:
        base_cpu = statistics.median(c for _, c, _ in got[(name, "baseline")])
        for k in trees:
            runs = got[(name, k)]
            cpu = statistics.median(c for _, c, _ in runs)
            wall = statistics.median(w for w, _, _ in runs)
            rss = max(r for _, _, r in runs)
            print(f"{name:<24} {k:<9} {cpu:7.3f} {wall:7.3f} {rss:9.1f} {cpu / base_cpu:10.2f}")
    print(f"calibration files: largest absolute difference of any number {diff:.3g}")


if __name__ == "__main__":
    main()
