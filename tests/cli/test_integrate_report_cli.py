"""`accellog integrate` (CSV artifact of the double integration) and `accellog report` (tables from
the JSON artifacts of the other stages)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from accellog.cli import main
from accellog.flows.simulate import Scenario, simulate


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("intrep")
    simulate(Scenario(protocol="six", hold_s=5.0, move_s=2.0, sample_rate_hz=200.0, seed=1), d / "cal.mcap")
    simulate(Scenario(protocol="+z", hold_s=22.0, sample_rate_hz=200.0, seed=2), d / "test.mcap")
    assert main(["fit", str(d / "cal.mcap"), "-o", str(d / "cal.json")]) == 0
    return d


def test_integrate_writes_the_evaluated_track(files, capsys):
    d = files
    capsys.readouterr()
    rc = main(
        ["integrate", str(d / "test.mcap"), "--cal", str(d / "cal.json"), "-o", str(d / "t.csv"), "--json"]
    )
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert main(["evaluate", str(d / "test.mcap"), "--cal", str(d / "cal.json"), "--json"]) == 0
    ev = json.loads(capsys.readouterr().out)["calibrated"][0]
    rows = np.loadtxt(d / "t.csv", delimiter=",", skiprows=1)
    assert rows.shape[1] == 7 and np.all(np.diff(rows[:, 0]) > 0)
    np.testing.assert_allclose(rows[-1, 4:], ev["displacement"]["disp_end_m"], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(summary["disp_end_m"], ev["displacement"]["disp_end_m"], rtol=1e-12)
    # velocity is the derivative of the displacement (trapezoid pairs)
    v_mid = np.diff(rows[:, 4:], axis=0) / np.diff(rows[:, 0])[:, None]
    np.testing.assert_allclose(v_mid, 0.5 * (rows[1:, 1:4] + rows[:-1, 1:4]), atol=1e-6)


def test_report_renders_every_artifact_as_markdown(files, capsys):
    d = files
    capsys.readouterr()
    assert main(["evaluate", str(d / "test.mcap"), "--cal", str(d / "cal.json"), "--json"]) == 0
    (d / "ev.json").write_text(capsys.readouterr().out)
    assert main(["report", str(d / "cal.json"), str(d / "ev.json"), "--markdown"]) == 0
    md = capsys.readouterr().out
    cal = json.loads((d / "cal.json").read_text())
    b_x = next(p for p in cal["params"] if p["name"] == "b_x")
    assert "| b_x |" in md and f"{b_x['value']:.4f}"[:6] in md
    assert "mean residual after calibration" in md and "| no calibration |" in md and "| model3 |" in md


def test_report_refuses_foreign_files(files, capsys, tmp_path):
    (tmp_path / "x.json").write_text('{"hello": 1}')
    for f in (tmp_path / "x.json", files / "cal.mcap", tmp_path / "missing.json"):
        rc = main(["report", str(f)])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and err.startswith("accellog: error:") and f.name in err and "\n" not in err
