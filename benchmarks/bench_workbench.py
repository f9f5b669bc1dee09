"""Workbench speed: 24 poses x 30 s at 1 kHz with a held-out session < 10 s (issue #10).

Two sessions of one emulated chip with a hidden quadratic bias-temperature curve on two different
warm-ups are simulated through the real recording path (emulator -> driver -> Recorder -> MCAP).
Timed in the same run, on the same files:

- baseline: read both MCAP files, cut 2 s windows, fit model3 once (what `fit` costs);
- workbench: what `accellog workbench CAL --heldout HELD --json` does: the same reading and
  windowing, then `discover` (diagnose + out-of-sample choice per step, held-out session) and the
  ladder (`ladder_rows`: model1 -> final); then again with the gyro calibration of the final model
  that `-o` / `--rrd` add.

With --more, two further cases of the same chip (each against its own baseline, same run):

- leave one session out: `accellog workbench A B C --json` on three labelled warm-ups (baseline:
  read the three, windows, fit model3 on all windows);
- hand-held: `accellog workbench HAND --heldout HAND2 --json` on two sessions of 18 tilted holds
  with their labels removed (baseline: read both, detect the static intervals of both, one
  orientation-free fit).

Prints seconds, the ratio workbench / baseline, peak traced memory, what was found and the load
average (the machine is shared).

    python benchmarks/bench_workbench.py [--hold 30] [--rate 1000] [--more]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import tracemalloc
from pathlib import Path

from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.calibrate.observe.segment import observations
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


EDGES = "+z,-z,+y,-y,+x,-x,+x+y,-x-y,+x-y,-x+y,+x+z,-x-z,+x-z,-x+z,+y+z,-y-z,+y-z,-y+z"
WARMUPS = (("cal", 1, 24.0, 40.0, 250.0), ("held", 2, 22.0, 36.0, 150.0), ("third", 3, 28.0, 44.0, 300.0))


def sessions(
    root: Path,
    hold_s: float,
    rate_hz: float,
    which=WARMUPS[:2],
    protocol: str = "24",
    unlabelled: bool = False,
) -> list[Path]:
    out = []
    for name, seed, T0, T1, tau in which:
        sc = Scenario(
            protocol=protocol,
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
        if unlabelled:  # the same recording as a hand-held one: no pose labels
            import dataclasses

            from accellog.store.writer import write_session

            p = write_session(root / f"{name}_hand.mcap", dataclasses.replace(read_session(p), poses=[]))
        out.append(p)
    return out


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
    ap.add_argument("--more", action="store_true", help="also leave-one-session-out and hand-held")
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
    if a.more:
        more(a.hold, a.rate)


def more(hold_s: float, rate_hz: float) -> None:
    """Leave one session out (three labelled warm-ups) and a hand-held session with a held-out one."""
    from accellog.calibrate.diagnosis.loso import concat_obs
    from accellog.calibrate.model.effects import HANDHELD_START
    from accellog.calibrate.model.fit import fit_orientation_free
    from accellog.calibrate.observe.detected_holds import detect_holds
    from accellog.flows.workbench import run_workbench

    with tempfile.TemporaryDirectory() as d:
        paths = sessions(Path(d), hold_s, rate_hz, WARMUPS)

        def base3():
            obs = concat_obs([observations(read_session(p)) for p in paths])
            return fit_model(obs, build_model("model3"))

        _, t_b, m_b = timed(base3)
        out, t_w, m_w = timed(lambda: run_workbench(paths))
        print(
            f"\nleave one session out, 3 x 24 poses x {hold_s:g} s at {rate_hz:g} Hz; loadavg {os.getloadavg()}"
        )
        print(f"baseline (read 3 + windows + fit model3 on all): {t_b:6.2f} s, peak {m_b:6.1f} MiB")
        print(f"workbench A B C --json:                          {t_w:6.2f} s, peak {m_w:6.1f} MiB")
        print(
            f"ratio {t_w / t_b:.1f}; found {out.found.final_model}; per session held-out chi2/dof "
            f"{[round(p['heldout_chi2_dof'], 2) for p in out.found.loso]}"
        )
    with tempfile.TemporaryDirectory() as d:
        hand, hand2 = sessions(Path(d), hold_s, rate_hz, WARMUPS[:2], protocol=EDGES, unlabelled=True)

        def base_hand():
            o1 = detect_holds(read_session(hand))[0]
            detect_holds(read_session(hand2))
            return fit_orientation_free(o1, build_model(HANDHELD_START))

        _, t_b, m_b = timed(base_hand)
        out, t_w, m_w = timed(lambda: run_workbench(hand, heldout=[hand2]))
        print(
            f"\nhand-held, 18 tilted holds x {hold_s:g} s at {rate_hz:g} Hz + held-out; loadavg {os.getloadavg()}"
        )
        print(f"baseline (read 2 + detect both + orientation-free fit): {t_b:6.2f} s, peak {m_b:6.1f} MiB")
        print(f"workbench HAND --heldout HAND2 --json:                  {t_w:6.2f} s, peak {m_w:6.1f} MiB")
        print(f"ratio {t_w / t_b:.1f}; found {out.found.final_model}; held-out {out.found.heldout}")


if __name__ == "__main__":
    main()
