"""Pictures that show the failure, read back from the .rrd (no viewer): each ladder step has its own
colour (bars and residuals alike), residuals (mg) and temperature (degC) never share an axis, bars
are named (by pose, by model), plots and the robot's 3D view are framed on the data they show,
and 3D labels of points that coincide are merged instead of drawn over each other."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from accellog.calibrate.diagnosis.ladder import LadderRow
from accellog.present.rrd.bars2d import nice_ticks
from accellog.present.rrd.demo_layout import DemoData, demo_blueprint, legend_corner, y_range
from accellog.present.rrd.recording import RunRecording

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rrd_readback import load_rrd


def _ladder(n: int = 40):
    """model1, model2, model3, model3+temp_bias; residuals of model3 follow temperature."""
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 300.0, n)
    temp = 25.0 + 15.0 * np.sin(t / 100.0)
    res3 = np.column_stack([0.0004 * (temp - 30.0), rng.normal(0, 1e-4, n), -0.0003 * (temp - 30.0)])
    rows = [
        LadderRow("model1", 6, 1.1e4, heldout_rms_g=0.016, drift_m=800.0),
        LadderRow("model2", 9, 5.3e3, heldout_rms_g=0.012, drift_m=300.0),
        LadderRow("model3", 12, 547.0, heldout_rms_g=0.006, drift_m=250.0, residual_g=res3),
        LadderRow(
            "model3+temp_bias",
            15,
            0.9,
            added=["temp_bias"],
            heldout_rms_g=0.00015,
            drift_m=9.5,
            residual_g=rng.normal(0, 1e-4, (n, 3)),
        ),
    ]
    return t, temp, rows


def _covers(view: dict, entity: str) -> bool:
    """Does a view's contents query (rerun's '+ /path/**' rules, '$origin') take in entity?"""
    hit = False
    for rule in view["contents"] or ["$origin/**"]:
        rule = rule.strip()
        neg = rule.startswith("-")
        rule = rule.lstrip("+- ").replace("$origin", view["origin"].rstrip("/"))
        rule = rule if rule.startswith("/") else "/" + rule
        ok = (
            entity == rule or (rule.endswith("/**") and (entity + "/").startswith(rule[:-2])) or rule == "/**"
        )
        if ok:
            hit = not neg
    return hit


def test_ladder_steps_own_colours_named_bars_and_separate_axes(tmp_path: Path) -> None:
    t, temp, rows = _ladder()
    out = tmp_path / "ladder.rrd"
    with RunRecording(f"save:{out}") as rec:
        rec.log_ladder(rows, t_s=t, driver=temp, driver_name="temperature (degC)", residual_steps=[2, 3])
        rec.log_residuals(
            "model3",
            ["+z", "-z", "+y"],
            np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 1.0, 0]]),
            np.array([[0.001, 0, 1.0], [0, 0.02, -1.0], [0, 1.0, -0.005]]),
        )
    r = load_rrd(out)

    # model3 and the final model: disjoint colours, each the colour of its own bars
    c3 = r.static("/ladder/steps/02/residual_mg", "SeriesPoints:colors")
    c4 = r.static("/ladder/steps/03/residual_mg", "SeriesPoints:colors")
    assert len(set(c3)) == 3 and not set(c3) & set(c4)
    legend = r.static("/charts/ladder/legend", "Points2D:labels")
    assert legend == ["0 model1", "1 model2", "2 model3", "3 +temp_bias"]
    bar_colors = r.static("/charts/ladder/legend", "Points2D:colors")
    assert c3[1] == bar_colors[2] and c4[1] == bar_colors[3]  # y in the step's own colour
    names = r.static("/ladder/steps/03/residual_mg", "SeriesPoints:names")
    assert names[0].startswith("3 +temp_bias") and "/" not in names[0]

    # the driver (degC) is logged once, and no view puts it on the residuals' axis (mg)
    _, drv = r.series("/ladder/driver")
    np.testing.assert_allclose(drv[:, 0], temp)
    assert not [e for e in r.entities if e.startswith("/ladder/steps/") and e.endswith("/driver")]
    ts_views = [v for v in r.views() if v["class"] == "TimeSeries"]
    for v in ts_views:
        assert not (_covers(v, "/ladder/driver") and _covers(v, "/ladder/steps/02/residual_mg")), v
    assert any(_covers(v, "/ladder/driver") for v in ts_views)

    # the residual bars are named by pose, one bar per pose and axis, longest where the residual is
    ticks = r.static("/charts/residuals/model3/ticks", "Points2D:labels")
    assert ticks[:3] == ["+z", "-z", "+y"] and any(s.endswith(" mg") for s in ticks[3:])
    strips = r.static("/charts/residuals/model3/bars", "LineStrips2D:strips")
    radii = r.static("/charts/residuals/model3/bars", "LineStrips2D:radii")
    assert all(np.ptp(np.asarray(s), axis=0).max() > 0 for s in strips)  # none of zero length (not drawn)
    lengths = [abs(s[-1][1] - s[0][1]) + 2 * rad for s, rad in zip(strips, radii, strict=True)]  # drawn
    assert len(strips) == 9  # 3 poses x 3 axes
    assert int(np.argmax(lengths)) == 3 * 1 + 1  # pose -z, axis y: the -20 mg residual
    assert lengths[0] == pytest.approx(lengths[8] / 5, rel=0.05)  # +z x: -1 mg, +y z: +5 mg


def test_demo_layout_separates_axes_and_frames_the_truth(tmp_path: Path) -> None:
    t, temp, rows = _ladder()
    ts = np.linspace(0.0, 60.0, 200)
    truth = np.column_stack([3 * np.sin(ts / 10), 3 * np.cos(ts / 10) - 3, 0 * ts])
    bad = truth + np.column_stack([0.02 * ts**2, 0.01 * ts**2, 0.3 * ts])  # 70 m off at the end
    down = np.column_stack([-0.2 * ts**2, -0.01 * ts**2, 0.001 * ts])  # from 0 downwards
    data = DemoData(
        static_tracks={"Model 1": (ts, down), "Model 3": (ts, 0.002 * np.column_stack([ts, -ts, ts]))},
        robot_tracks={"truth": (ts, truth), "Model 3": (ts, bad)},
        robot_errors={"Model 3": (ts, np.linalg.norm(bad - truth, axis=1))},
        workbench_residuals=[(t, 1e3 * rows[2].residual_g)],
        workbench_driver=[(t, temp)],
    )
    out = tmp_path / "demo.rrd"
    with RunRecording(f"save:{out}", blueprint=demo_blueprint(data, first=2)) as rec:
        rec.log_ladder(rows, t_s=t, driver=temp, driver_name="temperature (degC)", residual_steps=[2, 3])
        rec.log_track("robot/truth", ts, truth)
        rec.log_track("robot/Model 3", ts, bad)
    r = load_rrd(out)
    views = r.views()
    ts_views = [v for v in views if v["class"] == "TimeSeries"]
    assert not [
        v for v in ts_views if _covers(v, "/ladder/driver") and _covers(v, "/ladder/steps/02/residual_mg")
    ]
    assert [v for v in views if v["origin"] == "/charts/ladder" and v["class"] == "2D"]

    # the robot's 3D view looks at the true path's centre from a distance set by the truth, not by
    # the failing track (which ends 70 m away)
    robot = next(
        e for e, c in r.blueprint.items() if c.get("ViewBlueprint:space_origin") == ["/world/tracks/robot"]
    )
    eye = r.blueprint[robot + "/EyeControls3D"]
    centre = 0.5 * (truth.min(axis=0) + truth.max(axis=0))
    np.testing.assert_allclose(eye["EyeControls3D:look_target"][0], centre, atol=1e-6)
    dist = np.linalg.norm(np.asarray(eye["EyeControls3D:position"][0]) - centre)
    assert 1.0 < dist < 3 * np.linalg.norm(np.ptp(truth, axis=0)) < np.linalg.norm(bad[-1] - truth[-1])

    # every framed plot's y axis is set from its own data: a track within ±0.12 m is not on -1..1
    ranges = [c["ScalarAxis:range"][0] for c in r.blueprint.values() if "ScalarAxis:range" in c]
    small = [hi - lo for lo, hi in ranges if hi - lo < 1.0]
    assert len(small) == 1 and small[0] < 0.5, ranges  # 0.24 m of data ...
    lo, hi = next((lo, hi) for lo, hi in ranges if hi - lo < 1.0)
    assert lo <= -0.2 and hi >= 0.2  # ... on an axis out to the ticks at +-0.2: -0.2, -0.1, 0, 0.1, 0.2


def test_y_range_ticks_and_legend_corner() -> None:
    import rerun.blueprint as rrb

    from accellog.present.rrd.demo_layout import tick_range

    # an axis reaches past the outer ticks, so '0' is never the only labelled value
    for v in (
        np.array([-14.0, 15.0]),
        np.array([0.0, 0.042]),
        np.array([20.0, 40.0]),
        np.array([-800.0, 0.0]),
    ):
        lo, hi = tick_range(v)
        step = float(np.diff(nice_ticks(v.min(), v.max(), n=6))[0])  # the data's own 1-2-5 step
        inside = np.arange(np.ceil(lo / step), np.floor(hi / step) + 1) * step
        assert lo < v.min() and hi > v.max() and len(inside) >= 3 and hi - lo < 2.5 * np.ptp(v), (v, lo, hi)

    lo, hi = y_range(np.array([0.0, 0.03, -0.01]))
    assert lo < -0.01 and hi > 0.03 and hi - lo < 0.06
    assert y_range(np.zeros(5)) == (-1.0, 1.0)
    for lo, hi in ((-3.2, 47.0), (0.0, 0.042), (-880.0, 65.0), (1.0, 1.0)):
        ticks = nice_ticks(lo, hi)
        step = np.diff(ticks)
        assert ticks[0] <= lo and ticks[-1] >= hi and 2 <= len(ticks) <= 7, (lo, hi, ticks)
        np.testing.assert_allclose(step, step[0])  # even steps of 1, 2 or 5 x 10^k
        assert round(step[0] / 10.0 ** np.floor(np.log10(step[0])), 9) in (1.0, 2.0, 5.0)
        assert 0.0 in ticks or lo > 0  # zero is a tick when it is in range
    # a curve from 0 at the top-left falling to the bottom-right leaves the other two corners free
    t = np.linspace(0, 60, 300)
    corner = legend_corner([(t, -(t**2))])
    assert corner in (rrb.components.Corner2D.LeftBottom, rrb.components.Corner2D.RightTop)
    # a rising curve: the top-left or the bottom-right
    corner = legend_corner([(t, t**2)])
    assert corner in (rrb.components.Corner2D.LeftTop, rrb.components.Corner2D.RightBottom)


def _latest(r, entity: str, component: str) -> list:
    """A static component as the viewer shows it: the row written last (largest RowId), whatever
    the order of the chunks in the file."""
    tbl = r._table(entity, component)
    rows = [
        (bytes(rid), v)
        for rid, v in zip(tbl["rerun.controls.RowId"].to_pylist(), tbl[component].to_pylist(), strict=True)
        if v is not None
    ]
    return max(rows, key=lambda x: x[0])[1]


def test_coinciding_3d_labels_are_merged(tmp_path: Path) -> None:
    t = np.linspace(0.0, 60.0, 50)
    far = np.column_stack([-5 * t, 4 * t, 0 * t])  # ends at (-300, 240, 0) m
    near_a = 0.001 * np.column_stack([t, t, t])  # ends 0.06 m from the origin
    near_b = 0.002 * np.column_stack([t, -t, t])
    out = tmp_path / "tracks.rrd"
    with RunRecording(f"save:{out}") as rec:
        for label, d in (("test/far", far), ("test/a", near_a), ("test/b", near_b)):
            rec.log_track(label, t, d)
    r = load_rrd(out)
    lab = {k: _latest(r, f"/world/tracks/test/{k}/final", "Points3D:labels") for k in ("far", "a", "b")}
    assert lab["far"] == [lab["far"][0]] and lab["far"][0].startswith("far:")
    merged = [k for k in ("a", "b") if "\n" in lab[k][0]]
    assert len(merged) == 1
    other = "a" if merged == ["b"] else "b"
    assert lab[other][0].split(":")[0] in lab[merged[0]][0]  # both names on one label
    assert _latest(r, f"/world/tracks/test/{other}/final", "Points3D:show_labels") == [False]
    # the points themselves are untouched
    np.testing.assert_allclose(
        np.asarray(r.static("/world/tracks/test/b/final", "Points3D:positions")).reshape(3), near_b[-1]
    )
    # the strips keep their names in the data but do not draw them (the final point carries them)
    assert r.static("/world/tracks/test/far", "LineStrips3D:show_labels") == [False]


def test_log_ladder_bars_near_one_are_visible_and_show_their_values(tmp_path: Path) -> None:
    """On the log scale a chi2/dof of 0.9 is a bar (from a floor below the smallest value), not a
    sliver at 1, and each bar's value is written over it when there is room."""
    from accellog.present.rrd.bars2d import H, log_bar_groups

    out = tmp_path / "bars.rrd"
    with RunRecording(f"save:{out}") as rec:
        log_bar_groups(rec, "charts/t", ["chi2/dof"], ["a", "b"], [(1, 2, 3), (4, 5, 6)], np.array([[547.0, 0.9]]),
                       log10=True)  # fmt: skip
    r = load_rrd(out)
    strips = r.static("/charts/t/bars", "LineStrips2D:strips")
    radii = r.static("/charts/t/bars", "LineStrips2D:radii")
    length = [abs(s[-1][1] - s[0][1]) + 2 * rad for s, rad in zip(strips, radii, strict=True)]
    assert length[1] > 0.1 * H and length[0] > 2 * length[1]
    assert r.static("/charts/t/values", "Points2D:labels") == ["547", "0.9"]
    ticks = r.static("/charts/t/ticks", "Points2D:labels")
    assert "0.1" in ticks and "1000" in ticks  # whole decades from below 0.9 to above 547


