"""`accellog diagnose` on the seed's real data (capstone, ../shared/data/capstone).

Six poses (per-pose means and standard deviations) can test model3 against the noise and one more
library effect (nonlin2: each axis at +1, 0, -1 g); everything else needs data the study did not
record, and the tool must say what: the 24-pose protocol (fixture tilt), the die temperature over a
warm-up or sweep (temperature effects), off-axis poses (nonlin3, g_cross), a longer session (time
effects), host timestamps (clock). The 60 s static test file (one '+z' hold) can only fit a bias.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from accellog.cli import main

POSE_TABLES = [
    "final_trial/six_position_data.csv",
    "trial_1/six_position_data_1.csv",
    "trial_2/six_position_data_2.csv",
    "trial_3/six_position_data_3.csv",
]


def _diagnose(capsys: pytest.CaptureFixture, *args: str) -> dict:
    rc = main(["diagnose", *args, "--json"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    return json.loads(cap.out)


@pytest.mark.parametrize("table", POSE_TABLES)
def test_six_pose_table_what_it_can_and_cannot_tell(
    shared_data: Path, capsys: pytest.CaptureFixture, table: str
) -> None:
    d = _diagnose(capsys, str(shared_data / "capstone" / table))
    assert d["model"] == "model3" and d["n_obs"] == 6 and d["dof"] == 6
    # what it can tell: model3 is far from the noise floor of the pose means (std / sqrt(n)) ...
    assert d["missing"] and d["chi2_dof"] > 100 and d["rms_g"] > 10 * d["noise_floor_g"]
    assert 1e-3 < d["rms_g"] < 5e-3  # ~2 mg residual RMS, as in the study
    # ... and no library effect testable on six poses explains it: only nonlin2 is identifiable,
    # and it is not significant (3 more parameters on 6 dof)
    rows = {c["effect"]: c for c in d["candidates"]}
    assert [n for n, c in rows.items() if c["identifiable"]] == ["nonlin2"]
    assert not rows["nonlin2"]["significant"] and d["best"] is None
    assert "no identifiable library effect" in d["verdict"]
    # the driver-signal view still names the pattern of the residual (same in all four trials)
    top = d["driver_signals"][0]
    assert (top["signal"], top["axis"]) == ("f_z^2 (g^2)", "y")
    # what to record next
    advice = "\n".join(d["advice"])
    assert "24-pose protocol" in advice and "fixture_tilt" in advice
    assert "temperature sweep" in advice and "TEMP_OUT" in advice
    assert "poses off the axes" in advice and "g_cross" in advice and "nonlin3" in advice
    assert "time_drift needs observations spread over >= 60 s" in advice
    assert "host time" in rows["clock"]["reason"]
    assert d["clock"] is None


def test_static_test_file_bias_only_and_what_model3_needs(
    shared_data: Path, capsys: pytest.CaptureFixture
) -> None:
    """The 60 s static test (capstone CSV, one '+z' hold) through the same command."""
    f = shared_data / "capstone" / "final_trial" / "six_position_test_data.csv"
    rc = main(["diagnose", str(f), "--json"])  # default model3: one line saying what is missing
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("accellog: error:") and len(err.strip().splitlines()) == 1
    assert "both +x and -x poses" in err and "faces present: +z" in err
    d = _diagnose(capsys, str(f), "--model", "model1")
    assert d["model"] == "model1" and d["n_obs"] >= 25
    assert 0.5 < d["chi2_dof"] < 3.0  # a bias fits one hold close to the window noise
    rows = {c["effect"]: c for c in d["candidates"]}
    assert not any(c["identifiable"] for c in rows.values())
    assert "+x and -x poses" in rows["scale"]["reason"]
    assert "spread over >= 60 s" in rows["time_drift"]["reason"]
    assert "temperature sweep" in rows["temp_bias"]["reason"]
