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
        "flip_heldout": _sc(5, HOT2, temp_bias_g_per_degC=[-0.0012, 0.0008, -0.001]),
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
    """The .rrd read back: per axis one residual-vs-temperature plot with the start model (sloped:
    the residual follows temperature) and the final model (flat) overlaid, each in its ladder step's
    colour, the added effect's prediction drawn over the start model's residual; temperature, the
    driver the residual follows, has its own tab. Every view has one parent (a view placed in two
    containers draws in neither: the 'residual vs every driver' tabs drew nothing while their views
    were also the before/after tab's)."""
    from collections import Counter

    from accellog.present.rrd.logs import step_color

    d = sessions
    rrd = d / "wb_residuals.rrd"
    args = ["workbench", str(d / "hidden.mcap"), "--heldout", str(d / "heldout.mcap"), "--rrd", str(rrd)]
    assert main([*args, "--json"]) == 0
    capsys.readouterr()
    r = load_rrd(rrd)
    children = Counter(
        child for comps in r.blueprint.values() for child in comps.get("ContainerBlueprint:contents", [])
    )
    assert children and max(children.values()) == 1, [c for c, n in children.items() if n > 1]
    root = "/residual_vs/temp_degC"
    plots = sorted(
        {e.split("/")[3] for e in r.entities if e.startswith(root + "/")} - {"frame_x", "frame_y", "frame_z"}
    )
    assert plots == ["final_model3_temp_bias", "start_model3"], plots
    views = [v for v in r.views() if v["class"] == "2D" and v["origin"] == root]
    by_axis = {v["name"].split()[1]: v for v in views if v["name"].startswith("residual ")}
    assert set(by_axis) == {"x", "y", "z"}, [v["name"] for v in views]
    x_view = by_axis["x"]
    assert "vs temperature (degC)" in x_view["name"]
    assert {f"{root}/start_model3/x", f"{root}/final_model3_temp_bias/x"} <= set(x_view["contents"])
    assert f"{root}/start_model3/y" not in x_view["contents"]  # one axis per plot
    names = {c.get("ContainerBlueprint:display_name", [None])[0] for c in r.blueprint.values()}
    assert "residual vs temperature (degC): before / after" in names and "the search" in names

    def slope(plot: str) -> float:
        """|least-squares slope| of the plotted residual (view units) against plotted x, axis x."""
        pts = np.asarray(r.static(f"{root}/{plot}/x", "Points2D:positions"), float)
        return abs(np.polyfit(pts[:, 0], pts[:, 1], 1)[0])

    assert slope("start_model3") > 20 * slope("final_model3_temp_bias")
    assert f"{root}/start_model3/contribution_x" in r.entities
    # the same calibration, the same colour: start = ladder step 2 (model3), final = step 3
    start = {tuple(c) for c in _rgb(r.static(f"{root}/start_model3/x", "Points2D:colors"))}
    final = {tuple(c) for c in _rgb(r.static(f"{root}/final_model3_temp_bias/x", "Points2D:colors"))}
    assert step_color(2) in start and step_color(3) in final and not start & final


def test_a_search_that_ends_at_the_start_shows_what_it_tried(sessions, capsys):
    """The held-out session's temperature coefficient has the other sign: no effect predicts it
    better, the start model is written, and the text and .rrd still name the candidates tried,
    each with its held-out residual and why it was not taken."""
    d = sessions
    rrd = d / "wb_flip.rrd"
    args = ["workbench", str(d / "hidden.mcap"), "--heldout", str(d / "flip_heldout.mcap"), "--rrd", str(rrd)]
    main([*args, "--json"])
    out = json.loads(capsys.readouterr().out)
    assert out["final_model"] == "model3"
    tried = [t for t in out["trail"] if t["status"] == "rejected"]
    assert "+temp_bias" in [t["change"] for t in tried]
    assert all(
        t["heldout_chi2_dof"] is not None and "does not predict unseen data better" in t["why"] for t in tried
    )
    labels = load_rrd(rrd).labels("/charts/search/labels")
    assert "+temp_bias" in " ".join(labels) and "rejected" in labels and "start = final" in labels


def _rgb(packed) -> list[tuple[int, int, int]]:
    """RGB of rerun's packed 0xRRGGBBAA colours."""
    return [((c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255) for c in packed]


def test_workbench_shows_every_step_tried(sessions, capsys):
    """The text and the .rrd show each model the search tried with its held-out residual on the
    common yardstick: the start model, the added effect (kept, final) and the curve between them."""
    d = sessions
    rrd = d / "wb_search.rrd"
    args = ["workbench", str(d / "hidden.mcap"), "--heldout", str(d / "heldout.mcap"), "--rrd", str(rrd)]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "the search, step by step" in text and "kept = final" in text
    assert main([*args[:-2], "--json"]) == 0
    trail = json.loads(capsys.readouterr().out)["trail"]
    assert [(t["change"], t["status"]) for t in trail[:2]] == [("model3", "start"), ("+temp_bias", "kept")]
    assert trail[1]["final"] and trail[1]["heldout_chi2_dof"] < 0.1 * trail[0]["heldout_chi2_dof"]
    r = load_rrd(rrd)
    labels = r.labels("/charts/search/labels")
    assert r.labels("/charts/search/labels/steps")[:4] == [
        "0 model3",
        "start",
        "1 +temp_bias",
        "kept = final",
    ]
    assert (
        f"{trail[1]['heldout_chi2_dof']:.3g}" in labels and f"{trail[0]['heldout_rms_mg']:.3g} mg" in labels
    )
    path = np.asarray(r.static("/charts/search/path", "LineStrips2D:strips")[0], float)
    assert path[1, 1] > path[0, 1]  # the curve falls (view y grows downwards)
    assert "/docs/search" in r.entities


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
    labels = r.static("/residual_vs/pose/frame_x/ticks", "Points2D:labels")
    assert labels[: len(names)] == names, labels[:5]
    pts = np.asarray(r.static("/residual_vs/pose/final_model3_temp_bias/x", "Points2D:positions"), float)
    assert len(pts) >= 2 * len(names)  # several windows per hold, none averaged away
    views = [v for v in r.views() if v["class"] == "2D" and v["origin"] == "/residual_vs/pose"]
    assert len(views) == 3 and any("/residual_vs/pose/start_model3/x" in v["contents"] for v in views)
