"""Do the reported 1-sigma cover the truth when holds scatter more than the noise? (issue #10, item 4)

Many seeded 24-pose sessions (window means from the measurement equation, tests/support/synthetic.py)
of one chip, with hold-level disturbances the window noise does not describe:

- placement repeatability: each hold's true orientation is off by a random tilt (--tilt-deg rms per
  axis), f_true = R(delta_h) f_nominal, so every window of the hold carries the same error;
- slow bias wander: the bias is off by a random amount during each hold, independent between holds
  and zero-mean (--wander-mg rms), so the session's bias is still the estimand.

Each session is fitted with model3 (window-weighted) and its uncertainty computed three ways
(accellog.calibrate.model.variance): noise only, between-hold variance component, leave-one-hold-out
jackknife. Printed per method: RMS over seeds and parameters of (estimate - truth) / sigma (1 when
sigma is honest; goal 0.9-1.2) per parameter group, with its statistical 1-sigma from the seed count,
and the mean estimated between-hold scatter vs the injected one.

    python benchmarks/bench_hold_scatter.py [--n 200] [--tilt-deg 0.1] [--wander-mg 0.3] [--windows 6]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.calibrate.model.variance import with_uncertainty

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.synthetic import hold_disturbance, synthetic_obs, true_theta

GROUPS = {"b": slice(0, 3), "S_ii": slice(3, 6), "S_ij": slice(6, 12)}


def run(n: int, tilt_deg: float, wander_mg: float, windows: int) -> dict:
    model = build_model("model3")
    th = true_theta(model, seed=1)
    z = {m: [] for m in ("noise", "between_hold", "jackknife")}
    tau = []
    t0 = time.perf_counter()
    for seed in range(n):
        extra = hold_disturbance(np.deg2rad(tilt_deg), wander_mg * 1e-3, seed)
        obs = synthetic_obs(
            model, th, protocol="24", hold_s=20.0, windows_per_hold=windows, extra=extra, seed=seed
        )
        res = fit_model(obs, model)
        for m in z:
            r = with_uncertainty(res, obs, m)
            z[m].append((r.theta - th) / r.sigma)
            if m == "between_hold":
                tau.append(r.between_hold_g)
    return {
        "z": {m: np.asarray(v) for m, v in z.items()},
        "tau_mg": 1e3 * np.mean(tau, axis=0),
        "seconds": time.perf_counter() - t0,
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--tilt-deg", type=float, default=0.1)
    ap.add_argument("--wander-mg", type=float, default=0.3)
    ap.add_argument("--windows", type=int, default=6)
    a = ap.parse_args(argv)
    out = run(a.n, a.tilt_deg, a.wander_mg, a.windows)
    print(
        f"{a.n} seeds, 24 poses x 20 s, {a.windows} windows per hold; placement tilt {a.tilt_deg} deg rms, "
        f"bias wander {a.wander_mg} mg per hold; {out['seconds']:.1f} s; loadavg {os.getloadavg()}"
    )
    print(f"estimated between-hold scatter (mg, along / across gravity): {np.round(out['tau_mg'], 3)}")
    print(f"{'method':<14}" + "".join(f"{g:>16}" for g in [*GROUPS, "all"]) + "   (RMS z; goal 0.9-1.2)")
    for m, zz in out["z"].items():
        cells = []
        for sl in [*GROUPS.values(), slice(0, 12)]:
            v = zz[:, sl]
            rms = float(np.sqrt(np.mean(v**2)))
            se = rms / np.sqrt(2.0 * v.size / (sl.stop - sl.start))  # ~ independent per seed and group
            cells.append(f"{rms:8.2f} +- {se:4.2f}")
        print(f"{m:<14}" + "".join(f"{c:>16}" for c in cells))


if __name__ == "__main__":
    main()
