"""Make docs/images/residual_vs_temperature.png: the workbench's residual-vs-temperature plots of a
warm-up session with a hidden quadratic bias-temperature curve, before (model3: sloped, curved) and
after (the model the workbench chose with a held-out session: flat).

    python tools/residual_screenshot.py [--out docs/images/residual_vs_temperature.png]

Two emulated 200 Hz sessions (24 poses x 6 s, two different warm-ups) go through the real path
(emulator -> driver -> MCAP), `discover --heldout` chooses the model, the residual views are written
to an .rrd (accellog.present.residual_views) and `accellog view --screenshot` takes the picture
(headless Chromium; needs chromium from apt).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
os.environ.setdefault("RERUN_ANALYTICS", "0")

from accellog.calibrate.model.compose import build_model  # noqa: E402
from accellog.calibrate.model.fit import fit_model  # noqa: E402
from accellog.calibrate.observe.segment import observations  # noqa: E402
from accellog.flows.simulate import Scenario, simulate  # noqa: E402
from accellog.flows.workbench import discover  # noqa: E402
from accellog.present.residual_views import contribution_g, log_panels, panels  # noqa: E402
from accellog.present.rrd.recording import RunRecording  # noqa: E402
from accellog.present.viewer import screenshot_rrd  # noqa: E402
from accellog.store.reader import read_session  # noqa: E402

CHIP = {
    "bias_g": [0.04, -0.03, 0.06],
    "scale": [0.02, -0.01, 0.015],
    "noise_density_g_per_rtHz": 300e-6,
    "temp_bias_g_per_degC": [1.0e-3, -0.8e-3, 1.2e-3],
    "temp_bias2_g_per_degC2": [6e-5, -5e-5, 7e-5],
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "images" / "residual_vs_temperature.png")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        obs = {}
        for name, seed, T0, T1, tau in (("cal", 1, 24.0, 40.0, 80.0), ("held", 2, 22.0, 36.0, 50.0)):
            sc = Scenario(
                protocol="24",
                hold_s=6.0,
                move_s=2.0,
                sample_rate_hz=200.0,
                errors="perfect",
                set=CHIP,
                seed=seed,
                temperature={"kind": "warmup", "T_start": T0, "T_end": T1, "tau_s": tau},
            )
            simulate(sc, Path(d) / f"{name}.mcap")
            obs[name] = observations(read_session(Path(d) / f"{name}.mcap"))
        found = discover(obs["cal"], "model3", heldout=obs["held"])
        start = fit_model(obs["cal"], build_model("model3"))
        final = fit_model(obs["cal"], build_model(found.final_model))
        print(found.verdict)
        rrd = Path(d) / "residuals.rrd"
        with RunRecording(f"save:{rrd}") as rec:
            # temperature only: the picture of the README
            fits = {"before model3": start, f"after {found.final_model}": final}
            log_panels(
                rec,
                [
                    p
                    for p in panels(
                        obs["cal"], fits, {"before model3": contribution_g(start, final, obs["cal"])}
                    )
                    if p.driver == "temp_degC"
                ],
            )
        a.out.parent.mkdir(parents=True, exist_ok=True)
        stats = screenshot_rrd(rrd, a.out, size=(1200, 800))
        print(f"{a.out}: {stats.colors} colours, {100 * stats.non_background:.0f}% drawn")


if __name__ == "__main__":
    main()
