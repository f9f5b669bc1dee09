"""The model ladder as one typed result: built once (calibrate.ladder), one JSON form with an explicit
drift_at_s, one table (present.tables.ladder_table) that `accellog report` also uses on --json files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rich.console import Console
from support.synthetic import synthetic_obs, true_theta

from accellog.calibrate.diagnosis.ladder import LadderRow, ladder
from accellog.calibrate.model.compose import build_model
from accellog.cli import main
from accellog.core.jsonio import dumps
from accellog.present.tables import ladder_table


def _temp(t):
    return 25.0 + 15.0 * np.sin(t / 120.0)


@pytest.fixture(scope="module")
def rows() -> list[LadderRow]:
    truth = build_model("model3").with_terms(["temp_bias"])
    th = true_theta(truth, {}, seed=3)
    obs = synthetic_obs(truth, th, protocol="24", temp_path=_temp, seed=5)
    held = synthetic_obs(truth, th, protocol="24", temp_path=_temp, seed=6)
    return ladder(obs, [build_model("model1"), build_model("model3"), truth], held)


def test_rows_are_typed_and_judged_out_of_sample(rows):
    assert [r.model for r in rows] == ["model1", "model3", "model3+temp_bias"]
    assert rows[0].n_params < rows[1].n_params < rows[2].n_params
    # the missing temperature term shows held out, and adding it brings the residual to the noise floor
    assert rows[1].heldout_rms_g > 3 * rows[1].heldout_noise_g
    assert rows[2].heldout_rms_g < 1.3 * rows[2].heldout_noise_g
    assert rows[2].residual_g.shape == (len(rows[2].fit.residual_g), 3)


def test_json_keys_and_explicit_drift_horizon(rows):
    r = rows[-1]
    d = json.loads(dumps(r.to_dict()))
    assert {"model", "added", "n_params", "chi2_dof", "rms_g", "warnings", "heldout_rms_g"} <= set(d)
    assert "fit" not in d and "residual_g" not in d and "drift_at_s" not in d
    r.drift_m, r.drift_at_s = 0.42, 30.0
    d = json.loads(dumps(r.to_dict()))
    assert d["drift_at_s"] == 30.0 and d["drift_30s_m"] == 0.42  # the explicit field and the older key
    back = LadderRow.from_dict(d)
    assert (back.model, back.drift_m, back.drift_at_s, back.heldout_rms_g) == (
        r.model,
        0.42,
        30.0,
        pytest.approx(r.heldout_rms_g),
    )
    # a row written before drift_at_s existed: the horizon comes from its key
    old = {k: v for k, v in d.items() if k != "drift_at_s"}
    assert LadderRow.from_dict(old).drift_at_s == 30.0
    r.drift_m = r.drift_at_s = None


def test_one_table_for_live_rows_and_report_of_json(rows, tmp_path, capsys):
    rows[1].drift_m, rows[1].drift_at_s = 1.5, 30.0
    try:
        con = Console(width=200, record=True)
        con.print(ladder_table(rows))
        text = con.export_text()
        assert "30 s drift (m)" in text and "held-out RMS (mg)" in text and "model3 + temp_bias" in text
        f = tmp_path / "wb.json"
        f.write_text(dumps({"session": "x", "ladder": [r.to_dict() for r in rows]}))
        capsys.readouterr()
        assert main(["report", str(f), "--markdown"]) == 0
        md = capsys.readouterr().out
        assert "30 s drift (m)" in md and "| 1.5 |" in md
        assert f"{rows[2].heldout_rms_g * 1000:.3g}" in md
    finally:
        rows[1].drift_m = rows[1].drift_at_s = None
