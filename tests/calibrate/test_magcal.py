"""Magnetometer calibration on an emulated rotation session with known hard iron, soft iron and local field:
recovered within the reported uncertainties, stored in the calibration file, applied by `apply`, shown on a
sphere in the .rrd; the residual diagnosis finds a field that changes with time."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rrd_readback import load_rrd

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.calibrate.mag.magnetometer import fit_magnetometer
from accellog.cli import main
from accellog.core.errors import InputError, ModelError
from accellog.core.jsonio import dumps
from accellog.flows.apply import run_apply
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session, read_vector3

FIELD = np.array([20.0, 0.0, -45.0])
HARD = np.array([30.0, -12.0, 8.0])
W = np.array([[1.05, 0.02, 0.0], [0.02, 0.97, 0.01], [0.0, 0.01, 0.98]])


@pytest.fixture(scope="module")
def rotation(tmp_path_factory):
    d = tmp_path_factory.mktemp("mag")
    mag = {"field_uT": FIELD.tolist(), "hard_iron_uT": HARD.tolist(), "soft_iron": W.tolist()}
    simulate(
        Scenario(protocol="24", hold_s=1.0, move_s=1.5, sample_rate_hz=50.0, seed=3, magnetometer=mag),
        d / "rot.mcap",
    )
    simulate(Scenario(protocol="six", hold_s=4.0, move_s=2.0, sample_rate_hz=100.0, seed=1), d / "cal.mcap")
    assert main(["fit", str(d / "cal.mcap"), "-o", str(d / "cal.json")]) == 0
    return d


def test_hard_and_soft_iron_recovered_within_uncertainties(rotation, capsys):
    d = rotation
    capsys.readouterr()
    args = ["magcal", str(d / "rot.mcap"), "--field-uT", f"{np.linalg.norm(FIELD):.4f}", "--json"]
    assert (
        main([*args, "--rrd", str(d / "mag.rrd"), "--cal", str(d / "cal.json"), "-o", str(d / "calm.json")])
        == 0
    )
    r = json.loads(capsys.readouterr().out)
    scale = np.linalg.det(W) ** (1 / 3)  # det(A) = 1: the field carries the overall scale of W
    A_true, F_true = np.linalg.inv(W) * scale, np.linalg.norm(FIELD) * scale
    h, hs = np.array(r["hard_iron_uT"]), np.array(r["hard_iron_sigma_uT"])
    A, As = np.array(r["soft_iron"]), np.array(r["soft_iron_sigma"])
    assert np.all(np.abs(h - HARD) < 3 * hs) and np.all(hs < 0.1)
    assert np.all(np.abs(A - A_true) < 3 * As) and np.all(As < 2e-3)
    assert abs(r["field_uT"] - F_true) < 3 * r["field_sigma_uT"]
    assert r["residual_rms_uT"] < 1.5 * r["noise_uT"]
    assert not any(t["flagged"] for t in r["trends"])
    # the calibration file carries it; the rrd shows corrected samples on the sphere of radius F
    c = load_calibration(d / "calm.json")
    assert c.magnetometer.form == "sym" and len(c.magnetometer.trends) == len(r["trends"]) > 0
    assert json.loads(dumps([t.to_dict() for t in c.magnetometer.trends])) == r["trends"]
    c.save(d / "calm_again.json")  # read and written again: the same file
    assert (d / "calm_again.json").read_bytes() == (d / "calm.json").read_bytes()
    rrd = load_rrd(d / "mag.rrd")
    pts = np.asarray(rrd.static("/mag/corrected", "Points3D:positions"), float).reshape(-1, 3)
    raw = np.asarray(rrd.static("/mag/raw", "Points3D:positions"), float).reshape(-1, 3)
    assert np.std(np.linalg.norm(pts, axis=1)) < 0.5 < np.std(np.linalg.norm(raw, axis=1))
    assert np.mean(np.linalg.norm(pts, axis=1)) == pytest.approx(r["field_uT"], abs=0.05)


def test_apply_corrects_the_magnetometer(rotation):
    d = rotation
    out = run_apply(d / "rot.mcap", d / "calm.json", d / "applied.mcap")
    s = read_session(d / "rot.mcap")
    t, v, unit, frame = read_vector3(out, "mag_calibrated")
    mc = load_calibration(d / "calm.json").magnetometer
    assert unit == "uT" and frame == "AK8963"
    np.testing.assert_allclose(t, s.mag_t_s, atol=1e-9)
    np.testing.assert_allclose(v, mc.correct(s.mag_uT), rtol=1e-12)
    np.testing.assert_array_equal(read_session(out).mag_counts, s.mag_counts)  # raw samples untouched


def test_residual_diagnosis_finds_a_hard_iron_that_follows_a_motor_current(rotation):
    s = read_session(rotation / "rot.mcap")
    current_A = (np.floor(s.mag_t_s / 2.5) % 2).astype(float)  # a motor switched on and off every 2.5 s
    shift = np.array([2.0, -1.0, 0.5])  # uT per A, AK8963 axes
    m = s.mag_uT + current_A[:, None] * shift
    c = fit_magnetometer(m, "sym", drivers={"motor current": (current_A, "A"), "time": (s.mag_t_s, "s")})
    motor, time = c.trends
    assert motor.flagged and motor.chi2 > 50 * time.chi2  # drivers are regressed one at a time
    A = c.soft_iron  # d is the shift seen in corrected axes: A shift
    np.testing.assert_allclose(motor.shift, A @ shift, atol=4 * motor.shift_sigma.max() + 0.05)
    assert any("motor current" in n for n in c.notes)
    clean = fit_magnetometer(s.mag_uT, "sym", drivers={"motor current": (current_A, "A")})
    assert not clean.trends[0].flagged


def test_bad_magnetometer_input(rotation, tmp_path, capsys):
    assert main(["magcal", str(rotation / "cal.mcap")]) == 2
    assert "no magnetometer samples" in capsys.readouterr().err
    a = np.linspace(0, 2 * np.pi, 400)
    flat = np.column_stack([40 * np.cos(a), 40 * np.sin(a), np.zeros_like(a)])
    with pytest.raises(ModelError, match="plane"):
        fit_magnetometer(flat)
    with pytest.raises(InputError, match="form"):
        fit_magnetometer(flat, "full")
