"""`accellog workbench`: the discovery loop and the ladder on emulated sessions with a hidden
temperature effect (found, added, error falls to the noise floor) and on a clean one (nothing added)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rrd_readback import load_rrd

from accellog.cli import main
from accellog.flows.simulate import Scenario, simulate
from accellog.present.rrd.entities import slug

HOT = {"kind": "points", "t_s": [0.0, 60.0, 130.0, 200.0], "T": [22.0, 40.0, 28.0, 36.0]}
HOT2 = {"kind": "points", "t_s": [0.0, 70.0, 140.0, 200.0], "T": [30.0, 44.0, 33.0, 41.0]}


def _sc(seed: int, temperature: dict, **set_) -> Scenario:
    errors = {
        "bias_g": [0.04, -0.03, 0.06],
        "scale": [0.02, -0.01, 0.015],
        "noise_density_g_per_rtHz": 300e-6,
        **set_,
    }
    return Scenario(
        protocol="24",
        hold_s=6.0,
        move_s=2.0,
        sample_rate_hz=200.0,
        errors="perfect",
        set=errors,
        chip_seed=3,
        seed=seed,
        temperature=temperature,
    )


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("wb")
    tb = {"temp_bias_g_per_degC": [0.0012, -0.0008, 0.001]}
    paths = {
        "hidden": _sc(1, HOT, **tb),
        "heldout": _sc(2, HOT2, **tb),
        "clean": _sc(3, HOT),
        "clean_heldout": _sc(4, HOT2),
    }
    for name, sc in paths.items():
        simulate(sc, d / f"{name}.mcap")
    return d


def test_hidden_temperature_effect_is_found_and_the_error_falls(sessions, capsys):
    d = sessions
    rrd = d / "wb.rrd"
    rc = main(
        [
            "workbench",
            str(d / "hidden.mcap"),
            "--heldout",
            str(d / "heldout.mcap"),
            "--json",
            "--rrd",
            str(rrd),
        ]
    )
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["added"] == ["temp_bias"]
    ladder = out["ladder"]
    assert [r["model"] for r in ladder] == ["model1", "model2", "model3", "model3+temp_bias"]
    m3, final = ladder[2], ladder[-1]
    assert m3["chi2_dof"] > 20 and final["chi2_dof"] < 1.5
    assert final["heldout_rms_g"] < 1.3 * final["heldout_noise_g"] < m3["heldout_rms_g"] / 5
    assert "nothing is missing" in out["verdicts"][-1]
    # the .rrd ladder: one bar per step at its index, log10 of the held-out RMS (mg), named by its model
    bars = load_rrd(rrd).ladder_bars("log10_heldout_rms_mg")
    assert [x for x, _, _ in bars] == list(range(len(ladder)))
    assert [n.split("_", 1)[1] for _, n, _ in bars] == [slug(r["model"]) for r in ladder]
    np.testing.assert_allclose(
        [v for _, _, v in bars], [np.log10(r["heldout_rms_g"] * 1000) for r in ladder], rtol=1e-6
    )


def test_clean_session_adds_nothing(sessions, capsys):
    d = sessions
    rc = main(["workbench", str(d / "clean.mcap"), "--heldout", str(d / "clean_heldout.mcap"), "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["added"] == [] and out["final_model"] == "model3"
    assert out["ladder"][-1]["heldout_rms_g"] < 1.3 * out["ladder"][-1]["heldout_noise_g"]


def test_pose_table_is_refused_with_one_line(tmp_path, capsys):
    csv = tmp_path / "poses.csv"
    csv.write_text("x_true (g),x_mean (g),x_std,y_true (g),y_mean (g),y_std,z_true (g),z_mean (g),z_std\n")
    rc = main(["workbench", str(csv)])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and err.startswith("accellog: error:") and "\n" not in err


def test_workbench_rrd_shows_residuals_against_temperature(sessions, capsys):
    """The .rrd read back: residual-vs-temperature plots of the start model (sloped: the residual
    follows temperature) and of the final model (flat), one 2D view each, with the added effect's
    prediction drawn over the start model's residual."""
    d = sessions
    rrd = d / "wb_residuals.rrd"
    args = ["workbench", str(d / "hidden.mcap"), "--heldout", str(d / "heldout.mcap"), "--rrd", str(rrd)]
    assert main([*args, "--json"]) == 0
    capsys.readouterr()
    r = load_rrd(rrd)
    root = "/residual_vs/temp_degC"
    plots = sorted({e.split("/")[3] for e in r.entities if e.startswith(root + "/")})
    assert plots == ["final_model3_temp_bias", "start_model3"], plots
    views = {v["origin"]: v for v in r.views() if v["class"] == "2D"}
    assert {f"{root}/{p}" for p in plots} <= set(views), views.keys()
    assert "residual (mg) vs temp_degC" in views[f"{root}/start_model3"]["name"]

    def slope(plot: str) -> float:
        """|least-squares slope| of the plotted residual (view units) against plotted x, axis x."""
        pts = np.asarray(r.static(f"{root}/{plot}/x", "Points2D:positions"), float)
        return abs(np.polyfit(pts[:, 0], pts[:, 1], 1)[0])

    assert slope("start_model3") > 20 * slope("final_model3_temp_bias")
    assert f"{root}/start_model3/contribution_x" in r.entities


def test_workbench_rrd_residuals_by_pose_are_named(sessions, capsys):
    """The window residuals by pose carry the session's pose names (not indices), every window kept:
    one point per window and axis, for the start and the final model."""
    from accellog.store.reader import read_session

    d = sessions
    rrd = d / "wb_poses.rrd"
    args = ["workbench", str(d / "hidden.mcap"), "--heldout", str(d / "heldout.mcap"), "--rrd", str(rrd)]
    assert main([*args, "--json"]) == 0
    capsys.readouterr()
    r = load_rrd(rrd)
    names = [p.name for p in read_session(d / "hidden.mcap").poses]
    labels = r.static("/residual_vs/pose/start_model3/ticks", "Points2D:labels")
    assert labels[: len(names)] == names, labels[:5]
    pts = np.asarray(r.static("/residual_vs/pose/final_model3_temp_bias/x", "Points2D:positions"), float)
    assert len(pts) >= 2 * len(names)  # several windows per hold, none averaged away
    views = {v["origin"]: v for v in r.views() if v["class"] == "2D"}
    assert "/residual_vs/pose/start_model3" in views
