"""Emulated calibration sessions for the workbench's discovery loop (tests and
benchmarks/bench_discovery.py): a chip with model3's terms plus hidden effects, recorded through the
real path (emulator -> driver -> recorder -> MCAP) and cut into windows.

Scenarios (name -> chip error fields besides model3's and the temperature paths):

- ``rate``: a bias following the rate of the die temperature, b += r dT/dt (outside the library);
- ``hysteresis``: a linear bias tempco (library: temp_bias, the in-library part) and a thermal
  hysteresis, b += h s(t), s = -1 heating / +1 cooling (outside the library);
- ``two``: two library effects at once, temp_bias and time_drift;
- ``single``: one library effect, temp_bias (the succeeding search the failing ones are timed against);
- ``clean``: model3's terms only (nothing to add);
- ``quadratic``: a quadratic temperature bias, temp_bias and temp_bias2 (library), warm-ups;
- ``tilt``: a tilted fixture (fixture_tilt, library; the 24-pose protocol, ``TILT_DEG``);
- ``nonlin``: an input nonlinearity, nonlin2 (library);
- ``temp_nonlin``: temp_bias, temp_bias2 and nonlin2 at once (library), warm-ups.

Calibration and held-out sessions of one scenario share the chip and differ in noise seed and
temperature path (a warm-up of another amplitude and time constant, or heat/cool in another order).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from accellog.calibrate.observe.segment import observations
from accellog.core.session import ObsTable
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session

MODEL3_CHIP: dict[str, Any] = {
    "bias_g": [0.030, -0.020, 0.050],
    "scale": [0.010, -0.020, 0.015],
    "cross_axis": [[0.0, 0.005, -0.004], [0.003, 0.0, 0.006], [-0.005, 0.002, 0.0]],
    "noise_density_g_per_rtHz": [300e-6] * 3,
}
SIX = "+z,-z,+y,-y,+x,-x"
EDGES = SIX + ",+x+y,-x-y,+x-y,-x+y,+x+z,-x-z,+x-z,-x+z,+y+z,-y-z,+y-z,-y+z"

HIDDEN: dict[str, dict[str, Any]] = {
    "rate": {"temp_rate_bias_g_per_degC_per_s": [0.04, -0.03, 0.05]},
    "hysteresis": {
        "temp_bias_g_per_degC": [1.0e-3, -0.8e-3, 1.2e-3],
        "temp_hysteresis_g": [2.0e-3, -1.5e-3, 2.5e-3],
        "temp_hysteresis_width_degC": 3.0,
    },
    "two": {
        "temp_bias_g_per_degC": [1.0e-3, -0.8e-3, 1.2e-3],
        "time_drift_g_per_s": [1.5e-5, -1.0e-5, 1.2e-5],
    },
    "single": {"temp_bias_g_per_degC": [1.0e-3, -0.8e-3, 1.2e-3]},
    "clean": {},
    "quadratic": {
        "temp_bias_g_per_degC": [1.0e-3, -0.8e-3, 1.2e-3],
        "temp_bias2_g_per_degC2": [6e-5, -5e-5, 7e-5],
    },
    "tilt": {},
    "nonlin": {"nonlin2_per_g": [4e-3, -3e-3, 5e-3]},
    "temp_nonlin": {
        "temp_bias_g_per_degC": [1.0e-3, -0.8e-3, 1.2e-3],
        "temp_bias2_g_per_degC2": [6e-5, -5e-5, 7e-5],
        "nonlin2_per_g": [4e-3, -3e-3, 5e-3],
    },
}
"""Hidden chip error fields (accellog.acquire.emulator.sensor_model.AccelErrors) per scenario."""
TILT_DEG: dict[str, tuple[float, float]] = {"tilt": (0.3, -0.2)}
"""Fixture tilt (deg about x, y) per scenario; none elsewhere."""


def _temperature(name: str, held: bool, duration_s: float) -> dict[str, Any]:
    """Warm-ups (calibration 24 -> 40 degC, tau 0.3 duration; held-out 22 -> 34, tau 0.15) or, for
    hysteresis, heat then cool (calibration) / cool, heat, cool (held-out) as piecewise-linear paths."""
    if name == "hysteresis":
        d = duration_s
        if held:
            return {"kind": "points", "t_s": [0, 0.3 * d, 0.65 * d, d], "T": [34.0, 24.0, 38.0, 28.0]}
        return {"kind": "points", "t_s": [0, 0.5 * d, d], "T": [24.0, 40.0, 26.0]}
    if held:
        return {"kind": "warmup", "T_start": 22.0, "T_end": 34.0, "tau_s": 0.15 * duration_s}
    return {"kind": "warmup", "T_start": 24.0, "T_end": 40.0, "tau_s": 0.3 * duration_s}


def scenario(
    name: str, seed: int, held: bool = False, *, rounds: int = 3, hold_s: float = 10.0, poses: str = SIX
) -> Scenario:
    """The scenario's calibration (or held-out) session: `rounds` rounds of `poses` (the six faces;
    EDGES for hand-held sessions, which need >= 9 orientations) and a final +z, holds of hold_s s,
    2 s moves, 200 Hz. poses "24": the 24-pose fixture protocol, `rounds` times, no final +z."""
    if poses == "24":
        protocol, n_holds = ",".join(["24"] * rounds), 24 * rounds
    else:
        protocol, n_holds = ",".join([poses] * rounds + ["+z"]), len(poses.split(",")) * rounds + 1
    duration = n_holds * (hold_s + 2.0) + 1.0
    return Scenario(
        protocol=protocol,
        hold_s=hold_s,
        move_s=2.0,
        sample_rate_hz=200.0,
        errors="perfect",
        gyro_errors="perfect",
        set={**MODEL3_CHIP, **HIDDEN[name]},
        seed=seed,
        temperature=_temperature(name, held, duration),
        fixture_tilt_deg=TILT_DEG.get(name, (0.0, 0.0)),
    )


def session_path(root: Path, name: str, seed: int, held: bool = False, **kw: Any) -> Path:
    """The scenario's session as an MCAP file in root (simulated on first use)."""
    tag = {EDGES: "_edges", "24": "_24"}.get(kw.get("poses", SIX), "")
    which = "held" if held else "cal"
    p = Path(root) / f"{name}_{seed}_{which}_{kw.get('rounds', 3)}_{kw.get('hold_s', 10.0):g}{tag}.mcap"
    if not p.exists():
        simulate(scenario(name, seed, held, **kw), p)
    return p


def session_obs(root: Path, name: str, seed: int, held: bool = False, **kw: Any) -> ObsTable:
    """Windows (2 s) of the scenario's session (session_path) read back."""
    return observations(read_session(session_path(root, name, seed, held, **kw)), window_s=2.0)


def handheld_path(
    root: Path, name: str, seed: int, held: bool = False, rounds: int = 1, hold_s: float = 8.0
) -> Path:
    """The scenario recorded over the six faces and 12 cube edges, written again without its pose
    labels: a hand-held session."""
    import dataclasses

    from accellog.store.writer import write_session

    p = session_path(root, name, seed, held, rounds=rounds, hold_s=hold_s, poses=EDGES)
    q = p.with_name(p.stem + "_hand.mcap")
    if not q.exists():
        write_session(q, dataclasses.replace(read_session(p), poses=[]))
    return q
