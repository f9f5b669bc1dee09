"""Tables that never split a number, at the widths people use; diagnose on the seed's six poses says
each thing once and prints no 'nan -> nan'."""

from __future__ import annotations

import json
import re

import pytest
from rich.console import Console

from accellog.calibrate.diagnosis.ladder import LadderRow
from accellog.cli import main
from accellog.present.discovery_text import candidates_table
from accellog.present.tables import ladder_table


def _text(table, width: int) -> str:
    con = Console(width=width, record=True, file=open("/dev/null", "w"))  # noqa: SIM115
    con.print(table)
    return con.export_text()


@pytest.mark.parametrize("width", [80, 100])
def test_ladder_numbers_are_never_split(width):
    rows = [
        LadderRow("model1", 3, 11634.2, 0.0123, heldout_rms_g=0.0456, heldout_noise_g=6.1e-5, drift_m=1234.5,
                  drift_at_s=60.0),
        LadderRow("model3+temp_bias+temp_scale", 15, 1.07, 6.4e-5, heldout_rms_g=7.1e-5, heldout_noise_g=6.2e-5,
                  drift_m=0.0312, drift_at_s=60.0, warnings=["x"]),
    ]  # fmt: skip
    text = _text(ladder_table(rows, "watch the error fall"), width)
    for number in ("1.16e+04", "12.3", "45.6", "1.23e+03", "0.064", "0.071", "0.062", "0.0312"):
        assert number in text, (number, text)


def test_candidate_numbers_whole_and_repeated_reasons_said_once():
    reason = "needs driver 'temp_degC' (record the die temperature)"
    cands = [
        {"rank": 1, "effect": "nonlin2", "identifiable": True, "chi2_dof": 6789.1, "delta_bic": -2927.7,
         "p_value": 0.93, "reason": "chi2/dof 3.88e+03 -> 6.79e+03"},
        *({"rank": k, "effect": e, "identifiable": False, "reason": reason}
          for k, e in enumerate(("temp_bias", "temp_scale"), 2)),
    ]  # fmt: skip
    text = _text(candidates_table(cands), 160)
    assert "6.79e+03" in text and "-2927.7" in text
    assert text.count("record the die") == 1 and "as temp_bias" in text
    narrow = _text(candidates_table(cands), 100)
    assert "6.79e+03" in narrow and "-2927.7" in narrow  # the reason column wraps instead


def test_diagnose_on_the_seed_poses_says_each_thing_once(shared_data, capsys):
    poses = shared_data / "capstone" / "final_trial" / "six_position_data.csv"
    assert main(["diagnose", str(poses)]) == 0
    out = capsys.readouterr().out
    assert "nan" not in out
    assert out.count("record the die temperature") == 2  # the table's first row and one advice line
    assert main(["diagnose", str(poses), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert not any(re.search(r"\bnan\b", c.get("reason", "")) for c in d["candidates"])


@pytest.mark.parametrize("width", [100, 120])
def test_ladder_model_names_wrap_at_their_terms(width):
    """A long model name wraps between its terms, never inside one (it was 'model3+temp_' /
    'bias+temp_sc' / 'ale'); at 120 columns it is whole."""
    rows = [
        LadderRow("model1", 3, 11634.2, 0.0123, heldout_rms_g=0.0456, heldout_noise_g=6.1e-5, drift_m=1234.5,
                  drift_at_s=60.0, heldout_chi2_dof=6.96),
        LadderRow("model3+temp_bias+temp_scale", 18, 0.888, 1.41e-4, heldout_rms_g=1.5e-4, heldout_noise_g=1.52e-4,
                  drift_m=1.41, drift_at_s=60.0, warnings=["x"], heldout_chi2_dof=0.896),
    ]  # fmt: skip
    text = _text(ladder_table(rows, "watch the error fall"), width)
    cells = [ln.split("│")[1].strip() for ln in text.splitlines() if ln.startswith("│")]
    words = " ".join(cells).split()
    assert words[:2] == ["model1", "model3"] and {"temp_bias", "temp_scale"} <= set(words), cells
    assert all(len(ln) <= width for ln in text.splitlines())
    if width == 120:
        assert "model3 + temp_bias + temp_scale" in cells


def test_every_column_shows_at_80_characters():
    """The workbench's two tables on an 80-column terminal: every column there (the last one was
    cropped), no line wider, the warnings per model in the ladder's caption; the search's reasons
    as lines below its table."""
    from types import SimpleNamespace

    from accellog.present.discovery_text import print_search

    rows = [
        LadderRow("model1", 3, 3210.0, 0.0143, heldout_rms_g=0.0204, heldout_noise_g=1.86e-4,
                  heldout_chi2_dof=8510.0, drift_m=1234.5, drift_at_s=60.0, warnings=["x", "y"]),
        LadderRow("model3+temp_bias+temp_bias2", 18, 0.767, 1.73e-4, heldout_rms_g=2.08e-4,
                  heldout_noise_g=1.86e-4, heldout_chi2_dof=0.858, drift_m=0.0312, drift_at_s=60.0),
    ]  # fmt: skip
    text = _text(ladder_table(rows, "watch the error fall"), 80)
    assert max(map(len, text.splitlines())) <= 80
    for word in ("params", "floor", "χ²/dof", "drift", "8.51e+03", "0.858", "0.0312", "warnings", "model1 2"):
        assert word in text, (word, text)
    step = dict(heldout=1.0, final=False, on_path=True, status="kept")
    trail = [
        SimpleNamespace(step=0, change="model3", heldout_chi2_dof=6110.0, heldout_rms_mg=17.7, why="", **step),
        SimpleNamespace(step=1, change="+temp_bias2", heldout_chi2_dof=0.858, heldout_rms_mg=0.208,
                        why="temp_bias2: held-out chi2/eq 734 -> 1.47", **{**step, "final": True}),
    ]  # fmt: skip
    con = Console(width=80, record=True, file=open("/dev/null", "w"))  # noqa: SIM115
    print_search(trail, con)
    text = con.export_text()
    assert max(map(len, text.splitlines())) <= 80
    for word in (
        "step",
        "change",
        "became",
        "RMS",
        "log scale",
        "6.11e+03",
        "0.208",
        "1 +temp_bias2: temp_bias2",
    ):
        assert word in text, (word, text)
