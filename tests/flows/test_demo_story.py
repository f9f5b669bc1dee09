"""The demo's robot chapter says what its table shows (issue 45, item 9): the raw track takes its
gyro bias at rest, Model 3's track its 25 degC gyro bias, which is off at 38 degC; Model 3's
accelerometer part alone, given the raw track's gyro, ends about where raw ends; the model the
workbench finds ends nearer than all of them."""

from __future__ import annotations

import re

import pytest

from accellog.cli import main


def _final_m(out: str, name: str) -> list[float]:
    """The 'final (m)' column of every robot-table row named `name`."""
    return [float(m) for m in re.findall(rf"│ {re.escape(name)} +│ +([\d.e+-]+) │", out)]


@pytest.mark.slow  # the quick demo: ~10 s
def test_the_robot_chapter_says_what_its_table_shows(tmp_path, capsys):
    assert main(["demo", "--quick", "--no-rrd", "-o", str(tmp_path / "demo")]) == 0
    out = capsys.readouterr().out.split("3. a moving robot", 1)[1]  # the robot tables (chapters 3 and 4)
    raw, model3, alone = (
        _final_m(out, "raw")[0],
        _final_m(out, "Model 3")[0],
        _final_m(out, "Model 3 accel, gyro bias at rest"),
    )
    assert (
        len(alone) == 1
    )  # in the first table only: the recording's tracks are raw, Model 3 and the final model
    said = re.search(r"At 38 °C its gyro bias is ([\d.]+) °/s off", out)
    assert said and float(said.group(1)) > 0.5, out
    assert "its accelerometer part alone ends about where raw ends" in out
    assert model3 > 10 * raw and 0.5 * raw < alone[0] < 2 * raw
    final = _final_m(out, "model3+temp_bias+temp_scale")
    assert final and final[0] < raw / 2
