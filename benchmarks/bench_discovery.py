"""Discovery when the library lacks the effect (issue 25, "Also"): seed sweeps of the workbench loop.

Scenarios (tests/support/discovery.py), each a calibration and a held-out session of one emulated
chip recorded through the real path (emulator -> driver -> recorder -> MCAP), model3's terms plus:

- rate:       a bias following dT/dt (outside the library), warm-ups;
- hysteresis: a thermal hysteresis (outside the library), heat then cool;
- two:        temp_bias and time_drift at once (library), warm-ups;
- single:     temp_bias alone (library): the succeeding search the failing ones are timed against.

Per seed and scenario: what `discover(cal, "model3", heldout=held)` added and dropped, whether the
verdict names "no library effect", the final model's held-out chi2/dof, the largest |b_final -
b_model3| / sigma_b(model3) over the axes, and the loop's CPU time (process time: the machine is
shared). Checks (issue 25): out of library -> "no library effect" and bias within 3 sigma of model3's;
two effects -> held-out chi2/dof < 2 in >= 2/3 seeds; CPU of a failing search <= 2x a succeeding one
(ratio of medians, same run).

With --numeric each loop runs again with central-difference Jacobians (the baseline of the
analytic ones, calibrate.model_jacobian), same choices asserted.

    python benchmarks/bench_discovery.py [--seeds 6] [--rounds 3] [--hold 10] [--numeric]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.discovery import session_obs

from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.flows.workbench import discover

SCENARIOS = ("rate", "hysteresis", "two", "single")
OUT_OF_LIBRARY = ("rate", "hysteresis")


def run_one(root: Path, name: str, seed: int, rounds: int, hold_s: float, numeric: bool = False) -> dict:
    """One workbench loop on a scenario's calibration session with its held-out session."""
    kw = {"rounds": rounds, "hold_s": hold_s}
    cal = session_obs(root, name, seed, **kw)
    held = session_obs(root, name, seed + 100, held=True, **kw)
    t0 = time.process_time()
    found = discover(cal, "model3", heldout=held)
    cpu = time.process_time() - t0
    cpu_numeric = np.nan
    if numeric:  # the same loop with central differences for every column (the baseline)
        import accellog.calibrate.model.fit as fit_mod

        analytic, fit_mod._Problem.analytic = fit_mod._Problem.analytic, None
        try:
            t0 = time.process_time()
            again = discover(cal, "model3", heldout=held)
            cpu_numeric = time.process_time() - t0
        finally:
            fit_mod._Problem.analytic = analytic
        assert again.added == found.added, (again.added, found.added)
    m3 = fit_model(cal, build_model("model3"))
    fin = fit_model(cal, build_model(found.final_model))
    return {
        "scenario": name,
        "seed": seed,
        "added": list(found.added),
        "dropped": [d["effect"] for d in found.dropped],
        "no_library": "no library effect" in found.verdict,
        "heldout_chi2_dof": found.heldout["heldout_chi2_dof"],
        "bias_z": float(np.max(np.abs((fin.b - m3.b) / m3.sigma[:3]))),
        "cpu_s": cpu,
        "cpu_numeric_s": cpu_numeric,
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--rounds", type=int, default=3, help="rounds of the six faces per session")
    ap.add_argument("--hold", type=float, default=10.0, help="hold length (s)")
    ap.add_argument("--numeric", action="store_true", help="also time each loop with difference Jacobians")
    a = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for seed in range(1, a.seeds + 1):
            for name in SCENARIOS:
                r = run_one(Path(d), name, seed, a.rounds, a.hold, a.numeric)
                rows.append(r)
                print(
                    f"{name:10s} seed {seed:2d}: added {'+'.join(r['added']) or '-':22s} dropped "
                    f"{'+'.join(r['dropped']) or '-':16s} no-library {r['no_library']!s:5s} held-out "
                    f"chi2/dof {r['heldout_chi2_dof']:8.3g}  |db|/sigma {r['bias_z']:8.3g}  cpu {r['cpu_s']:5.2f} s"
                    + (f" (differences {r['cpu_numeric_s']:5.2f} s)" if a.numeric else ""),
                    flush=True,
                )
    by = {n: [r for r in rows if r["scenario"] == n] for n in SCENARIOS}
    out = [r for n in OUT_OF_LIBRARY for r in by[n]]
    ok_out = sum(r["no_library"] and r["bias_z"] <= 3.0 for r in out)
    ok_two = sum(r["heldout_chi2_dof"] < 2.0 for r in by["two"])
    cpu_fail = float(np.median([r["cpu_s"] for r in out]))
    cpu_ok = float(np.median([r["cpu_s"] for r in by["single"]]))
    print(
        f"\n{a.seeds} seeds, {a.rounds} rounds of six faces + '+z', holds {a.hold:g} s; loadavg {os.getloadavg()}"
    )
    print(f"out of library: 'no library effect' with bias within 3 sigma of model3's in {ok_out}/{len(out)}")
    print(f"two library effects: held-out chi2/dof < 2 in {ok_two}/{len(by['two'])} (goal >= 2/3)")
    print(
        f"CPU median: failing search {cpu_fail:.2f} s, succeeding (single) {cpu_ok:.2f} s, "
        f"ratio {cpu_fail / cpu_ok:.2f} (goal <= 2)"
    )
    if a.numeric:
        num, ana = sum(r["cpu_numeric_s"] for r in rows), sum(r["cpu_s"] for r in rows)
        print(
            f"CPU of all loops: difference Jacobians {num:.2f} s, analytic {ana:.2f} s, ratio {num / ana:.2f}"
        )


if __name__ == "__main__":
    main()
