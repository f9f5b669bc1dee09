"""Workbench speed: 24 poses x 30 s at 1 kHz with a held-out session < 10 s (issue #10).

Two sessions of one emulated chip with a hidden quadratic bias-temperature curve on two different
warm-ups are simulated through the real recording path (emulator -> driver -> Recorder -> MCAP).
Timed in the same run, on the same files:

- baseline: read both MCAP files, cut 2 s windows, fit model3 once (what `fit` costs);
- workbench: what `accellog workbench CAL --heldout HELD --json` does: the same reading and
  windowing, then `discover` (diagnose + out-of-sample choice per step, held-out session) and the
  ladder (`ladder_rows`: model1 -> final); then again with the gyro calibration of the final model
  that `-o` / `--rrd` add.

Prints seconds, the ratio workbench / baseline, peak traced memory, what was found and the load
average (the machine is shared).

    python benchmarks/bench_workbench.py [--hold 30] [--rate 1000]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import tracemalloc
from pathlib import Path

from accellog.calibrate.fit import fit_model
from accellog.calibrate.model import build_model
from accellog.calibrate.segment import observations
from accellog.flows.simulate import Scenario, simulate
from accellog.flows.workbench import discover, ladder_rows, steps_for
from accellog.store.reader import read_session

CHIP = {
    "bias_g": [0.04, -0.03, 0.06],
    "scale": [0.02, -0.01, 0.015],
    "noise_density_g_per_rtHz": 300e-6,
    "temp_bias_g_per_degC": [1.0e-3, -0.8e-3, 1.2e-3],
    "temp_bias2_g_per_degC2": [6e-5, -5e-5, 7e-5],
}


def sessions(root: Path, hold_s: float, rate_hz: float) -> tuple[Path, Path]:
    out = []
    for name, seed, T0, T1, tau in (("cal", 1, 24.0, 40.0, 250.0), ("held", 2, 22.0, 36.0, 150.0)):
        sc = Scenario(
            protocol="24",
            hold_s=hold_s,
            move_s=3.0,
            sample_rate_hz=rate_hz,
            errors="perfect",
            set=CHIP,
            seed=seed,
            temperature={"kind": "warmup", "T_start": T0, "T_end": T1, "tau_s": tau},
        )
        p = root / f"{name}.mcap"
        simulate(sc, p)
        out.append(p)
    return out[0], out[1]


def timed(fn):
    """(result, seconds, peak MiB): seconds from a plain run, peak memory from a second, traced
    run (tracemalloc slows Python code down, so it never times)."""
    t0 = time.perf_counter()
    r = fn()
    dt = time.perf_counter() - t0
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return r, dt, peak / 2**20


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hold", type=float, default=30.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        cal_p, held_p = sessions(Path(d), a.hold, a.rate)

        def baseline():
            s = read_session(cal_p)
            obs = observations(s)
            observations(read_session(held_p))
            return fit_model(obs, build_model("model3"))

        def workbench(gyro: bool):
            s = read_session(cal_p)
            obs = observations(s)
            held = observations(read_session(held_p))
            found = discover(obs, "model3", heldout=held)
            ladder_rows(s, obs, steps_for(found), heldout=held, gyro=gyro)
            return found, s.n

        _, t_base, m_base = timed(baseline)
        (found, n), t_wb, m_wb = timed(lambda: workbench(False))
        _, t_gyro, _ = timed(lambda: workbench(True))
    print(
        f"24 poses x {a.hold:g} s at {a.rate:g} Hz ({n} samples) + held-out session; loadavg {os.getloadavg()}"
    )
    print(f"baseline (read + windows + fit model3): {t_base:6.2f} s, peak {m_base:6.1f} MiB")
    print(f"workbench --heldout --json:              {t_wb:6.2f} s, peak {m_wb:6.1f} MiB  (goal < 10 s)")
    print(f"  + gyro calibration of the final model (-o): {t_gyro:6.2f} s")
    print(f"ratio workbench / baseline: {t_wb / t_base:.1f}")
    print(f"found: {found.final_model}; {found.verdict}")


if __name__ == "__main__":
    main()
