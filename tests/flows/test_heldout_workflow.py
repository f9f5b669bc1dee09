"""The held-out check a reviewer runs on unseen data, through the CLI only.

An emulated session with a hidden effect is exported to a generic CSV (header
t,ax,ay,az,temp,gx,gy,gz,pose; accelerometer in g; pose names '+x'..'-z' or '+z@90', empty between
holds), as any logger would write it. Then:

    accellog import csv cal.csv --unit g -o cal.mcap
    accellog diagnose cal.mcap --json                      -> top candidate
    accellog fit cal.mcap --model model3 [--add TOP] -o cal.json --json
    accellog evaluate heldout.mcap --cal m3.json --cal top.json --json

on a held-out multi-pose session (another noise seed and temperature path, same chip) and on a
single static hold of 65 s. evaluate's JSON must give the residual RMS, per-axis mean residuals,
chi-square against the noise estimate and the displacement at 60 s for both kinds of session, and
the error must fall when the top candidate is added.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

from accellog.cli import main
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session

RATE_HZ = 200.0
CHIP = {
    "bias_g": [0.040, -0.030, 0.060],
    "scale": [0.012, -0.018, 0.020],
    "cross_axis": [[0.0, 0.004, -0.006], [0.005, 0.0, 0.003], [-0.002, 0.006, 0.0]],
    "noise_density_g_per_rtHz": [300e-6] * 3,
}
"""model3 terms of the chip (g, scale deviation, cross-axis) and its noise density (g/sqrt(Hz))."""

SIX2 = "+z,-z,+y,-y,+x,-x,+x,-x,+y,-y,+z,-z"
REQUIRED = {"rms_mps2", "mean_residual_mps2", "chi2_noise", "chi2_noise_dof", "displacement_60s_m"}
"""What evaluate --json must report for a multi-pose session and for a single static hold."""

CASES = {
    # die temperature: a slow warm-up then cool-down (calibration), the reverse (held-out)
    "temp_bias": {
        "set": {"temp_bias_g_per_degC": [0.6e-3, -0.5e-3, 0.8e-3]},
        "protocol": SIX2,
        "hold_s": 10.0,
        "cal_T": {"kind": "points", "t_s": [0.0, 70.0, 145.0], "T": [24.0, 31.0, 26.0]},
        "held_T": {"kind": "points", "t_s": [0.0, 70.0, 145.0], "T": [30.0, 24.5, 29.0]},
        "static_T": {"kind": "points", "t_s": [0.0, 66.0], "T": [31.0, 29.0]},
        "tilt_deg": (0.0, 0.0),
    },
    # the table is not level: 24 poses named '+z@90' etc.
    "fixture_tilt": {
        "set": {},
        "protocol": "24",
        "hold_s": 6.0,
        "cal_T": {"kind": "constant", "T": 25.0},
        "held_T": {"kind": "constant", "T": 25.0},
        "static_T": None,
        "tilt_deg": (-0.25, 0.35),
    },
}


def export_csv(mcap: Path, out: Path) -> Path:
    """Write a recorded session as a generic CSV: t (s), ax..az (g), temp (degC), gx..gz (deg/s),
    pose (the label's name inside a labelled hold, empty elsewhere)."""
    s = read_session(mcap)
    pose = np.full(s.n, "", dtype=object)
    for p in s.poses:
        pose[s.slice_time(p.start_s, p.end_s)] = p.name
    num = np.column_stack([s.t_s, s.accel_g, s.temp_degC, s.gyro_dps])
    buf = io.StringIO()
    np.savetxt(buf, num, fmt=["%.6f"] + ["%.10g"] * 3 + ["%.4f"] + ["%.6g"] * 3, delimiter=",")
    rows = buf.getvalue().splitlines()
    body = "\n".join(f"{r},{q}" for r, q in zip(rows, pose, strict=True))
    out.write_text("t,ax,ay,az,temp,gx,gy,gz,pose\n" + body + "\n")
    return out


def _run_json(capsys: pytest.CaptureFixture, *args: str) -> dict:
    rc = main(list(args))
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    return json.loads(cap.out)


def _sessions(tmp: Path, effect: str) -> dict[str, Path]:
    """Simulate calibration, held-out and (if any) static sessions; export each to CSV."""
    c = CASES[effect]
    chip = {**CHIP, **c["set"]}
    common = dict(
        sample_rate_hz=RATE_HZ,
        move_s=2.0,
        errors="perfect",
        gyro_errors="perfect",
        set=chip,
        fixture_tilt_deg=c["tilt_deg"],
    )
    specs = {
        "cal": Scenario(
            protocol=c["protocol"], hold_s=c["hold_s"], seed=51, temperature=c["cal_T"], **common
        ),
        "held": Scenario(
            protocol=c["protocol"], hold_s=c["hold_s"], seed=52, temperature=c["held_T"], **common
        ),
    }
    if c["static_T"] is not None:
        specs["static"] = Scenario(protocol="+z", hold_s=65.0, seed=53, temperature=c["static_T"], **common)
    out = {}
    for role, sc in specs.items():
        simulate(sc, tmp / f"{role}_emulated.mcap")
        out[role] = export_csv(tmp / f"{role}_emulated.mcap", tmp / f"{role}.csv")
    return out


@pytest.mark.parametrize("effect", list(CASES))
def test_csv_import_diagnose_fit_evaluate_heldout(
    tmp_path: Path, capsys: pytest.CaptureFixture, effect: str
) -> None:
    csvs = _sessions(tmp_path, effect)
    mcap = {}
    for role, csv in csvs.items():
        mcap[role] = tmp_path / f"{role}.mcap"
        facts = _run_json(capsys, "import", "csv", str(csv), "--unit", "g", "-o", str(mcap[role]), "--json")
        assert facts["source"] == "import:csv" and facts["poses"]
    assert "+z@90" in facts["poses"] or effect != "fixture_tilt"

    d = _run_json(capsys, "diagnose", str(mcap["cal"]), "--json")
    top = d["candidates"][0]["effect"]
    assert d["missing"] and top == d["best"] == effect, d["verdict"]
    clock = next(c for c in d["candidates"] if c["effect"] == "clock")
    assert not clock["identifiable"]  # a CSV without host time cannot show the sample clock

    cals = {}
    for label, add in (("model3", []), ("top", ["--add", top])):
        cals[label] = tmp_path / f"{label}.json"
        f = _run_json(
            capsys, "fit", str(mcap["cal"]), "--model", "model3", *add, "-o", str(cals[label]), "--json"
        )
        assert (f["chi2_dof"] < 1.5) == (label == "top"), (label, f["chi2_dof"])

    # held-out multi-pose session
    ev = _run_json(
        capsys,
        "evaluate",
        str(mcap["held"]),
        "--cal",
        str(cals["model3"]),
        "--cal",
        str(cals["top"]),
        "--json",
    )
    assert ev["kind"] == "poses"
    m3, tp = ev["calibrated"]
    for e in (ev["raw"], m3, tp):
        assert set(e) >= REQUIRED, REQUIRED - set(e)
        assert set(e["mean_residual_mps2"]) == {"x", "y", "z"} and len(e["displacement_60s_m"]) == 3
    assert tp["rms_mps2"] < 0.5 * m3["rms_mps2"] < m3["rms_mps2"] < ev["raw"]["rms_mps2"]
    assert tp["chi2_noise_dof"] < 1.5 < 3.0 < m3["chi2_noise_dof"]
    assert np.max(np.abs(tp["displacement_60s_m"])) < np.max(np.abs(m3["displacement_60s_m"]))

    if "static" not in mcap:
        return
    # held-out single static hold (65 s, z up)
    ev = _run_json(
        capsys,
        "evaluate",
        str(mcap["static"]),
        "--cal",
        str(cals["model3"]),
        "--cal",
        str(cals["top"]),
        "--json",
    )
    m3, tp = ev["calibrated"]
    for e in (ev["raw"], m3, tp):
        assert set(e) >= REQUIRED, REQUIRED - set(e)
        assert e["displacement_60s_m"] is not None and len(e["displacement_60s_m"]) == 3
    assert tp["rms_mps2"] < m3["rms_mps2"]
    assert np.linalg.norm(tp["displacement_60s_m"]) < 0.5 * np.linalg.norm(m3["displacement_60s_m"])
    assert tp["chi2_noise"] < m3["chi2_noise"]
