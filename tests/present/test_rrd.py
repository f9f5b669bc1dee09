"""Rerun recordings read back as a user would look at them; online integration; live sinks that die."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from accellog.calibrate.diagnosis.ladder import LadderRow
from accellog.core.errors import InputError
from accellog.core.session import Event, PoseLabel
from accellog.navigate.online import OnlineIntegrator, integrate_batch
from accellog.present.rrd.live import LiveView
from accellog.present.rrd.recording import RunRecording
from accellog.present.rrd.sinks import wait_for_port
from accellog.present.viewer import rerun_binary, stop_process

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rrd_readback import load_rrd


def _session(n: int = 4000, seed: int = 3):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.004, 0.007, n))  # uneven, like the capstone logger
    raw = rng.normal([0.09, 0.05, 0.75], 0.002, (n, 3))
    return t, raw


def _poses(t):
    return [
        PoseLabel("+z", float(t[100]), float(t[900]), (0.0, 0.0, 1.0), None, 0),
        PoseLabel("-y", float(t[1200]), float(t[2000]), (0.0, -1.0, 0.0), None, 1),
        PoseLabel("+x@90", float(t[2500]), float(t[3500]), (1.0, 0.0, 0.0), None, 2),
    ]


def test_full_recording_reads_back(tmp_path: Path) -> None:
    t, raw = _session()
    cal = (raw - [0.09, 0.05, -0.25]) @ np.diag([1.0, 1.0, 1 / 1.02])
    disp = integrate_batch(t, cal, local_gravity_mps2=9.797).disp_m
    poses = _poses(t)
    events = [
        Event(float(t[50]), "gap", "2 missing", 50, 2),
        Event(float(t[3000]), "note", "operator bumped table"),
    ]
    meas = np.array([[0.09, 0.05, 0.77], [0.09, -0.95, -0.25], [1.09, 0.05, -0.25]])
    pred = meas + np.array([[0.001, 0.0, -0.002], [0.0, 0.0005, 0.0], [0.0, 0.0, 0.003]])
    out = tmp_path / "run.rrd"
    with RunRecording(f"save:{out}", recording_id="test-run") as rec:
        rec.log_samples("raw", t, np.arange(len(t)), raw, "g")
        rec.log_samples("calibrated", t, np.arange(len(t)), cal, "g")
        rec.log_poses(poses)
        rec.log_temperature(t, 30.0 + 0.01 * t)
        rec.log_events(events)
        rec.log_residuals("model3", [p.name for p in poses], meas, pred)
        rec.log_track("model3", t, disp)
        rec.log_document("calibration/model3", "| param | value |\n|---|---|\n| b_x | 0.0900 +- 0.0001 g |")
        rec.log_ladder(
            [
                LadderRow("bias", 3, 120.0, added=["bias"], heldout_rms_g=0.008, residual_g=raw[:5] - 0.1),
                LadderRow("bias+scale", 6, 1.1, added=["bias", "scale"], heldout_rms_g=0.0009),
            ],
            t_s=t[:5],
            driver=t[:5],
            driver_name="T",
            residual_steps=[0],
        )
    assert out.exists() and not list(tmp_path.glob(".*tmp"))
    r = load_rrd(out)

    # the calibrated series are exactly the numbers passed in, on the sensor time and sample index
    ts, vals = r.series("accel/calibrated")
    np.testing.assert_array_equal(vals, cal)
    np.testing.assert_allclose(ts, t, atol=1e-9)
    idx, vals_by_index = r.series("accel/raw", timeline="sample")
    np.testing.assert_array_equal(idx, np.arange(len(t)))
    np.testing.assert_array_equal(vals_by_index, raw)

    # track: series and 3D final point equal the reported displacement
    _, d = r.series("tracks/model3")
    np.testing.assert_array_equal(d[-1], disp[-1])
    final = np.array(r.static("world/tracks/model3/final", "Points3D:positions")).reshape(3)
    np.testing.assert_allclose(final, disp[-1], rtol=1e-6)
    label = r.static("world/tracks/model3/final", "Points3D:labels")[0]
    assert f"{disp[-1][0]:+.3g}" in label

    # pose windows: hold k is 1 from its start to its end, named by its label; log lines at the starts
    for k, p in enumerate(poses):
        tp, vp = r.series(f"poses/active/{k:02d}")
        np.testing.assert_allclose(tp, [p.start_s, p.end_s], atol=1e-9)
        np.testing.assert_array_equal(vp[:, 0], [1.0, 0.0])
        assert r.static(f"poses/active/{k:02d}", "SeriesLines:names") == [f"pose {p.name}"]
    logs = r.texts("poses/log")
    assert [round(tl, 6) for tl, _ in logs] == [round(p.start_s, 6) for p in poses]
    assert all(p.name in txt for (_, txt), p in zip(logs, poses, strict=True))

    # events with lost samples, temperature, residual bars in mg
    ev = r.texts("events")
    assert "2 samples lost" in ev[0][1] and "bumped" in ev[1][1]
    _, lost = r.series("events/lost_samples")
    assert lost[:, 0].tolist() == [2.0]
    _, temp = r.series("temperature")
    np.testing.assert_array_equal(temp[:, 0], 30.0 + 0.01 * t)
    for k, a in enumerate("xyz"):
        bars = r.bar_values(f"residuals/model3/{a}")
        np.testing.assert_allclose(bars, (meas - pred)[:, k] * 1000.0, atol=1e-12)
    assert "b_x" in r.static("docs/calibration/model3", "TextDocument:text")[0]
    assert "bias+scale" in r.static("docs/ladder", "TextDocument:text")[0]
    # ladder bars: log10 per step at its index, the model in the entity name; no drift measured, no drift bars
    assert r.ladder_bars("log10_chi2_dof") == [
        (0.0, "00_bias", pytest.approx(np.log10(120.0))),
        (1.0, "01_bias_scale", pytest.approx(np.log10(1.1))),
    ]
    assert [v for _, _, v in r.ladder_bars("log10_heldout_rms_mg")] == pytest.approx(
        [np.log10(8.0), np.log10(0.9)]
    )
    assert r.ladder_bars("log10_drift_m") == []
    _, res0 = r.series("ladder/steps/00/residual_mg")
    np.testing.assert_allclose(res0, (raw[:5] - 0.1) * 1000.0)
    assert "/ladder/steps/01/residual_mg" not in r.entities

    # the blueprint shows what the user looks for, and follows the sensor time
    views = {(v["class"], v["origin"]) for v in r.views()}
    for want in [
        ("TimeSeries", "/accel/raw"),
        ("TimeSeries", "/accel/calibrated"),
        ("TimeSeries", "/tracks/model3"),
        ("3D", "/world"),
        ("2D", "/charts/residuals/model3"),  # the residual bars, named by pose
        ("2D", "/charts/ladder"),
        ("TimeSeries", "/ladder/driver"),  # the driver on its own axis, not with the residuals (mg)
        ("TextDocument", "/docs/calibration/model3"),
        ("TextLog", "/"),
    ]:
        assert want in views, f"{want} missing from {views}"
    for v in r.views():
        if v["origin"] == "/accel/raw":
            assert "/poses/active/**" in v["contents"]
    tp = r.time_panel()
    assert tp["TimePanelBlueprint:timeline"] == ["sensor_time"]
    assert tp["TimePanelBlueprint:play_state"] == [3]  # following
    # reproducible: no wall-clock log_time timeline
    assert all("log_time" not in b.schema.names for bs in r.chunks.values() for b in bs)


def test_streams_are_columnar_in_batches(tmp_path: Path) -> None:
    """A stream written in many batches reads back complete and in order; a file sink gathers small
    batches into few send_columns calls (a series whose sample timeline comes and goes too)."""
    from accellog.present.rrd.recording import COALESCE_ROWS

    t, raw = _session(n=5000)
    out = tmp_path / "batches.rrd"
    with RunRecording(f"save:{out}") as rec:
        for k, sl in enumerate(np.array_split(np.arange(len(t)), 17)):
            rec.log_samples("raw", t[sl], sl, raw[sl], "g")
            buf = raw[sl] * 2.0  # a caller reusing its buffer must not change what was gathered
            rec.log_series("mixed", t[sl], buf, ["x", "y", "z"], sample_index=sl if k >= 8 else None)
            buf[:] = np.nan
    r = load_rrd(out)
    s_idx, v = r.series("accel/raw", timeline="sample")
    np.testing.assert_array_equal(v, raw)
    np.testing.assert_array_equal(s_idx, np.arange(len(t)))
    np.testing.assert_array_equal(r.series("mixed")[1], raw * 2.0)
    scalar_chunks = [b for b in r.chunks["/accel/raw"] if "Scalars:scalars" in b.schema.names]
    assert len(scalar_chunks) == -(-len(t) // COALESCE_ROWS)  # 17 batches, one call
    assert sum("Scalars:scalars" in b.schema.names for b in r.chunks["/mixed"]) == 2  # without, with


def test_failed_run_leaves_no_file(tmp_path: Path) -> None:
    out = tmp_path / "x.rrd"
    with pytest.raises(InputError), RunRecording(f"save:{out}") as rec:
        rec.log_samples("raw", np.arange(3.0), None, np.zeros((4, 3)), "g")
    assert not out.exists() and not list(tmp_path.iterdir())


def test_bad_sink_is_a_one_line_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="unknown rerun sink"):
        RunRecording("ftp://x")
    with pytest.raises(InputError, match="does not exist"):
        RunRecording(f"save:{tmp_path}/nope/x.rrd")


@pytest.mark.parametrize("n_parts", [1, 7, 300])
def test_online_integration_equals_numpy(n_parts: int) -> None:
    """The online integrator fed n_parts pieces gives, sample by sample, what numpy and scipy give on
    the whole arrays: f = correct(reading), a = (f - up) g (up +z), v and d by cumulative trapezoid."""
    from scipy.integrate import cumulative_trapezoid

    t, raw = _session(n=6001, seed=n_parts)
    temp = 25.0 + 0.001 * np.arange(len(t))

    def correct(m, drivers):
        return (m - [0.09, 0.05, -0.25]) * (1.0 + 1e-4 * (drivers["temp_degC"][:, None] - 25.0))

    f = (raw - [0.09, 0.05, -0.25]) * (1.0 + 1e-4 * (temp[:, None] - 25.0))
    a = (f - [0.0, 0.0, 1.0]) * 9.797
    v = cumulative_trapezoid(a, t, axis=0, initial=0.0)
    want = {
        "f_g": f,
        "accel_mps2": a,
        "vel_mps": v,
        "disp_m": cumulative_trapezoid(v, t, axis=0, initial=0.0),
    }
    rng = np.random.default_rng(n_parts)
    cuts = np.sort(rng.choice(np.arange(1, len(t)), n_parts - 1, replace=False))
    oi = OnlineIntegrator(local_gravity_mps2=9.797, correct=correct)
    steps = [oi.push(t[p], raw[p], {"temp_degC": temp[p]}) for p in np.split(np.arange(len(t)), cuts)]
    for field, ref in want.items():
        got = np.concatenate([getattr(s, field) for s in steps])
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12, err_msg=field)
    np.testing.assert_allclose(oi.disp_m, want["disp_m"][-1], rtol=1e-9, atol=1e-12)
    # and the trapezoid itself is right: constant 0.01 g along x for 2 s -> 1/2 a t^2
    tt = np.linspace(0.0, 2.0, 2001)
    s = OnlineIntegrator(local_gravity_mps2=10.0).push(tt, np.tile([0.01, 0.0, 1.0], (len(tt), 1)))
    np.testing.assert_allclose(s.disp_m[-1], [0.5 * 0.1 * 4.0, 0.0, 0.0], atol=1e-12)


# -- live sinks ------------------------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _write_mcap_while_live(path: Path, live: LiveView, kill, n_batches: int = 150) -> list[float]:
    """A recorder-like loop: every batch goes to a real MCAP file and to the live view."""
    from mcap.writer import Writer

    worst = []
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="accellog-test")
        sid = w.register_schema("raw", "", b"")
        cid = w.register_channel("/imu/raw", "application/octet-stream", sid)
        for i in range(n_batches):
            idx = np.arange(i * 36, (i + 1) * 36)
            acc = np.tile([0.0, 0.0, 1.0], (36, 1)) + 1e-3 * np.sin(idx)[:, None]
            ns = idx * 1_000_000
            w.add_message(
                cid,
                log_time=int(ns[-1]),
                publish_time=int(ns[-1]),
                data=acc.astype("<f8").tobytes(),
                sequence=i,
            )
            w.flush()
            t0 = time.perf_counter()
            live.log_batch(idx / 1000.0, idx, acc, temp_degC=np.full(36, 30.0))
            live.stillness(idx[-1] / 1000.0, True, 0.001)
            if i % 50 == 0:
                live.pose_prompt("+z", (0, 0, 1), index=i // 50, total=3)
                live.running_calibration(f"| b_z | {i} |")
            worst.append(time.perf_counter() - t0)
            if i == n_batches // 4:
                kill()
            time.sleep(0.01)
        w.finish()
    return worst


def _read_mcap(path: Path) -> np.ndarray:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        msgs = [m.data for _, _, m in make_reader(f).iter_messages()]
    return np.frombuffer(b"".join(msgs), dtype="<f8").reshape(-1, 3)


def test_viewer_killed_mid_recording_does_not_touch_mcap(tmp_path: Path) -> None:
    """A real Rerun gRPC server on 127.0.0.1 dies mid-stream: the MCAP loop keeps going, the file is
    complete, the failure is counted and reported exactly once."""
    port = _free_port()
    env = dict(os.environ, RERUN_ANALYTICS="0")
    srv = subprocess.Popen(
        [
            rerun_binary(),
            "--serve-grpc",
            "--bind",
            "127.0.0.1",
            "--port",
            str(port),
            "--server-memory-limit",
            "200MB",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
        start_new_session=True,
    )
    try:
        assert wait_for_port("127.0.0.1", port, 30.0), "rerun gRPC server did not start"
        reports: list[str] = []
        run = RunRecording(f"connect:rerun+http://127.0.0.1:{port}/proxy", on_failure=reports.append)
        live = LiveView(run, integrate=True)

        def kill():
            os.killpg(srv.pid, signal.SIGKILL)
            srv.wait()

        worst = _write_mcap_while_live(tmp_path / "s.mcap", live, kill, n_batches=200)
        live.close()
    finally:
        stop_process(srv)
    acc = _read_mcap(tmp_path / "s.mcap")
    assert acc.shape == (200 * 36, 3)
    idx = np.arange(200 * 36)
    np.testing.assert_array_equal(acc, np.tile([0.0, 0.0, 1.0], (len(idx), 1)) + 1e-3 * np.sin(idx)[:, None])
    assert run.down and run.failures > 0
    assert len(reports) == 2 and "unreachable" in reports[0] and "dropped" in reports[1]
    assert max(worst) < 1.0, f"a live call stalled the loop for {max(worst):.2f} s"


@pytest.mark.slow
def test_unreachable_viewer_from_the_start(tmp_path: Path) -> None:
    reports: list[str] = []
    live = LiveView(
        RunRecording(f"connect:rerun+http://127.0.0.1:{_free_port()}/proxy", on_failure=reports.append)
    )
    worst = _write_mcap_while_live(tmp_path / "s.mcap", live, lambda: None, n_batches=120)
    live.close()
    assert _read_mcap(tmp_path / "s.mcap").shape == (120 * 36, 3)
    assert live.failures > 0 and reports and "unreachable" in reports[0]
    assert max(worst) < 1.0


def test_live_view_to_file_records_prompts_and_batches(tmp_path: Path) -> None:
    """The same LiveView calls against a file sink: what the viewer would have shown is all there,
    the sample streams as min/max envelopes of LIVE_BUCKET_S buckets (every sample on demand)."""
    from accellog.present.rrd.envelope import EnvelopeBuilder
    from accellog.present.rrd.live import LIVE_BUCKET_S

    out, full = tmp_path / "live.rrd", tmp_path / "full.rrd"
    live = LiveView(RunRecording(f"save:{out}"), integrate=True)
    worst = _write_mcap_while_live(tmp_path / "s.mcap", live, lambda: None, n_batches=60)
    live.close()
    assert max(worst) < 1.0 and live.failures == 0
    acc = _read_mcap(tmp_path / "s.mcap")
    n = acc.shape[0]
    t = np.arange(n) / 1000.0

    def envelope(v):
        eb = EnvelopeBuilder(0.0, LIVE_BUCKET_S)
        a, b = eb.push(t, v, np.arange(n)), eb.finish()
        return np.r_[a.row_index, b.row_index], np.concatenate([a.values, b.values])

    r = load_rrd(out)
    s_idx, raw = r.series("accel/raw", timeline="sample")
    want_idx, want = envelope(acc)
    assert raw.shape == (2 * round(n / 1000.0 / LIVE_BUCKET_S), 3)  # 20 ms buckets of 20 samples
    np.testing.assert_array_equal(raw, want)
    np.testing.assert_array_equal(s_idx, want_idx)
    assert raw[:, 2].max() == acc[:, 2].max() and raw[:, 2].min() == acc[:, 2].min()
    np.testing.assert_array_equal(r.series("temperature")[1], np.full((raw.shape[0], 1), 30.0))
    assert "+z" in r.static("live/prompt", "TextDocument:text")[0]
    _, still = r.series("live/stillness")
    assert still.shape == (60, 2) and still[:, 0].min() == 1.0
    _, d = r.series("tracks/live")
    integ = OnlineIntegrator()  # as the live view: batch by batch
    disp = np.concatenate([integ.push(t[a : a + 36], acc[a : a + 36]).disp_m for a in range(0, n, 36)])
    np.testing.assert_array_equal(d, envelope(disp)[1])
    assert hashlib.sha256(out.read_bytes()).hexdigest()  # file complete and readable

    live = LiveView(RunRecording(f"save:{full}", full_rate=True), integrate=True)
    _write_mcap_while_live(tmp_path / "s2.mcap", live, lambda: None, n_batches=60)
    live.close()
    r = load_rrd(full)
    np.testing.assert_array_equal(r.series("accel/raw")[1], acc)
    assert r.series("tracks/live")[1].shape == (n, 3)


def test_live_holds_logged_one_by_one_keep_their_own_series(tmp_path: Path) -> None:
    """The recorder reports each finished hold separately: hold k still lands at poses/active/{k:02d}
    with its own label (not every hold on entry 00 under the first hold's name)."""
    t, _ = _session(n=4000)
    out = tmp_path / "holds.rrd"
    live = LiveView(RunRecording(f"save:{out}"))
    for p in _poses(t):
        live.finished_pose(p)
    live.close()
    r = load_rrd(out)
    for k, p in enumerate(_poses(t)):
        tp, vp = r.series(f"poses/active/{k:02d}")
        np.testing.assert_allclose(tp, [p.start_s, p.end_s], atol=1e-9)
        np.testing.assert_array_equal(vp[:, 0], [1.0, 0.0])
        assert r.static(f"poses/active/{k:02d}", "SeriesLines:names") == [f"pose {p.name}"]


def test_every_time_series_view_shows_its_own_data_range(tmp_path: Path) -> None:
    """Issue 10 item 2: a calibration session (0-20 s, holds, temperature) and a held-out session
    (100-160 s) in one recording: each view opens on its own data's time range (not the other
    session's, not the last seconds), with an x axis of its own."""
    out = tmp_path / "ranges.rrd"
    rng = np.random.default_rng(0)
    t_cal, t_test = np.arange(2000) / 100.0, 100.0 + np.arange(6000) / 100.0
    poses = [PoseLabel("+z", 2.0, 8.0, (0, 0, 1), None, 0), PoseLabel("-z", 11.0, 18.0, (0, 0, -1), None, 1)]
    with RunRecording(f"save:{out}") as rec:
        rec.log_samples("cal", t_cal, None, rng.normal(size=(2000, 3)), "g")
        rec.log_poses(poses)
        rec.log_temperature(t_cal[::10], 30.0 + t_cal[::10] / 100)
        rec.log_samples("heldout", t_test, None, rng.normal(size=(6000, 3)), "g")
        rec.log_track("heldout/model3", t_test, rng.normal(size=(6000, 3)))
        rec.log_track("heldout/raw", t_test[:3000], rng.normal(size=(3000, 3)))
        assert rec.extents["accel/heldout"] == (100.0, t_test[-1])
    views = {v["name"]: v for v in load_rrd(out).views() if v["class"] == "TimeSeries"}
    want = {
        "accel cal": (0.0, t_cal[-1]),  # its samples and the holds inside them
        "accel heldout": (100.0, t_test[-1]),
        "temperature (degC) + lost samples": (0.0, t_cal[::10][-1]),
        "heldout/model3 (m)": (100.0, t_test[-1]),
        "heldout/raw (m)": (100.0, t_test[2999]),
    }
    assert set(want) <= set(views)
    for name, (lo, hi) in want.items():
        np.testing.assert_allclose(views[name]["time_range"], (lo, hi), atol=1e-9, err_msg=name)
        np.testing.assert_allclose(views[name]["axis_range"], (lo, hi), atol=1e-9, err_msg=name)


@pytest.mark.parametrize("gc_on", [True, False])
def test_rerun_is_imported_once_with_the_collector_left_as_it_was(gc_on: bool, tmp_path: Path) -> None:
    """The first RunRecording imports rerun with the collector paused (present.rrd.sdk); the collector
    is left as the caller had it and none of the caller's objects is frozen (a library must not)."""
    code = (
        "import gc, json, sys\n"
        f"{'' if gc_on else 'gc.disable()'}\n"
        "from accellog.present.rrd.recording import RunRecording\n"
        "before = 'rerun' in sys.modules\n"
        "RunRecording('save:' + sys.argv[1]).close()\n"
        "print(json.dumps([before, 'rerun' in sys.modules, gc.isenabled(), gc.get_freeze_count()]))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "r.rrd")],
        capture_output=True, text=True, check=True, env={**os.environ, "RERUN_ANALYTICS": "0"},
    ).stdout  # fmt: skip
    before, loaded, enabled, frozen = json.loads(out)
    assert not before and loaded and enabled == gc_on and frozen == 0
