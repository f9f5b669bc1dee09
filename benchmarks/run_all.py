"""The commands users run, timed end to end beside their baselines in the same run -> benchmarks/RESULTS.md.

Every figure is a fresh process started from files on disk: the `accellog` CLI (the script installed
beside this interpreter, else `python -m accellog`) or a baseline script doing the same job with
plain libraries (numpy, pyarrow, rosbags, allantools). Each runs --repeat times, the commands and
their baselines interleaved (a change of load hits both alike); reported: median wall time, median
CPU time (user + sys of the process and its threads), median peak RSS (the child's own ru_maxrss
from wait4; this parent imports only the standard library, so a child inherits no large address
space). Ratios are end-to-end wall / baseline wall in the same run.

The baseline runs first in every other round: the first of two runs loads from disk what the second
then finds in the page cache (the input, numpy's and the command's libraries). On a host that drops
file pages left idle (the 2-core test VM pages out file pages unused for 60 s: a DAMON `pageout`
scheme), a round of the full run takes minutes, and the command, always first, paid that alone:
`replay --rrd` 1.25-1.30x its replay in full runs, 1.15-1.22x in runs of that row only.

Inputs are generated once into --dir (default /tmp/accellog_bench) and reused by later runs:
benchmarks/synth_long.py (1 kHz calibration sessions: 12 holds, accel + gyro + temperature),
synth_static.py (static sessions for `noise`), accellog.flows.simulate (the emulator's 24-pose
session, ~71 MB an hour, for the `cpu` rows: `accellog simulate --protocol 24 --hold 150`), bench_replay.py (static session + a model3
calibration), bench_csv_import.py (logger CSV), bench_ros2_import.py (rosbag2 MCAP bag).

    python benchmarks/run_all.py            # 1 h rows, 4 h CSV / noise, 60 min bag, 3 runs each
    python benchmarks/run_all.py --quick    # smaller inputs, 1 run: a check that every row runs
    python benchmarks/run_all.py --full     # + fit 24 h, fleet run (300 sessions); 5 runs
    python benchmarks/run_all.py --rows fit diagnose --no-write   # some rows, RESULTS.md untouched
    python benchmarks/run_all.py --rows cpu     # CPU of fit, evaluate, replay, noise, diagnose, doctor
                                                # beside benchmarks/floor_numpy.py, one 1 h session;
                                                # their peak memory on 1 min and 4 h beside it

A run of some rows (--rows) replaces those rows of RESULTS.md's table (the others keep their
figures) and adds a line naming the run; the README's speed table is remade from RESULTS.md's.

The console shows the load average once per run (figures on a loaded machine are inflated: compare
the ratios); RESULTS.md holds the figures only.
"""

from __future__ import annotations

import argparse
import compileall
import os
import re
import shlex
import statistics
import subprocess
import sys
import sysconfig
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
ENV = {**os.environ, "RERUN_ANALYTICS": "0", "PYTHONPATH": os.pathsep.join([str(BENCH), str(ROOT)])}


@dataclass
class Fig:
    """Median wall and CPU time (s) and peak RSS (MB) of one command over its runs."""

    wall_s: float
    cpu_s: float
    peak_mb: float


@dataclass
class Row:
    """One line of RESULTS.md: a user command, its baseline and the goal they are judged by."""

    key: str
    what: str
    goal: str
    cmd: list[str]
    base_name: str
    base: list[str] | None
    judge: Callable[[Fig, Fig | None], tuple[str, bool]]
    wall_only: bool = False  # judged on wall time whatever --by says (a parallel speed-up)
    shown: str = ""  # the command as RESULTS.md prints it
    figs: dict[str, list] = field(default_factory=lambda: {"cmd": [], "base": []})


# --- baselines: the same job with plain libraries, each a whole fresh process ---------------------

