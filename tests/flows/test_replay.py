"""Replay and compare: MCAP read-only, tracks equal the batch evaluation, .rrd read back, CLI."""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from accellog.cli import main
from accellog.core.errors import InputError
from accellog.core.session import PoseLabel, Session, SessionMeta
from accellog.flows.replay import compare, replay
from accellog.flows.stages import run_drift, run_fit
from accellog.navigate.evaluate import evaluate
from accellog.present.rrd.recording import RunRecording
from accellog.store.reader import read_session
from accellog.store.writer import write_session

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rrd_readback import load_rrd

LSB = 16384.0
S_TRUE = np.array([[1.01, 0.004, -0.003], [0.002, 0.995, 0.006], [-0.005, 0.001, 1.02]])
B_TRUE = np.array([0.03, -0.02, 0.05])


def _counts(f_g: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    a = f_g @ S_TRUE.T + B_TRUE + rng.normal(0.0, 0.002, f_g.shape)
    return np.round(a * LSB).astype(np.int32)


def _meta(rate: float) -> SessionMeta:
    return SessionMeta(
        source="emulator",
        accel_range_g=2.0,
        accel_lsb_per_g=LSB,
        sample_rate_hz=rate,
        local_gravity_mps2=9.797,
    )


def _session(counts: np.ndarray, rate: float, poses=(), temp=None) -> Session:
    n = counts.shape[0]
    return Session(
        meta=_meta(rate),
        t_s=np.arange(n) / rate,
        sample_index=np.arange(n, dtype=np.int64),
        accel_g=counts / LSB,
        accel_counts=counts,
        temp_degC=temp,
        poses=list(poses),
    )


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A six-pose calibration session, a 60 s static z-up test session (seeded), and calibrations."""
    d = tmp_path_factory.mktemp("replay")
    rng = np.random.default_rng(42)
    rate, hold = 200.0, 4.0
    ups = [(0, 0, 1), (0, 0, -1), (0, 1, 0), (0, -1, 0), (1, 0, 0), (-1, 0, 0)]
    names = ["+z", "-z", "+y", "-y", "+x", "-x"]
    per = int(hold * rate)
    f = np.concatenate([np.tile(np.array(u, float), (per, 1)) for u in ups])
    poses = [
        PoseLabel(nm, k * hold + 0.2, (k + 1) * hold - 0.2, u, None, k)
        for k, (nm, u) in enumerate(zip(names, ups, strict=True))
    ]
    write_session(d / "cal.mcap", _session(_counts(f, rng), rate, poses))
    n = int(60 * rate)
    test = _session(_counts(np.tile([0.0, 0.0, 1.0], (n, 1)), rng), rate, temp=30.0 + np.linspace(0, 0.5, n))
    write_session(d / "test.mcap", test)
    out = {"cal_session": d / "cal.mcap", "test": d / "test.mcap"}
    for model in ("model1", "model3"):
        cal = run_fit(d / "cal.mcap", model, gravity="seed", weighted=False).cal
        cal.save(d / f"{model}.json")
        out[model] = d / f"{model}.json"
    run_drift(d / "test.mcap", out["model3"]).cal.save(d / "model3_drift.json")
    out["model3_drift"] = d / "model3_drift.json"
    return out


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_replay_tracks_equal_batch_evaluation_and_rrd(files, tmp_path: Path) -> None:
    from accellog.calibrate.calfile.calibration import load_calibration

    before = _sha(files["test"])
    mtime = files["test"].stat().st_mtime_ns
    out = tmp_path / "replay.rrd"
    rec = RunRecording(f"save:{out}")
    res = replay(
        files["test"],
        cals=[files["model1"], files["model3"], files["model3_drift"]],
        speed="max",
        recording=rec,
        batch_s=7.3,
    )
    rec.close()
    # the MCAP was only read
    assert _sha(files["test"]) == before and files["test"].stat().st_mtime_ns == mtime

    s = read_session(files["test"])
    labels = [t.label for t in res.tracks]
    assert labels == ["raw", "model1", "model3", "model3_drift"]
    ev_raw = evaluate(s, None, local_gravity_mps2=9.797)
    np.testing.assert_allclose(res.track("raw").disp_end_m, ev_raw.disp_end_m, rtol=1e-12, atol=1e-12)
    for lab in ("model1", "model3", "model3_drift"):
        ev = evaluate(s, load_calibration(files[lab]))
        np.testing.assert_allclose(res.track(lab).disp_end_m, ev.disp_end_m, rtol=1e-12, atol=1e-12)
        if ev.drift_applied:
            np.testing.assert_allclose(res.track(lab).final_m, ev.disp_end_drift_m, rtol=1e-12, atol=1e-12)
    # calibration helps, the drift model most (seeded data; the physics, not a hard-coded number)
    norms = {t.label: np.linalg.norm(t.final_m) for t in res.tracks}
    assert norms["model3_drift"] < norms["model3"] < norms["raw"]

    r = load_rrd(out)
    _, raw = r.series("accel/raw")
    np.testing.assert_array_equal(raw, s.accel_g)
    _, cal3 = r.series("accel/model3")
    np.testing.assert_allclose(cal3, load_calibration(files["model3"]).correct(s), rtol=0, atol=1e-14)
    for t in res.tracks:
        _, d = r.series(f"tracks/{t.label}")
        np.testing.assert_array_equal(d[-1], t.final_m)
        final = np.array(r.static(f"world/tracks/{t.label}/final", "Points3D:positions")).reshape(3)
        np.testing.assert_allclose(final, t.final_m, rtol=1e-6, atol=1e-9)
    tt, temp = r.series("temperature")  # a short session (<= FULL_RATE_MAX_SAMPLES): every sample
    np.testing.assert_allclose(tt, s.t_s, rtol=0, atol=2e-9)  # ns on the timeline
    np.testing.assert_array_equal(temp[:, 0], s.temp_degC)
    doc = r.static("docs/replay/final_displacement", "TextDocument:text")[0]
    assert all(t.label in doc for t in res.tracks) and f"{res.track('model3').final_m[0]:+.3f}" in doc
    views = {(v["class"], v["origin"]) for v in r.views()}
    assert {("TimeSeries", f"/tracks/{lab}") for lab in labels} <= views and ("3D", "/world") in views


def test_replay_is_paced_in_sensor_time(files) -> None:
    """--speed 4 on 60 s of data asks to sleep about 15 s in total (a fake clock, real pacing logic)."""
    now = [0.0]
    slept = []

    def sleep(dt: float) -> None:
        slept.append(dt)
        now[0] += dt

    res = replay(files["test"], speed=4, clock=lambda: now[0], sleep=sleep)
    assert res.speed == 4.0
    assert sum(slept) == pytest.approx(60.0 / 4, abs=0.05)
    assert len(slept) >= 60 * 4  # many small batches (20 per wall second)


def test_replay_calibration_session_with_poses(files, tmp_path: Path) -> None:
    out = tmp_path / "cal.rrd"
    rec = RunRecording(f"save:{out}")
    res = replay(files["cal_session"], cals=[files["model3"]], speed=None, recording=rec)
    rec.close()
    assert "several pose labels" in res.tracks[0].notes[0]
    r = load_rrd(out)
    s = read_session(files["cal_session"])
    for k, p in enumerate(s.poses):
        tp, vp = r.series(f"poses/active/{k:02d}")
        np.testing.assert_allclose(tp, [p.start_s, p.end_s], atol=1e-9)
        np.testing.assert_array_equal(vp[:, 0], [1.0, 0.0])
    # calibrated accel within each hold is close to the pose's up vector (what the user checks)
    t, cal = r.series("accel/model3")
    for p in s.poses:
        m = (t >= p.start_s) & (t < p.end_s)
        np.testing.assert_allclose(cal[m].mean(axis=0), p.up_sensor, atol=2e-3)


def test_compare_cli_table_json_and_rrd(files, tmp_path: Path, capsys) -> None:
    before = _sha(files["test"])
    out = tmp_path / "cmp.rrd"
    rc = main(
        [
            "compare",
            str(files["test"]),
            "--cal",
            str(files["model1"]),
            "--cal",
            str(files["model3_drift"]),
            "--rrd",
            str(out),
            "--json",
        ]
    )
    assert rc == 0
    data = json.loads(capsys.readouterr().out)
    assert [t["label"] for t in data["tracks"]] == ["raw", "model1", "model3_drift"]
    assert data["tracks"][2]["disp_end_after_drift_m"] is not None
    assert _sha(files["test"]) == before
    r = load_rrd(out)
    for t in data["tracks"]:
        _, d = r.series(f"tracks/{t['label']}")
        np.testing.assert_allclose(d[-1], t["final_m"], rtol=1e-12)
    # the 3D tracks in colours of their own (they were all the first), the eye on every end
    colors = [r.static(f"/world/tracks/{t['label']}", "LineStrips3D:colors")[0] for t in data["tracks"]]
    assert len(set(colors)) == 3, colors
    world = next(e for e, c in r.blueprint.items() if c.get("ViewBlueprint:space_origin") == ["/world"])
    eye = r.blueprint[world + "/EyeControls3D"]
    ends = np.array([np.zeros(3)] + [t["disp_end_after_drift_m"] or t["final_m"] for t in data["tracks"]])
    centre = 0.5 * (ends.min(axis=0) + ends.max(axis=0))
    np.testing.assert_allclose(eye["EyeControls3D:look_target"][0], centre, atol=1e-6)
    rc = main(["compare", str(files["test"]), "--cal", str(files["model3"])])
    assert rc == 0
    txt = capsys.readouterr().out
    assert "model3" in txt and "final displacement" in txt


def test_replay_cli_and_errors(files, tmp_path: Path, capsys) -> None:
    out = tmp_path / "r.rrd"
    assert (
        main(
            ["replay", str(files["test"]), "--speed", "max", "--cal", str(files["model3"]), "--rrd", str(out)]
        )
        == 0
    )
    assert out.exists() and "model3" in capsys.readouterr().out
    assert main(["replay", str(files["test"]), "--speed", "fast"]) == 2
    assert "--speed 'fast'" in capsys.readouterr().err
    assert main(["replay", str(tmp_path / "missing.mcap")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["replay", str(files["test"]), "--rrd", str(out), "--rerun", "spawn"]) == 2
    assert main(["compare", str(files["test"])]) == 2
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    before = sorted(tmp_path.iterdir())
    assert main(["compare", str(files["test"]), "--cal", str(bad), "--rrd", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("accellog: error:") and "Traceback" not in err
    assert sorted(tmp_path.iterdir()) == before  # no half-written .rrd
    with pytest.raises(InputError, match="speed"):
        replay(files["test"], speed=-1)


def test_compare_seed_final_trial(shared_data: Path, tmp_path: Path) -> None:
    """Real data: the capstone final trial, full model + drift model -> about a metre (slides: -1, -1, -7 m
    on the 300 s file; here the 60 s fit file itself, where the drift model leaves centimetres)."""
    from accellog.store.importers import import_capstone

    ft = shared_data / "capstone" / "final_trial"
    cal = run_fit(
        ft / "six_position_data.csv", "model3", gravity="seed", weighted=False, local_gravity_mps2=9.797
    ).cal
    test = import_capstone(ft / "six_position_test_data.csv")
    res = compare(test, [cal], labels=["model3"], up_sensor="+z")
    np.testing.assert_allclose(res.track("model3").final_m, [-43.6, 57.6, 22.7], atol=0.1)


@pytest.fixture(scope="module")
def spiky(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Session]:
    """40 s at 1 kHz, z up, one-sample spikes (+1.5 g on x, -1.2 g on y) and a clipped stretch on z."""
    d = tmp_path_factory.mktemp("spiky")
    rng = np.random.default_rng(7)
    rate, n = 1000.0, 40_000
    counts = _counts(np.tile([0.0, 0.0, 1.0], (n, 1)), rng)
    counts[12_347, 0] += int(1.5 * LSB)  # not on a stride of n // 4000 = 10 samples
    counts[30_001, 1] -= int(1.2 * LSB)
    counts[20_000:20_400, 2] = 32767  # clipping
    s = _session(counts, rate, temp=30.0 + np.linspace(0, 0.5, n))
    write_session(d / "spiky.mcap", s, batch_size=1000)
    return d / "spiky.mcap", read_session(d / "spiky.mcap")


def test_replay_rrd_envelope_keeps_spikes_and_each_buckets_min_max(spiky, tmp_path: Path) -> None:
    """Issue 11 item 5: a long series is drawn as min/max per bucket: the spikes plain striding drops
    are in the recording, and every bucket's two rows are numpy's min and max of its samples."""
    from accellog.present.rrd.envelope import ENVELOPE_BUCKETS

    path, s = spiky
    out = tmp_path / "env.rrd"
    with RunRecording(f"save:{out}") as rec:
        replay(path, speed=None, recording=rec, up_sensor="+z")
    r = load_rrd(out)
    t, v = r.series("accel/raw")
    idx, _ = r.series("accel/raw", timeline="sample")  # the device sample index of every row
    assert len(t) % 2 == 0 and ENVELOPE_BUCKETS <= len(t) // 2 <= ENVELOPE_BUCKETS + 2
    stride = s.n // ENVELOPE_BUCKETS
    strided = s.accel_g[::stride]
    assert strided[:, 0].max() < 1.0 and strided[:, 1].min() > -0.5  # striding loses both spikes
    assert v[:, 0].max() == s.accel_g[:, 0].max() and v[:, 1].min() == s.accel_g[:, 1].min()
    assert np.count_nonzero(v[:, 2] == 32767 / LSB) >= 2 * (400 // stride - 2)  # the clipped stretch
    first, last = idx[0::2].astype(int), idx[1::2].astype(int)
    np.testing.assert_array_equal(first[1:], last[:-1] + 1)  # the buckets tile the session
    assert first[0] == 0 and last[-1] == s.n - 1
    np.testing.assert_allclose(t[0::2], s.t_s[first], rtol=0, atol=2e-9)
    np.testing.assert_allclose(t[1::2], s.t_s[last], rtol=0, atol=2e-9)
    ends = np.r_[first[1:], s.n]
    mn = np.minimum.reduceat(s.accel_g, first, axis=0)
    mx = np.maximum.reduceat(s.accel_g, first, axis=0)
    np.testing.assert_array_equal(np.minimum(v[0::2], v[1::2]), mn)
    np.testing.assert_array_equal(np.maximum(v[0::2], v[1::2]), mx)
    assert (ends - first).max() <= 2 * stride  # pixel-scale buckets
    tt, temp = r.series("temperature")  # an envelope too, tracks every k-th sample + the last
    assert len(tt) <= 2 * ENVELOPE_BUCKETS + 4 and temp[:, 0].max() == s.temp_degC.max()
    _, d = r.series("tracks/raw")
    assert len(d) <= 2 * ENVELOPE_BUCKETS + 2


def test_replay_streams_and_full_rate_on_demand(spiky, tmp_path: Path, capsys) -> None:
    """The streamed file and the Session in memory replay to the same tracks; --rrd-full logs every
    sample."""
    path, s = spiky
    a = replay(path, speed=None, batch_s=3.7)
    b = replay(s, speed=None)
    np.testing.assert_array_equal(a.track("raw").disp_end_m, b.track("raw").disp_end_m)
    assert a.n == b.n == s.n and a.t_end_s == b.t_end_s
    out = tmp_path / "full.rrd"
    assert main(["replay", str(path), "--speed", "max", "--up", "+z", "--rrd", str(out), "--rrd-full"]) == 0
    capsys.readouterr()
    t, v = load_rrd(out).series("accel/raw")
    np.testing.assert_allclose(t, s.t_s, rtol=0, atol=2e-9)
    np.testing.assert_array_equal(v, s.accel_g)


def _full_passes(monkeypatch) -> list[int]:
    """Counts the passes over a streamed file's samples that read it to its end (store.source)."""
    import accellog.store.source as source

    done: list[int] = []
    real = source.iter_imu

    def counted(path):
        yield from real(path)
        done.append(1)  # reached only when the pass read every block

    monkeypatch.setattr(source, "iter_imu", counted)
    return done


@pytest.mark.parametrize("up", ["+z", None])
def test_replay_reads_the_file_once(files, monkeypatch, up) -> None:
    """Without a recording the stamps are checked along the replay's own pass: one pass over the
    file, also when the up vector is inferred from the mean reading (the test file has no label)."""
    done = _full_passes(monkeypatch)
    res = replay(files["test"], cals=[files["model3"]], speed=None, up_sensor=up)
    assert len(done) == 1 and res.n == 12_000 and list(res.up_sensor) == [0, 0, 1]
    done.clear()
    out = Path(str(files["test"]) + ".rrd")
    rec = RunRecording(f"save:{out}", recording_id="passes")
    replay(files["test"], cals=[files["model3"]], speed=None, up_sensor=up, recording=rec)
    rec.close()
    assert len(done) == 2  # a recording: the stamps first (with the mean's pass when inferred)


@pytest.mark.parametrize("with_rrd", [False, True])
def test_replay_refuses_bad_stamps_in_one_line(files, tmp_path: Path, capsys, with_rrd) -> None:
    """Stamps that go backwards are refused (the stamps' line, nothing written) whether they are
    checked along the one pass or before a recording."""
    s = read_session(files["test"])
    t = s.t_s.copy()
    t[5000], t[5001] = t[5001], t[5000]
    bad = tmp_path / "bad.mcap"
    write_session(bad, Session(meta=s.meta, t_s=t, sample_index=s.sample_index, accel_g=s.accel_g,
                               accel_counts=s.accel_counts, temp_degC=s.temp_degC))  # fmt: skip
    out = tmp_path / "bad.rrd"
    args = ["replay", str(bad), "--speed", "max", "--cal", str(files["model3"])]
    assert main([*args, *(["--rrd", str(out)] if with_rrd else [])]) == 2
    err = capsys.readouterr().err
    assert "decreasing time stamp at sample 5001" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()


def _turned(path: Path) -> Path:
    """400 s at 1 kHz: +x up for the first 100 s, then +z up (the mean reading's face is +z, the
    first chunk group's +x)."""
    rng = np.random.default_rng(3)
    n, rate = 400_000, 1000.0
    f = np.tile([0.0, 0.0, 1.0], (n, 1))
    f[:100_000] = [1.0, 0.0, 0.0]
    write_session(path, _session(_counts(f, rng), rate))
    return path


def test_replay_up_guess_checked_against_the_whole_mean(tmp_path: Path, monkeypatch) -> None:
    """The up vector is guessed from the first block's mean; when the whole session's mean has
    another face the replay is made again with it (a second pass): the tracks are those of the
    session in memory, whose mean is known at once."""
    from accellog.navigate.blocks import first_mean
    from accellog.store.source import open_source

    path = _turned(tmp_path / "turned.mcap")
    assert np.argmax(np.abs(first_mean(open_source(path)))) == 0  # the guess is +x
    done = _full_passes(monkeypatch)
    a = replay(path, speed=None)
    assert len(done) == 2 and list(a.up_sensor) == [0, 0, 1]
    b = replay(read_session(path), speed=None)
    np.testing.assert_allclose(a.tracks[0].final_m, b.tracks[0].final_m, rtol=1e-12)
    assert a.tracks[0].notes == b.tracks[0].notes and "+z up" in a.tracks[0].notes[0]
