"""Scale: wall time and peak memory against session length, whole-session vs chunk-by-chunk.

Sessions of 1 min / 1 h / 4 h (optionally 24 h) at 1 kHz with accel, gyro and temperature, 12 holds
per hour (benchmarks/synth_long.py, written hour by hour). Each measurement runs in a fresh
process under GNU time (wall, peak RSS), one at a time:

    read            read_session (the whole session in memory)
    whole           read_session + segment.observations + fit model3 + diagnose (library calls)
    stream          calibrate.observe.segment.observations of the file + fit model3 + diagnose: samples
                    pass chunk group by chunk group, memory = the longest hold + one group
    fit_whole       flows.stages.run_fit(load_input(P)): the fit command before streaming (model3 + gyro)
    fit_stream      flows.stages.run_fit(P): the fit command now (observations, time checks and the
                    gyro calibration streamed; same calibration)
    decompress      the floor of any reader: zstd-decompress every chunk of the file (no decoding)
    evaluate_whole  the evaluate command before streaming: run_evaluate_report(P, [CAL], stream=False)
                    on a static '+z' session of the same length (synth_static.py), raw + model3
    evaluate_stream the evaluate command now (navigate.evaluate: one pass over the chunks)
    integrate_whole the integrate command before streaming (whole session, CSV of every sample)
    integrate_stream the integrate command now (rows written block by block)
    drift_whole     the drift command before streaming: run_drift(load_input(P), CAL) (whole session)
    drift_stream    the drift command now: run_drift(P, CAL) (navigate.drift: two passes
                    over the chunks, same calibration to 1e-9 relative)

Prints the load average with each row (a loaded 2-core machine inflates every wall time).
--baseline TREE runs every mode a second time, right after, with TREE (another checkout, e.g. a
worktree of main) first on PYTHONPATH, and prints the CPU ratio this tree / TREE; --dir keeps the
generated sessions there and reuses them (a 24 h static session is 1.6 GB).

    python benchmarks/bench_scale.py [--hours 0.0167 1 4] [--modes ...] [--dir D] [--baseline TREE]
    python benchmarks/bench_scale.py --hours 1 4 --modes evaluate_whole evaluate_stream integrate_stream
    python benchmarks/bench_scale.py --hours 1 4 --modes drift_whole drift_stream
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from synth_long import write_long
from synth_static import write_static

MODES = {
    "read": "from accellog.store.reader import read_session; s = read_session(P)",
    "whole": (
        "from accellog.store.reader import read_session; from accellog.calibrate.observe.segment import observations\n"
        "from accellog.calibrate.model.fit import fit_model; from accellog.calibrate.model.compose import build_model\n"
        "from accellog.calibrate.diagnosis.diagnose import diagnose\n"
        "obs = observations(read_session(P)); fit_model(obs, build_model('model3')); diagnose(obs, build_model('model3'))"
    ),
    "stream": (
        "from accellog.calibrate.observe.segment import observations\n"
        "from accellog.calibrate.model.fit import fit_model; from accellog.calibrate.model.compose import build_model\n"
        "from accellog.calibrate.diagnosis.diagnose import diagnose\n"
        "obs = observations(P); fit_model(obs, build_model('model3')); diagnose(obs, build_model('model3'))"
    ),
    "fit_whole": "from accellog.flows.stages import load_input, run_fit; run_fit(load_input(P))",
    "fit_stream": "from accellog.flows.stages import run_fit; run_fit(P)",
    "decompress": (
        "import zstandard, lz4.frame\n"
        "from mcap.stream_reader import StreamReader; from mcap.records import Chunk\n"
        "z = zstandard.ZstdDecompressor().decompress\n"
        "for rec in StreamReader(open(P, 'rb'), emit_chunks=True).records:\n"
        "    if isinstance(rec, Chunk):\n"
        "        z(rec.data, max_output_size=rec.uncompressed_size) if rec.compression == 'zstd' else "
        "lz4.frame.decompress(rec.data)"
    ),
    "evaluate_whole": "from accellog.flows.stages import run_evaluate_report as r; r(P, [CAL], stream=False)",
    "evaluate_stream": "from accellog.flows.stages import run_evaluate_report as r; r(P, [CAL])",
    "integrate_whole": (
        "from accellog.flows.stages import run_integrate as r; r(P, CAL, output=OUT, stream=False)"
    ),
    "integrate_stream": "from accellog.flows.stages import run_integrate as r; r(P, CAL, output=OUT)",
    "drift_whole": "from accellog.flows.stages import load_input, run_drift as r; r(load_input(P), CAL)",
    "drift_stream": "from accellog.flows.stages import run_drift as r; r(P, CAL)",
}
STATIC_MODES = (
    "evaluate_whole",
    "evaluate_stream",
    "integrate_whole",
    "integrate_stream",
    "drift_whole",
    "drift_stream",
)
"""Modes run on a static one-hold session (synth_static.py) with a model3 calibration CAL."""


def run(
    mode: str, path: Path, cal: Path | None = None, tree: Path | None = None
) -> tuple[float, float, float]:
    """(wall s, peak RSS MB, CPU s = user + system) of one fresh process doing `mode` on path, BLAS on
    one thread (on a loaded machine the CPU time is the better guide to the quiet wall time); tree:
    the source tree put first on PYTHONPATH (None: as this process finds accellog). The process runs
    in path's directory and names the accellog it imported (checked against tree)."""
    out = path.with_suffix(".csv")
    # numpy first: threadpoolctl limits only the BLAS libraries already loaded
    code = f"P = {str(path)!r}\nCAL = {str(cal)!r}\nOUT = {str(out)!r}\nimport numpy\nfrom threadpoolctl import threadpool_limits\nthreadpool_limits(1, 'blas')\n{MODES[mode]}\nimport accellog, sys; print(accellog.__file__, file=sys.stderr)"
    t0 = time.perf_counter()
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(tree), *filter(None, [env.get("PYTHONPATH")])])
    r = subprocess.run(
        ["/usr/bin/time", "-f", "%M %U %S", sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env=env,
        cwd=path.parent,  # not a checkout: `python -c` puts the working directory first on sys.path
    )
    wall = time.perf_counter() - t0
    if r.returncode:
        raise SystemExit(f"{mode}: {r.stderr[-2000:]}")
    out.unlink(missing_ok=True)
    *_, used, times = r.stderr.strip().splitlines()
    if tree is not None and not Path(used).resolve().is_relative_to(Path(tree).resolve()):
        raise SystemExit(f"{mode}: imported {used}, not the baseline {tree}")
    rss_kb, user_s, sys_s = times.split()
    return wall, int(rss_kb) / 1024, float(user_s) + float(sys_s)


def _calibration(d: Path) -> Path:
    """model3 fitted on a 10 min synth_long session (the calibration the static modes evaluate)."""
    from accellog.flows.stages import run_fit

    if (d / "cal.json").exists():
        return d / "cal.json"
    src = write_long(d / "cal.mcap", 600.0, seed=7)
    run_fit(src).cal.save(d / "cal.json")
    return d / "cal.json"


def _session(d: Path, kind: str, hours: float, keep: bool) -> Path:
    """The static or labelled session of that length in d (reused when keep and already there)."""
    name = f"{kind}_{hours:g}h.mcap" if keep else f"{kind}.mcap"
    path = d / name
    if keep and path.exists():
        return path
    if kind == "static":
        return write_static(path, hours * 3600.0, seed=1)
    return write_long(path, hours * 3600.0, seed=1)


def _row(label: str, mb: float, mode: str, wall: float, cpu: float, peak: float, extra: str = "") -> None:
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    print(
        f"{label:>8} {mb:>8.1f} {mode:>16} {wall:>8.2f} {cpu:>7.2f} {peak:>8.0f}  {load}{extra}", flush=True
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--hours", type=float, nargs="+", default=[1 / 60, 1.0, 4.0])
    ap.add_argument("--modes", nargs="+", default=list(MODES))
    ap.add_argument("--dir", type=Path, help="keep the sessions here and reuse them")
    ap.add_argument("--baseline", type=Path, help="a source tree to run every mode with as well")
    args = ap.parse_args()
    print(
        f"{'session':>8} {'file MB':>8} {'mode':>16} {'wall s':>8} {'CPU s':>7} {'peak MB':>8}  load average"
    )
    with tempfile.TemporaryDirectory(dir="/tmp") as tmp:
        d = args.dir or Path(tmp)
        d.mkdir(parents=True, exist_ok=True)
        static = [m for m in args.modes if m in STATIC_MODES]
        cal = _calibration(d) if static else None
        for h in args.hours:
            label = f"{h * 60:.0f} min" if h < 1 else f"{h:g} h"
            for kind, modes in (
                ("labelled", [m for m in args.modes if m not in STATIC_MODES]),
                ("static", static),
            ):
                if not modes:
                    continue
                path = _session(d, kind, h, args.dir is not None)
                mb = path.stat().st_size / 1e6
                for mode in modes:
                    wall, peak, cpu = run(mode, path, cal)
                    _row(label, mb, mode, wall, cpu, peak)
                    if args.baseline is not None:
                        w0, p0, c0 = run(mode, path, cal, args.baseline)
                        _row(label, mb, "  (baseline)", w0, c0, p0, f"   CPU {cpu / c0:.2f}x the baseline")
                if args.dir is None:
                    path.unlink()


if __name__ == "__main__":
    main()