LSTSQ = """
import sys, numpy as np
from accellog.store.reader import read_session
s = read_session(sys.argv[1])
mask, up = np.zeros(s.n, bool), np.zeros((s.n, 3))
for p in s.poses:
    sl = s.slice_time(p.start_s + 0.5, p.end_s - 0.5)
    mask[sl] = True
    up[sl] = p.up_sensor
f, a, g, dT = up[mask], s.accel_g[mask], s.gyro_dps[mask], s.temp_degC[mask] - 25.0
A = np.column_stack([f, np.ones(f.shape[0])])
for i in range(3):
    np.linalg.lstsq(A, a[:, i], rcond=None)
np.linalg.lstsq(np.column_stack([np.ones(dT.shape[0]), dT]), g, rcond=None)
"""
PYARROW_CSV = """
import sys, pyarrow.csv as pacsv
n = 0
for b in pacsv.open_csv(sys.argv[1], read_options=pacsv.ReadOptions(block_size=16 << 20)):
    cols = [c.to_numpy() for c in b.columns]
    n += b.num_rows
"""
ROSBAGS_READ = """
import sys
from pathlib import Path
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
with AnyReader([Path(sys.argv[1])], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as r:
    conns = [c for c in r.connections if c.msgtype == "sensor_msgs/msg/Imu"]
    n = sum(1 for _ in r.messages(connections=conns))
"""
ALLANTOOLS = """
import sys, numpy as np, allantools
from accellog.store.reader import read_session
s = read_session(sys.argv[1])
y = np.concatenate([s.accel_g * 9.80665, np.deg2rad(s.gyro_dps)], axis=1)
for k in range(6):
    allantools.oadev(y[:, k], rate=s.meta.sample_rate_hz, data_type="freq", taus="octave")
"""

TWO_PROCESSES = """
import ast, subprocess, sys
procs = [subprocess.Popen(c, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for c in ast.literal_eval(sys.argv[1])]
sys.exit(max(p.wait() for p in procs))
"""

DASK_CONFIG_FILE = """
import sys, yaml
from accellog.flows.fleet_dask import WORKER_CONFIG
tree = {}
for key, value in WORKER_CONFIG.items():
    *path, last = key.split(".")
    node = tree
    for part in path:
        node = node.setdefault(part, {})
    node[last] = value
open(sys.argv[1], "w").write(yaml.safe_dump(tree))
"""

WAIT_FOR_WORKERS = """
import sys
from dask.distributed import Client
with Client(sys.argv[1], timeout=60) as c:
    c.wait_for_workers(int(sys.argv[2]), timeout=120)
"""


def running_cluster(d: Path, workers: int) -> str:
    """A Dask scheduler and `workers` single-threaded workers on 127.0.0.1, started as a lab keeps one
    running (the dask CLI; accellog's WORKER_CONFIG in a dask config file, as docs/fleet.md asks of a
    real cluster); stopped when this script exits. Returns the scheduler's address."""
    import atexit
    import json

    conf = d / "dask_config"
    conf.mkdir(exist_ok=True)
    subprocess.run(python(DASK_CONFIG_FILE, conf / "accellog.yaml"), env=ENV, check=True)
    env = {**ENV, "DASK_CONFIG": str(conf), "OPENBLAS_NUM_THREADS": "1"}
    info = d / "dask_scheduler.json"
    info.unlink(missing_ok=True)
    dask = [str(Path(sysconfig.get_path("scripts")) / "dask")]
    quiet = {
        "env": env,
        "stdout": subprocess.DEVNULL,
        "stderr": subprocess.DEVNULL,
        "start_new_session": True,
    }
    procs = [subprocess.Popen([*dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(info)], **quiet)]  # fmt: skip

    def stop() -> None:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()

    atexit.register(stop)
    end = time.monotonic() + 60
    while not info.exists() or not info.read_text().strip():
        if time.monotonic() > end or procs[0].poll() is not None:
            raise SystemExit("the dask scheduler of the running-cluster row did not start")
        time.sleep(0.1)
    address = json.loads(info.read_text())["address"]
    procs.append(subprocess.Popen([*dask, "worker", address, "--nworkers", str(workers), "--nthreads", "1",
                                   "--host", "127.0.0.1", "--no-dashboard"], **quiet))  # fmt: skip
    subprocess.run(python(WAIT_FOR_WORKERS, address, workers), env=env, check=True)
    return address


# --- inputs: generated once into --dir, each in a subprocess (this parent stays small) ------------

GEN = {
    "fit": "from synth_long import write_long; write_long(OUT, {sec}, seed=1)",
    "still": "from synth_static import write_static; write_static(OUT, {sec}, seed=2)",
    "csv": "from bench_csv_import import write_csv; write_csv(OUT, round({sec} * 1000), 1000.0)",
    "bag": "from bench_ros2_import import write_bag; write_bag(OUT, round({sec} * 1000), 1000.0)",
    "replay": "from bench_replay import write_static; write_static(OUT, {sec} / 60)",
    "sim24": "from accellog.flows.simulate import Scenario, simulate; simulate(Scenario(protocol='24', hold_s={sec} / 24), OUT)",
}


