"""`accellog noise` on a long 1 kHz static session: wall time and peak memory, and the ratio to allantools.

    python benchmarks/bench_noise.py [--hours 4] [--rate 1000] [--session PATH]

1. Simulates (or reuses ``--session``) a static '+z' session through the real recording path
   (``accellog.flows.simulate``: emulated chip -> FIFO driver -> Recorder -> MCAP), datasheet white noise
   plus accelerometer bias instability 40 ug and random walk 2 ug/s/rtHz.
   The simulation runs in its own subprocess so the measuring children start from a small parent (Linux
   ru_maxrss of a child counts the parent's memory at fork).
2. In a fresh subprocess: ``characterise_noise`` (streamed read + overlapping ADEV of 6 columns + fits);
   wall time and peak RSS (ru_maxrss, includes the interpreter and numpy/scipy, ~100 MB).
3. In another subprocess, the baseline: ``read_session`` (whole file) then ``allantools.oadev`` (octave
   taus, data_type='freq') on the same 6 columns; and our ``oadev`` on the same in-memory arrays. Ratios
   are allantools / ours on the ADEV computation alone and end to end.
Every figure is printed with os.getloadavg(): the machine is shared.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_OURS = r"""
import json, resource, sys, time
from accellog.flows.characterise import characterise_noise
t = time.perf_counter(); m = characterise_noise(sys.argv[1]); dt = time.perf_counter() - t
print(json.dumps({"wall_s": dt, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "n": m.n_samples, "accel_N": [a.white.value for a in m.accel.axes]}))
"""

_SIM = r"""
import json, sys
from accellog.flows.simulate import Scenario, simulate
sc = Scenario(protocol="+z", hold_s=float(sys.argv[2]), sample_rate_hz=float(sys.argv[3]), seed=5,
              set={"bias_instability_g": [40e-6] * 3, "random_walk_g_per_s_rtHz": [2e-6] * 3})
simulate(sc, sys.argv[1])
print(json.dumps({}))
"""

_BASE = r"""
import json, resource, sys, time
import numpy as np, allantools
from accellog.store.reader import read_session
from accellog.calibrate.noise.allan import oadev
t0 = time.perf_counter(); s = read_session(sys.argv[1])
y = np.concatenate([s.accel_g * 9.80665, np.deg2rad(s.gyro_dps)], axis=1); rate = s.meta.sample_rate_hz
t1 = time.perf_counter()
ad = [allantools.oadev(y[:, k], rate=rate, data_type="freq", taus="octave")[1] for k in range(6)]
t2 = time.perf_counter(); ours = oadev(y, rate); t3 = time.perf_counter()
n = ours.m.size
rel = max(float(np.max(np.abs(ours.adev[ours.stride == 1, k] / ad[k][: n][ours.stride == 1] - 1))) for k in range(6))
print(json.dumps({"read_s": t1 - t0, "allantools_s": t2 - t1, "ours_inmem_s": t3 - t2, "max_rel_diff_exact": rel,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def _run(code: str, path: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run(
        [sys.executable, "-c", code, str(path)], capture_output=True, text=True, env=env, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--hours", type=float, default=4.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--session", type=Path, default=None, help="reuse (or create) this MCAP file")
    ap.add_argument("--no-baseline", action="store_true")
    a = ap.parse_args()
    path = a.session or Path(f"/tmp/accellog_noise_{a.hours:g}h_{a.rate:g}Hz.mcap")
    if not path.exists():  # in a subprocess: ru_maxrss of later children must not inherit a big parent
        t = time.perf_counter()
        _run(_SIM, path, f"{a.hours * 3600.0!r}", f"{a.rate!r}")
        print(
            f"simulated {path} ({path.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t:.0f} s, "
            f"load {os.getloadavg()}"
        )
    ours = _run(_OURS, path)
    print(
        f"accellog noise: {ours['n']} samples, {ours['wall_s']:.1f} s wall, peak RSS {ours['peak_rss_mb']:.0f} MB "
        f"(goal < 60 s, < 500 MB); load {os.getloadavg()}"
    )
    if a.no_baseline:
        return
    base = _run(_BASE, path)
    print(
        f"baseline (read_session + allantools.oadev x6): read {base['read_s']:.1f} s, allantools {base['allantools_s']:.1f} s, "
        f"our oadev on the same arrays {base['ours_inmem_s']:.1f} s, peak RSS {base['peak_rss_mb']:.0f} MB; "
        f"max relative ADEV difference (exact taus) {base['max_rel_diff_exact']:.1e}; load {os.getloadavg()}"
    )
    print(
        f"ratios: ADEV computation allantools / ours = {base['allantools_s'] / base['ours_inmem_s']:.2f}; "
        f"end to end (read + allantools) / accellog noise = {(base['read_s'] + base['allantools_s']) / ours['wall_s']:.2f}; "
        f"peak memory baseline / ours = {base['peak_rss_mb'] / ours['peak_rss_mb']:.1f}"
    )


if __name__ == "__main__":
    main()