def test_ladder_chart_draws_no_empty_group(tmp_path: Path) -> None:
    """Without a static test no step has a drift: its group is not drawn (an empty group read as
    zero drift)."""
    _, _, rows = _ladder()
    for r in rows:
        r.drift_m = None
    out = tmp_path / "ladder.rrd"
    with RunRecording(f"save:{out}") as rec:
        rec.log_ladder(rows)
    ticks = load_rrd(out).static("/charts/ladder/ticks", "Points2D:labels")
    assert "χ²/dof (fit)" in ticks and "held-out RMS (mg)" in ticks and "static-test drift (m)" not in ticks


def test_a_constant_temperature_is_drawn_flat(tmp_path: Path) -> None:
    """The demo's calibration tab: a chip at 25 degC with +-0.05 degC quantisation noise on an axis
    at least MIN_TEMP_SPAN_DEGC tall (it filled the panel under one tick), its ticks labelled."""
    from accellog.present.rrd.demo_layout import MIN_TEMP_SPAN_DEGC

    t = np.linspace(0.0, 300.0, 3000)
    temp = 25.0 + np.random.default_rng(1).choice([-0.05, 0.0, 0.05], t.size)
    out = tmp_path / "demo.rrd"
    data = DemoData(calibration_temperature=[(t, temp)])
    with RunRecording(f"save:{out}", blueprint=demo_blueprint(data, first=1)) as rec:
        rec.log_temperature(t, temp)
    r = load_rrd(out)
    view = next(e for e, c in r.blueprint.items() if c.get("ViewBlueprint:space_origin") == ["/temperature"])
    lo, hi = r.blueprint[view + "/ScalarAxis"]["ScalarAxis:range"][0]
    assert hi - lo >= MIN_TEMP_SPAN_DEGC and lo < 24.0 and hi > 26.0 and lo < temp.min() and hi > temp.max()