def made(d: Path, kind: str, sec: float) -> Path:
    """The input file of `kind` and length `sec` in d, generated the first time (via a temporary
    name, so an interrupted generation is never taken for a cached input)."""
    ext = "csv" if kind == "csv" else "mcap"
    path = d / f"{kind}_{sec:g}s.{ext}"
    if path.exists():
        return path
    part = d / f"{kind}_{sec:g}s.part.{ext}"
    part.unlink(missing_ok=True)
    t0 = time.perf_counter()
    code = f"OUT = {str(part)!r}\n" + GEN[kind].format(sec=float(sec))
    subprocess.run([sys.executable, "-c", code], env=ENV, cwd=BENCH, check=True)
    os.replace(part, path)
    print(f"  made {path.name} ({path.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t0:.0f} s",
          flush=True)  # fmt: skip
    return path


def fleet_sessions(d: Path, n: int) -> Path:
    """A simulated fleet of n short sessions (accellog.flows.fleet_sim, 4 per device), made once."""
    out = d / f"fleet_{n}"
    if not (out / "fleet_truth.json").exists():
        code = (
            "from accellog.flows.fleet_sim import FleetSpec, simulate_fleet\n"
            f"simulate_fleet(FleetSpec(n_devices={-(-n // 4)}, sessions_per_device=4), {str(out)!r}, jobs=2)"
        )
        subprocess.run([sys.executable, "-c", code], env=ENV, cwd=BENCH, check=True)
    return out


def calibration(d: Path) -> Path:
    """model3 calibration of bench_replay's synthetic chip (its own six-pose session), made once."""
    path = d / "model3.json"
    if not path.exists():
        code = (
            "from pathlib import Path; from bench_replay import write_calibration; write_calibration(Path(D))"
        )
        subprocess.run([sys.executable, "-c", f"D = {str(d)!r}\n{code}"], env=ENV, cwd=BENCH, check=True)
    return path


# --- measuring --------------------------------------------------------------------------------------


def accellog(*args: object) -> list[str]:
    script = Path(sysconfig.get_path("scripts")) / "accellog"
    head = [str(script)] if script.is_file() else [sys.executable, "-m", "accellog"]
    return head + [str(a) for a in args]


def python(code: str, *args: object) -> list[str]:
    return [sys.executable, "-c", code] + [str(a) for a in args]


