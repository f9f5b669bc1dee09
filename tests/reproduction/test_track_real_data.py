"""A real recording through the moving-sensor path: imucal's hand-held Ferraris session (real IMU,
102.4 Hz, six holds and three full turns, no truth) imported, calibrated (accelerometer Model 3 +
gyro from the moves between holds, gravity-referenced: the operator's headings are unknown) and
integrated; without truth, the sensor ends where it started, so loop closure is the error."""

from __future__ import annotations

import json

import numpy as np

from accellog.cli import main


def test_imucal_session_tracks_close_better_when_calibrated(shared_data, tmp_path, capsys):
    d = shared_data / "imucal"
    mcap, cal = tmp_path / "imucal.mcap", tmp_path / "cal.json"
    assert (
        main(
            [
                "import",
                "imucal",
                str(d / "example_ferraris_session.csv"),
                "--sections",
                str(d / "example_ferraris_session_list.json"),
                "-o",
                str(mcap),
            ]
        )
        == 0
    )
    assert main(["fit", str(mcap), "-o", str(cal)]) == 0
    gyro = json.loads(cal.read_text())["gyro"]
    m = np.array(gyro["matrix"])
    # imucal's own Ferraris gyro scale for this session is (1.028, 0.982, 0.998): same size of error
    assert np.all(np.abs(np.diag(m) - 1) < 0.05) and np.all(np.abs(m - np.diag(np.diag(m))) < 0.05)
    capsys.readouterr()
    assert main(["track", str(mcap), "--cal", str(cal), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["reference"] == "loop_closure"
    raw, calibrated = out["tracks"]
    assert calibrated["zupt_stops"] >= 6
    assert calibrated["final_error_m"] < raw["final_error_m"] / 2
    assert calibrated["without_zupt"]["final_error_m"] < 0.8 * raw["without_zupt"]["final_error_m"]