def test_a_diagnosis_recording_opens_on_what_is_missing(tmp_path: Path) -> None:
    """diagnose --rrd: the first tab is the residual against the driver it follows, before and
    after the chosen effect, under one line naming it (the recording said nothing on screen and
    half of it was raw data)."""
    from support.synthetic import synthetic_obs, true_theta

    from accellog.calibrate.diagnosis.diagnose import diagnose
    from accellog.calibrate.model.compose import build_model
    from accellog.present.residual_views import write_diagnosis_rrd

    truth = build_model("model3+temp_bias")
    th = true_theta(truth, {"bT_x": 1e-3, "bT_y": -8e-4, "bT_z": 5e-4}, seed=2)
    obs = synthetic_obs(
        truth, th, protocol="24", temp_path=lambda t: 25 + 10 * np.sin(2 * np.pi * t / t.max()), seed=4
    )
    d = diagnose(obs, build_model("model3"))
    assert d.best == "temp_bias"
    out = tmp_path / "diag.rrd"
    write_diagnosis_rrd(out, None, d, obs)
    r = load_rrd(out)
    said = r.static("/docs/verdict", "TextDocument:text")[0]
    assert said.startswith("## model3: missing: temp_bias (chi2/dof ")
    import uuid

    root = uuid.UUID(bytes=bytes(r.blueprint["/viewport"]["ViewportBlueprint:root_container"][0]))
    first = "/" + r.blueprint[f"/container/{root}"]["ContainerBlueprint:contents"][0]
    tab = r.blueprint[first]
    assert tab["ContainerBlueprint:display_name"] == ["residual vs temperature (degC): before / after"]
    top = "/" + tab["ContainerBlueprint:contents"][0]
    assert r.blueprint[top]["ViewBlueprint:space_origin"] == ["/docs/verdict"]