def run_once(cmd: list[str], cwd: Path) -> tuple[float, float, float]:
    """Wall s, CPU s (user + sys) and peak RSS MB of one fresh process; its output is discarded."""
    t0 = time.perf_counter()
    child = subprocess.Popen(cmd, cwd=cwd, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    err = child.stderr.read() if child.stderr else b""
    _, status, use = os.wait4(child.pid, 0)
    wall = time.perf_counter() - t0
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode:
        tail = err.decode(errors="replace").strip().splitlines()[-1:] or ["(no message)"]
        raise SystemExit(f"{shlex.join(cmd)[:200]}: exit {child.returncode}: {tail[0]}")
    return wall, use.ru_utime + use.ru_stime, use.ru_maxrss / 1024  # KiB on Linux


def median(runs: list[tuple[float, float, float]]) -> Fig:
    return Fig(*(statistics.median(r[i] for r in runs) for i in range(3)))


def judged(r: Row, by: str) -> tuple[Fig, Fig | None, str, bool]:
    """(command figure, baseline figure, ratio text, goal met) of a row; by 'cpu': the ratio and the
    goal on CPU time instead of wall time (a loaded machine inflates wall times)."""
    f = median(r.figs["cmd"])
    b = median(r.figs["base"]) if r.figs["base"] else None
    on = (lambda x: Fig(x.cpu_s, x.cpu_s, x.peak_mb)) if by == "cpu" and not r.wall_only else (lambda x: x)
    ratio, ok = r.judge(on(f), None if b is None else on(b))
    return f, b, ratio, ok


# --- the rows ---------------------------------------------------------------------------------------


def _below(limit_s: float) -> Callable[[Fig, Fig | None], tuple[str, bool]]:
    def judge(f: Fig, b: Fig | None) -> tuple[str, bool]:
        return (f"{f.wall_s / b.wall_s:.2f}x" if b else "-"), f.wall_s < limit_s

    return judge


def _ratio(at_most: float, also_s: float = float("inf")) -> Callable[[Fig, Fig | None], tuple[str, bool]]:
    def judge(f: Fig, b: Fig | None) -> tuple[str, bool]:
        r = f.wall_s / b.wall_s if b else float("nan")
        return f"{r:.2f}x", r <= at_most and f.wall_s < also_s

    return judge


def _ros2(sec: float) -> Callable[[Fig, Fig | None], tuple[str, bool]]:
    def judge(f: Fig, b: Fig | None) -> tuple[str, bool]:
        rt = sec / f.wall_s
        return f"{f.wall_s / b.wall_s:.2f}x; {rt:.0f}x real time", rt >= 100 and f.peak_mb <= 300

    return judge


def _speedup(at_least: float) -> Callable[[Fig, Fig | None], tuple[str, bool]]:
    def judge(f: Fig, b: Fig | None) -> tuple[str, bool]:
        r = b.wall_s / f.wall_s if b else float("nan")
        return f"{r:.2f}x faster", r >= at_least

    return judge


def _flat(f1h: Callable[[], Fig | None]) -> Callable[[Fig, Fig | None], tuple[str, bool]]:
    def judge(f: Fig, b: Fig | None) -> tuple[str, bool]:
        ref = f1h()
        if ref is None:
            return "-", True
        m = f.peak_mb / ref.peak_mb
        return f"memory {m:.2f}x, CPU time {f.cpu_s / ref.cpu_s:.2f}x", m <= 1.25

    return judge


def _beside(at_most: float) -> Callable[[Fig, Fig | None], tuple[str, bool]]:
    """Peak memory (and CPU time) beside the baseline's in the same run: the goal on memory."""

    def judge(f: Fig, b: Fig | None) -> tuple[str, bool]:
        m = f.peak_mb / b.peak_mb if b else float("nan")
        return f"memory {m:.2f}x, CPU time {f.cpu_s / b.cpu_s:.2f}x" if b else "-", m <= at_most

    return judge


def _cpu_floor(
    floor: Callable[[], Fig | None], at_most: float
) -> Callable[[Fig, Fig | None], tuple[str, bool]]:
    """CPU time against the same run's plain-numpy floor (benchmarks/floor_numpy.py)."""

    def judge(f: Fig, b: Fig | None) -> tuple[str, bool]:
        ref = floor()
        if ref is None:
            return "-", True
        r = f.cpu_s / ref.cpu_s
        return f"CPU {r:.2f}x", r <= at_most

    return judge


CPU_COMMANDS = ("fit", "evaluate --cal", "replay --cal", "noise", "diagnose --model model3", "doctor")


def _cpu_commands(sim: Path, cal: Path, d: Path) -> list[tuple[str, tuple]]:
    """The commands of the `cpu` rows on session sim (evaluate and replay apply cal), as CPU_COMMANDS."""
    return list(zip(CPU_COMMANDS, (("fit", sim, "-o", d / "cal_cpu_fit.json", "--force"),
                                   ("evaluate", sim, "--cal", cal),
                                   ("replay", sim, "--cal", cal, "--speed", "max"),
                                   ("noise", sim, "--json"),
                                   ("diagnose", sim, "--model", "model3"),
                                   ("doctor", sim, "--json")), strict=True))  # fmt: skip


def rows(d: Path, mode: str, only: set[str] | None) -> list[Row]:
    """The rows of this run (mode: quick / default / full); inputs are made only for chosen rows."""
    quick, full = mode == "quick", mode == "full"
    want = lambda key: only is None or key in only or (key == "fit" and "scale" in only)  # noqa: E731
    out: list[Row] = []
    pass_ = python("pass")
    if want("fit") or want("diagnose") or want("scale"):
        f1h = made(d, "fit", 3600)
    if want("fit"):
        out.append(Row("fit", "`fit` 1 h at 1 kHz (model3 + gyro)", "< 3 s and <= 0.75x baseline",
                       accellog("fit", f1h, "-o", d / "cal_fit.json", "--force"), "read_session + np.linalg.lstsq",
                       python(LSTSQ, f1h), _ratio(0.75, 3.0)))  # fmt: skip
    if want("diagnose"):
        out.append(Row("diagnose", "`diagnose` 1 h at 1 kHz", "< 1.5 s", accellog("diagnose", f1h, "--json"),
                       "read_session + np.linalg.lstsq", python(LSTSQ, f1h), _below(1.5)))  # fmt: skip
    if want("csv"):
        sec = 3600 if quick else 14400
        csv = made(d, "csv", sec)
        out.append(Row("csv", f"`import csv` {sec // 3600} h at 1 kHz", "<= 1.5x baseline",
                       accellog("import", "csv", csv, "-o", d / "csv_out.mcap", "--force"), "pyarrow open_csv (streamed) + to_numpy",
                       python(PYARROW_CSV, csv), _ratio(1.5)))  # fmt: skip
    if want("replay"):
        sec = 600 if quick else 3600
        rp, cal = made(d, "replay", sec), calibration(d)
        plain = accellog("replay", rp, "--cal", cal, "--speed", "max", "--up", "+z")
        out.append(Row("replay", f"`replay --rrd` {sec // 60} min at 1 kHz", "< 1.25x baseline",
                       [*plain, "--rrd", str(d / "replay.rrd")], "the same replay without --rrd", plain,
                       _ratio(1.25)))  # fmt: skip
    if want("ros2"):
        sec = 600 if quick else 3600
        bag = made(d, "bag", sec)
        out.append(Row("ros2", f"`import ros2` {sec // 60} min bag at 1 kHz", ">= 100x real time in <= 300 MB",
                       accellog("import", "ros2", bag, "-o", d / "ros2_out.mcap", "--force"), "rosbags AnyReader, raw messages",
                       python(ROSBAGS_READ, bag), _ros2(sec)))  # fmt: skip
    if want("startup"):
        for args, goal in ((["effects"], 0.5), (["--help"], 0.3), (["fit", "--help"], 0.5)):
            out.append(Row("startup", f"`{' '.join(args)}` start-up", f"< {goal:g} s", accellog(*args),
                           "python -c pass", pass_, _below(goal)))  # fmt: skip
    if want("noise"):
        sec = 3600 if quick else 14400
        still = made(d, "still", sec)
        out.append(Row("noise", f"`noise` {sec // 3600} h at 1 kHz", "< 60 s and < 500 MB",
                       accellog("noise", still, "--json"), "read_session + allantools.oadev (6 columns)",
                       python(ALLANTOOLS, still),
                       lambda f, b: (f"{f.wall_s / b.wall_s:.2f}x", f.wall_s < 60 and f.peak_mb < 500)))  # fmt: skip
    if want("scale"):
        ref = lambda: next((median(r.figs["cmd"]) for r in out if r.key == "fit" and r.figs["cmd"]), None)  # noqa: E731
        for sec in [60] + ([] if quick else [14400]) + ([86400] if full else []):
            path = made(d, "fit", sec)
            name = f"{sec // 60} min" if sec < 3600 else f"{sec // 3600} h"
            out.append(Row("scale", f"`fit` {name} (memory flat in the length)", "peak <= 1.25x the 1 h fit",
                           accellog("fit", path, "-o", d / "cal_scale.json", "--force"), "`fit` 1 h (row above)", None,
                           _flat(ref)))  # fmt: skip
    if want("doctor"):
        for sec in [60, 600 if quick else 3600] + ([86400] if full else []):
            path = made(d, "fit", sec)
            name = f"{sec // 60} min" if sec < 3600 else f"{sec // 3600} h"
            out.append(Row("doctor", f"`doctor` {name} (memory beside `fit`'s)", "peak <= 1.25x `fit` on the same session",
                           accellog("doctor", path, "--json"), f"`fit` {name}",
                           accellog("fit", path, "-o", d / "cal_doctor.json", "--force"), _beside(1.25)))  # fmt: skip
    if want("cpu"):
        sim = made(d, "sim24", 3600)
        cal = d / "cal_cpu.json"
        if not cal.exists():  # the calibration evaluate and replay apply: the session's own fit, made once
            subprocess.run(accellog("fit", sim, "-o", cal), env=ENV, stdout=subprocess.DEVNULL, check=True)
        floor_cmd = [sys.executable, str(BENCH / "floor_numpy.py"), str(sim)]
        floor = Row("cpu", "plain-numpy floor of the work, 1 h 24-pose at 1 kHz", "-", floor_cmd, "-", None,
                    lambda f, b: ("-", True), shown="python benchmarks/floor_numpy.py D/sim24_3600s.mcap")  # fmt: skip
        out.append(floor)
        ref = lambda: median(floor.figs["cmd"]) if floor.figs["cmd"] else None  # noqa: E731
        for label, args in _cpu_commands(sim, cal, d):
            out.append(Row("cpu", f"`{label}` 1 h 24-pose at 1 kHz: CPU beside the floor", "CPU <= 1.5x the floor",
                           accellog(*args), "the floor (row above)", None, _cpu_floor(ref, 1.5)))  # fmt: skip
        # memory flat in the length: each command on 1 min and 4 h of the same protocol, beside its 1 h peak
        hour = {r.what.split("`")[1]: r for r in out[-len(CPU_COMMANDS) :]}
        for sec in (60, 600 if quick else 14400):
            path, name = made(d, "sim24", sec), f"{sec // 60} min" if sec < 3600 else f"{sec // 3600} h"
            for label, args in _cpu_commands(path, cal, d):
                out.append(Row("cpu", f"`{label}` {name} 24-pose (memory flat in the length)",
                               "peak <= 1.25x its 1 h run", accellog(*args), f"`{label}` 1 h (CPU row)", None,
                               _flat(lambda r=hour[label]: median(r.figs["cmd"]) if r.figs["cmd"] else None)))  # fmt: skip
    if full and want("fleet"):
        fl = fleet_sessions(d, 300)
        run = ("fleet", "run", ROOT / "pipelines" / "fleet.toml", f"{fl}/**/*.mcap", "--force", "-o")
        out.append(Row("fleet", "`fleet run` 300 sessions, 2 local workers", ">= 1.8x faster than serial",
                       accellog(*run, d / "fleet_par", "--workers", 2), "the serial loop (--workers 0)",
                       accellog(*run, d / "fleet_ser", "--workers", 0), _speedup(1.8), wall_only=True))  # fmt: skip
        # the ceiling of 2 cores: the same sessions cut in two halves, two serial runs side by side
        halves = [f"{fl}/IMU-00[0-3]?/*.mcap", f"{fl}/IMU-00[4-9]?/*.mcap"]
        pair = [
            [*accellog(*run[:3], h, "--force", "-o", d / f"fleet_half{k}", "--workers", 0)]
            for k, h in enumerate(halves)
        ]
        address = running_cluster(d, 2)
        out.append(Row("fleet", "`fleet run` 300 sessions, a running cluster of 2 workers", ">= 1.8x faster than serial",
                       accellog(*run, d / "fleet_run", "--scheduler", address, "--workers-write"),
                       "the serial loop (--workers 0)", accellog(*run, d / "fleet_ser", "--workers", 0),
                       _speedup(1.8), wall_only=True,
                       shown="accellog fleet run pipelines/fleet.toml 'D/fleet_300/**/*.mcap' --force -o D/fleet_run "
                             "--scheduler tcp://127.0.0.1:PORT --workers-write (`dask scheduler` and "
                             "`dask worker --nworkers 2 --nthreads 1` started before)"))  # fmt: skip
        out.append(Row("fleet", "2 plain processes, one per half of the same sessions (the ceiling)", "-",
                       python(TWO_PROCESSES, repr(pair)), "the serial loop (--workers 0)",
                       accellog(*run, d / "fleet_ser", "--workers", 0), _speedup(0.0), wall_only=True,
                       shown="two `accellog fleet run ... --workers 0` side by side, on devices IMU-0001..39 and IMU-0040..75"))  # fmt: skip
    head = len(accellog())
    for r in out:  # as RESULTS.md shows it: the CLI as `accellog`, the input directory as D
        if r.shown:
            continue
        args = [str(a).replace(str(d), "D").replace(str(ROOT) + "/", "") for a in r.cmd[head:]]
        r.shown = shlex.join(["accellog", *args])
    return out


# --- output -----------------------------------------------------------------------------------------


def fmt(f: Fig) -> str:
    return f"{f.wall_s:.2f} s (CPU {f.cpu_s:.2f} s, {f.peak_mb:.0f} MB)"


def met(r: Row, ok: bool) -> str:
    """The "goal met" cell: '-' for a row without a goal (a reference point such as a ceiling)."""
    return "-" if r.goal == "-" else ("yes" if ok else "**no**")


TABLE_HEAD = "| what | goal | end to end | baseline (same run) | ratio | goal met | command |"


def row_lines(done: list[Row], by: str) -> list[str]:
    """The RESULTS.md table rows of this run's rows."""
    out = []
    for r in done:
        f, b, ratio, ok = judged(r, by)
        base = f"{r.base_name}: {fmt(b)}" if b else r.base_name
        out.append(f"| {r.what} | {r.goal} | {fmt(f)} | {base} | {ratio} | {met(r, ok)} | `{r.shown}` |")
    return out


def results_md(done: list[Row], mode: str, repeat: int, by: str, only: list[str] | None, load: str) -> str:
    """RESULTS.md's table: the whole of it from a run of every row; from a run of some rows (only),
    the current table with those rows replaced (or added at its end) and a line naming that run."""
    flags = ("" if mode == "default" else f" --{mode}") + (" --by cpu" if by == "cpu" else "")
    flags += f" --repeat {repeat}" if repeat != {"quick": 1, "default": 3, "full": 5}[mode] else ""
    lines = row_lines(done, by)
    head, table, notes = _split_results(
        (BENCH / "RESULTS.md").read_text() if (BENCH / "RESULTS.md").exists() else ""
    )
    if only and table:
        new = {_what(x): x for x in lines}
        kept = [new.pop(_what(x), x) for x in table]
        keys = ", ".join(f"`{k}`" for k in only)
        note = (f"The {keys} rows: `python benchmarks/run_all.py{flags} --rows {' '.join(only)}` (medians of "
                f"{repeat} run(s), load {load}).")  # fmt: skip
        notes = [x for x in notes if not _made_by(x) or not _made_by(x) <= set(only)] + [note]
        return "\n".join([*head, *kept, *new.values(), "", *notes]) + "\n"
    head = [
        "# Benchmark results",
        "",
        f"Generated by `python benchmarks/run_all.py{flags}`: "
        "each command is run end to end from the CLI in a fresh process, from files on disk, beside its "
        f"baseline in the same run; figures are medians of {repeat} run(s): wall time (CPU time = user + "
        "sys of the process and the children it waited for, from wait4; peak resident memory). The ratio "
        f"and the goal are judged on {by} time where the goal names no CPU. `D` is the input directory "
        "(`--dir`, default /tmp/accellog_bench) where the script generates the sessions. Inner-function "
        "figures of the individual `bench_*.py` scripts are described in benchmarks/README.md.",
        "",
        TABLE_HEAD,
        "|---|---|---|---|---|---|---|",
    ]
    return "\n".join([*head, *lines]) + "\n"


def _made_by(note: str) -> set[str]:
    """The row keys of a note "The `a`, `b` rows: ..." (empty for any other line): a later run of
    those rows makes it stale."""
    m = re.match(r"The ((?:`\w+`(?:, )?)+) rows:", note)
    return set(re.findall(r"`(\w+)`", m[1])) if m else set()


def _what(line: str) -> str:
    return line.split("|")[1].strip()


def _split_results(text: str) -> tuple[list[str], list[str], list[str]]:
    """(the lines down to the table's separator, the table's rows, the lines after it) of RESULTS.md's
    main table (the text before the sections other scripts write)."""
    lines = text.split(RESULTS_START, 1)[0].rstrip("\n").splitlines()
    if TABLE_HEAD not in lines:
        return lines, [], []
    i = lines.index(TABLE_HEAD) + 2
    j = i
    while j < len(lines) and lines[j].startswith("| "):
        j += 1
    return lines[:i], lines[i:j], [x for x in lines[j:] if x.strip()]


RESULTS_START = "<!-- discovery: python benchmarks/bench_discovery.py --write -->"
RESULTS_END = "<!-- end of discovery -->"
"""Markers of the discovery section of RESULTS.md (written by bench_discovery.py --write)."""


PEERS_START, PEERS_END = "<!-- peers: python benchmarks/bench_peers.py --write -->", "<!-- end of peers -->"
"""Markers of the peers section of RESULTS.md (written by bench_peers.py --write)."""
KEPT_SECTIONS = ((RESULTS_START, RESULTS_END), (PEERS_START, PEERS_END))
"""Markers of the sections of RESULTS.md that other scripts write (bench_discovery.py, bench_peers.py)."""


def write_section(text: str, start: str, end: str, path: Path | None = None) -> None:
    """Replace the section of RESULTS.md between the markers start and end with text (which holds
    them), or append it."""
    path = path or BENCH / "RESULTS.md"
    old = path.read_text() if path.exists() else ""
    if start in old and end in old:
        head, rest = old.split(start, 1)
        old = head + text.rstrip("\n") + rest.split(end, 1)[1]
    else:
        old = old.rstrip("\n") + "\n\n" + text
    path.write_text(old)


def kept_sections() -> str:
    """Sections of the current RESULTS.md that other scripts write (KEPT_SECTIONS), kept when the
    table is regenerated."""
    text = (BENCH / "RESULTS.md").read_text() if (BENCH / "RESULTS.md").exists() else ""
    out = ""
    for start, end in KEPT_SECTIONS:
        if start in text and end in text:
            out += "\n" + start + text.split(start, 1)[1].split(end, 1)[0] + end + "\n"
    return out


README_START, README_END = "<!-- speed table: python benchmarks/run_all.py -->", "<!-- end of speed table -->"
FIGURE = re.compile(r"([\d.]+) s \(CPU ([\d.]+) s, (\d+) MB\)")
"""An end-to-end cell of RESULTS.md (fmt): wall s, CPU s, peak MB."""


def write_readme_table() -> None:
    """The README's speed table (between its two markers) from RESULTS.md's table: what, wall time,
    CPU time (user + sys, children included), peak memory, the ratio to the same-run baseline, the
    goal and whether it is met; the commands are in RESULTS.md."""
    _, table, _ = _split_results((BENCH / "RESULTS.md").read_text())
    lines = [README_START, "", "| what (end to end, from the CLI) | wall | CPU | peak RSS | vs the same-run baseline | goal | met |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    for row in table:
        what, goal, end, base, ratio, ok = (c.strip() for c in row.split("|")[1:7])
        m = FIGURE.match(end)
        wall, cpu, mb = (f"{m[1]} s", f"{m[2]} s", f"{m[3]} MB") if m else (end, "-", "-")
        vs = ratio if base == "-" else f"{ratio} ({base.split(': ', 1)[0]})"
        lines.append(f"| {what} | {wall} | {cpu} | {mb} | {vs} | {goal} | {ok} |")
    text = (ROOT / "README.md").read_text()
    a, b = text.index(README_START), text.index(README_END)
    (ROOT / "README.md").write_text(text[:a] + "\n".join([*lines, ""]) + "\n" + text[b:])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="smaller inputs, one run each")
    g.add_argument("--full", action="store_true", help="all rows, incl. fit on 24 h")
    ap.add_argument("--repeat", type=int, help="runs per command (default 3; --quick 1, --full 5)")
    ap.add_argument("--dir", type=Path, default=Path("/tmp/accellog_bench"), help="inputs, generated once")
    ap.add_argument(
        "--rows",
        nargs="+",
        help="only these rows: fit diagnose csv replay ros2 startup noise scale doctor cpu fleet (--full); "
        "RESULTS.md keeps the other rows' figures (and says which rows this run made)",
    )
    ap.add_argument(
        "--by", choices=["wall", "cpu"], default="wall", help="judge ratios and goals on this time"
    )
    ap.add_argument("--no-write", action="store_true", help="print only; leave RESULTS.md as it is")
    a = ap.parse_args()
    mode = "quick" if a.quick else "full" if a.full else "default"
    repeat = a.repeat or {"quick": 1, "default": 3, "full": 5}[mode]
    a.dir.mkdir(parents=True, exist_ok=True)
    # users run accellog from bytecode (pip compiles it when installing; an editable install on first
    # use): so do the timed commands, even where PYTHONDONTWRITEBYTECODE keeps Python from writing it
    compileall.compile_dir(ROOT / "accellog", quiet=1)
    load = os.getloadavg()
    print(
        f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores; inputs in {a.dir}"
    )
    todo = rows(a.dir, mode, set(a.rows) if a.rows else None)
    loads = [load[0]]
    for k in range(repeat):  # interleaved: each round runs every command and its baseline once,
        for r in todo:  # the baseline first in every other round (module docstring)
            pair = [("cmd", r.cmd)] + ([("base", r.base)] if r.base is not None else [])
            for key, cmd in pair[:: -1 if k % 2 else 1]:
                r.figs[key].append(run_once(cmd, a.dir))
        loads.append(os.getloadavg()[0])
        print(f"  round {k + 1}/{repeat} done, load {loads[-1]:.2f}", flush=True)
    print(
        f"\n{'what':<46} {'wall s':>7} {'CPU s':>7} {'MB':>5} | {'base wall':>9} {'CPU s':>7} {'MB':>5} | ratio"
    )
    for r in todo:
        f, b, ratio, ok = judged(r, a.by)
        bs = f"{b.wall_s:9.2f} {b.cpu_s:7.2f} {b.peak_mb:5.0f}" if b else f"{'-':>9} {'-':>7} {'-':>5}"
        cpu_r = f" (CPU {f.cpu_s / b.cpu_s:.2f}x, wall {f.wall_s / b.wall_s:.2f}x)" if b else ""
        print(f"{r.what:<46} {f.wall_s:7.2f} {f.cpu_s:7.2f} {f.peak_mb:5.0f} | {bs} | {ratio}{cpu_r} "
              f"{'ok' if ok else 'GOAL MISSED: ' + r.goal}")  # fmt: skip
    if not a.no_write:
        span = f"{min(loads):.1f}-{max(loads):.1f}"
        text = results_md(todo, mode, repeat, a.by, a.rows, span) + kept_sections()
        (BENCH / "RESULTS.md").write_text(text)
        print(f"\nwrote {BENCH / 'RESULTS.md'}")
        write_readme_table()  # the README's speed table follows RESULTS.md's
        print(f"wrote the speed table of {ROOT / 'README.md'}")


if __name__ == "__main__":
    main()
