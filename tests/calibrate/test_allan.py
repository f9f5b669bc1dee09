"""Allan-variance noise characterisation: equal to allantools, noise terms recovered on emulated truth
(many seeds, within their intervals), the streaming CLI on MCAP and on the real capstone recording."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import allantools
import numpy as np
import pytest
from rrd_readback import load_rrd
from support.static_noise import (
    ACCEL_LSB,
    BW_HZ,
    GYRO_LSB,
    static_model,
    static_samples,
    write_static_mcap,
)

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.calibrate.calfile.noise_section import AxisNoiseTerms, NoiseSection, NoiseTerm, SensorNoiseTerms
from accellog.calibrate.noise.allan import AllanAccumulator, edf_simple, oadev
from accellog.calibrate.noise.noise_model import fit_axis
from accellog.calibrate.observe.hold_noise import integrated_autocorr_time
from accellog.cli import main
from accellog.flows.characterise import characterise_noise, tau_min_samples
from accellog.flows.simulate import Scenario, simulate

G0 = 9.80665


def emulated_white_N(density: float, rate_hz: float) -> float:
    """Allan white noise N of the emulator's DLPF-shaped noise (first-order, pole a = exp(-2 pi f_c / f_s)):
    per-sample sigma = density sqrt(pi f_c / 2), unit-energy taps a^k, so N = sigma sqrt((1 + a) / (1 - a) / f_s);
    = density / sqrt(2) (the one-sided density's Allan N) within 0.3 % at 1 kHz."""
    a = math.exp(-2 * math.pi * BW_HZ / rate_hz)
    sigma = density * math.sqrt(math.pi * BW_HZ / 2)
    return sigma * math.sqrt((1 + a) / (1 - a) / rate_hz)


# -- against allantools -------------------------------------------------------------------------------


def test_oadev_equals_allantools_chunked_and_whole():
    m = static_model(300.0, 4, gyro_bi_dps=0.003, gyro_rw=3e-4, accel_bi_g=40e-6)
    _, ac, gc, _ = static_samples(m, 200.0, 0, 60_000)
    y = np.concatenate([ac * G0 / ACCEL_LSB, np.deg2rad(gc / GYRO_LSB)], axis=1)
    whole = oadev(y, 200.0)
    acc = AllanAccumulator(200.0, 6)
    for part in np.array_split(y, [1, 7, 5000, 5001, 33_333]):  # uneven chunks, one of 1 sample
        acc.add(part)
    chunked = acc.curve()
    assert np.all(chunked.stride == 1)
    for k in range(6):
        taus, ad, _, ns = allantools.oadev(y[:, k], rate=200.0, data_type="freq", taus="octave")
        n = whole.m.size
        np.testing.assert_allclose(whole.tau_s, taus[:n], rtol=0, atol=0)
        np.testing.assert_allclose(whole.adev[:, k], ad[:n], rtol=1e-9, atol=0)
        np.testing.assert_allclose(chunked.adev[:, k], ad[:n], rtol=1e-9, atol=0)
        np.testing.assert_array_equal(whole.n_terms, ns[:n])


def test_decimated_long_taus_agree_with_the_full_estimator():
    rng = np.random.default_rng(3)
    y = rng.standard_normal((1 << 16, 1)) + np.cumsum(rng.standard_normal((1 << 16, 1)), axis=0) * 1e-3
    acc = AllanAccumulator(100.0, 1, m_exact=1 << 9, decimate=1 << 4)
    for part in np.array_split(y, 13):
        acc.add(part)
    c = acc.curve()
    _, ad, _, _ = allantools.oadev(y[:, 0], rate=100.0, data_type="freq", taus=c.tau_s)
    dec = c.stride > 1
    assert dec.sum() >= 4 and np.all(c.stride[dec] == 16)
    np.testing.assert_allclose(c.adev[~dec, 0], ad[~dec], rtol=1e-9)
    # sub-sampled start points (every 16th): the same statistic within its own scatter (m/16 >= 64 starts)
    np.testing.assert_allclose(c.adev[dec, 0], ad[dec], rtol=0.05)


def test_edf_matches_allantools_simple_formulas():
    for alpha in (2, 0, -1, -2):
        for m in (1, 2, 16, 512):
            ours = float(edf_simple(100_001, m, alpha))
            theirs = max(float(allantools.edf_simple(100_001, m, alpha)), 1.0)
            assert ours == pytest.approx(theirs, rel=1e-12)


# -- emulated truth -----------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_white_noise_within_5_percent_at_1khz(seed):
    """10 min at 1 kHz, datasheet densities (300 ug/rtHz, 0.01 dps/rtHz): N within +-5 % and 3 sigma."""
    rate = 1000.0
    m = static_model(600.0, seed)
    _, ac, gc, _ = static_samples(m, rate, 0, int(600 * rate))
    y = np.concatenate([ac * G0 / ACCEL_LSB, np.deg2rad(gc / GYRO_LSB)], axis=1)
    curve = oadev(y, rate)
    tau_int = float(np.max(integrated_autocorr_time(y[:8192] - y[:8192].mean(axis=0))))
    truths = [emulated_white_N(300e-6, rate) * G0] * 3 + [np.deg2rad(emulated_white_N(0.01, rate))] * 3
    assert emulated_white_N(300e-6, rate) == pytest.approx(300e-6 / math.sqrt(2), rel=3e-3)
    for k, truth in enumerate(truths):
        ax = fit_axis(curve, k, "xyz"[k % 3], "u", tau_min_samples(tau_int) / rate)
        assert ax.white.value == pytest.approx(truth, rel=0.05)
        assert abs(ax.white.value - truth) < 3 * ax.white.sigma
        assert ax.white.sigma < 0.05 * truth


def test_bias_instability_and_random_walk_recovered_within_intervals_over_seeds():
    """10 emulated 2 h gyro sessions at 25 Hz (white, flicker and random-walk noise): every estimate within
    3 sigma of the truth, and the pulls (estimate - truth) / sigma neither too wide nor too narrow."""
    rate, dur = 25.0, 7200.0
    N_true = np.deg2rad(emulated_white_N(0.01, rate))
    B_true, K_true = np.deg2rad(0.003), np.deg2rad(3e-4)
    pulls, detected = [], []
    for seed in range(10):
        m = static_model(dur, 200 + seed, gyro_bi_dps=0.003, gyro_rw=3e-4)
        _, _, gc, _ = static_samples(m, rate, 0, int(dur * rate))
        y = np.deg2rad(gc[:, :1] / GYRO_LSB)
        tau_int = float(integrated_autocorr_time(y[:8192, 0] - y[:8192, 0].mean()))
        ax = fit_axis(oadev(y, rate), 0, "x", "rad/s", tau_min_samples(tau_int) / rate)
        detected.append((ax.bias_instability.detected, ax.random_walk.detected))
        for p, truth in ((ax.white, N_true), (ax.bias_instability, B_true), (ax.random_walk, K_true)):
            pulls.append((p.value - truth) / p.sigma)
    pulls = np.array(pulls).reshape(10, 3)
    assert np.all(np.abs(pulls) < 3.0), pulls
    rms = np.sqrt(np.mean(pulls**2, axis=0))
    assert np.all(rms > 0.3) and np.all(rms < 1.3), rms
    assert np.mean(detected, axis=0).min() >= 0.8  # B and K resolved in (nearly) every session


def test_slow_noise_is_independent_of_how_the_stream_is_cut():
    m1 = static_model(100.0, 5, gyro_bi_dps=0.01, gyro_rw=1e-3, accel_bi_g=1e-4, accel_rw=1e-5)
    m2 = static_model(100.0, 5, gyro_bi_dps=0.01, gyro_rw=1e-3, accel_bi_g=1e-4, accel_rw=1e-5)
    whole = static_samples(m1, 1000.0, 0, 140_000)
    parts = [static_samples(m2, 1000.0, a, b) for a, b in ((70_000, 140_000), (0, 70_000))]  # out of order
    np.testing.assert_array_equal(whole[2], np.concatenate([parts[1][2], parts[0][2]]))
    np.testing.assert_array_equal(whole[1], np.concatenate([parts[1][1], parts[0][1]]))


# -- the command on files -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def static_mcap(tmp_path_factory):
    d = tmp_path_factory.mktemp("noise")
    m = static_model(600.0, 21, gyro_bi_dps=0.003, accel_bi_g=40e-6)
    return write_static_mcap(d / "static.mcap", m, 600.0, 200.0)


def test_noise_cli_json_rrd_and_calibration_section(static_mcap, tmp_path, capsys):
    rrd = tmp_path / "noise.rrd"
    capsys.readouterr()
    assert main(["noise", str(static_mcap), "--json", "--rrd", str(rrd)]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["n_samples"] == 120_000 and d["rate_hz"] == 200.0 and d["gaps"] == 0
    gx = d["gyro"]["axes"][0]
    N_true = np.deg2rad(emulated_white_N(0.01, 200.0))
    assert gx["white"]["value"] == pytest.approx(N_true, rel=0.05)
    ds = gx["datasheet_units"]
    assert ds["arw_deg_per_rth"] == pytest.approx(np.rad2deg(gx["white"]["value"]) * 60.0)
    ax = d["accel"]["axes"][2]
    assert ax["datasheet_units"]["white_ug_per_rtHz"] == pytest.approx(ax["white"]["value"] / G0 * 1e6)
    assert ax["white"]["min_duration_s"] is not None
    assert set(d["kalibr"]) == {
        "accelerometer_noise_density",
        "accelerometer_random_walk",
        "gyroscope_noise_density",
        "gyroscope_random_walk",
    }
    # the .rrd holds the log-log curve: x = log10 tau, y = -log10 adev (image-style axis flipped)
    r = load_rrd(rrd)
    strip = np.asarray(r.static("/noise/gyro/x/adev", "LineStrips2D:strips")[0], float).reshape(-1, 2)
    np.testing.assert_allclose(strip[:, 0], np.log10(gx["allan"]["tau_s"]), rtol=1e-6)
    np.testing.assert_allclose(-strip[:, 1], np.log10(gx["allan"]["adev"]), rtol=1e-6)
    assert "/noise/gyro/decades" in r.entities
    # the calibration file gains a versioned noise section; the original is left alone
    cal_in = tmp_path / "cal.json"
    simulate(
        Scenario(protocol="six", hold_s=4.0, move_s=2.0, sample_rate_hz=100.0, seed=1), tmp_path / "c.mcap"
    )
    assert main(["fit", str(tmp_path / "c.mcap"), "-o", str(cal_in)]) == 0
    before = cal_in.read_bytes()
    assert (
        main(["noise", str(static_mcap), "--cal", str(cal_in), "-o", str(tmp_path / "cal_noise.json")]) == 0
    )
    assert cal_in.read_bytes() == before
    c = load_calibration(tmp_path / "cal_noise.json")
    assert c.noise.version == 1
    assert c.noise.kalibr["gyroscope_noise_density"] == pytest.approx(d["kalibr"]["gyroscope_noise_density"])
    assert c.noise.gyro.units["white"] == "rad/s/sqrt(Hz)"


def test_noise_of_the_real_capstone_static_recording(shared_data):
    """300 s static, ~179 Hz, uneven timestamps, accel only: ADEV(tau0) is sqrt(mean(diff^2) / 2) exactly."""
    path = shared_data / "capstone" / "final_trial" / "six_position_final_test_data.csv"
    m = characterise_noise(path)
    assert m.gyro is None and m.n_samples == 53_966
    assert any("uneven timestamps" in n for n in m.notes)
    raw = np.loadtxt(path, delimiter=",", skiprows=2)[:, 1:4] * G0
    expect = np.sqrt(np.mean(np.diff(raw, axis=0) ** 2, axis=0) / 2)
    adev0 = np.array([a.adev[0] for a in m.accel.axes])
    np.testing.assert_allclose(adev0, expect, rtol=1e-9)
    for a in m.accel.axes:  # white noise of an MPU-9250 at ~180 Hz: tens to hundreds of ug/rtHz
        ug = m.accel.datasheet(a)["white_ug_per_rtHz"]
        assert 30 < ug < 1000 and a.white.detected


def test_noise_refuses_bad_input_in_one_line(tmp_path, capsys, shared_data):
    assert main(["noise", str(tmp_path / "missing.mcap")]) == 2
    assert capsys.readouterr().err.strip().count("\n") == 0
    assert main(["noise", str(shared_data / "capstone" / "final_trial" / "six_position_data.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("accellog: error:") and "pose means" in err


def test_temperature_driven_stretch_is_flagged(tmp_path):
    """A die warming at 0.6 degC/min is flagged as a temperature-driven stretch (not random walk)."""
    sc = Scenario(
        protocol="+z",
        hold_s=150.0,
        sample_rate_hz=50.0,
        seed=4,
        temperature={"kind": "ramp", "T0": 25.0, "rate_degC_per_s": 0.01},
    )
    simulate(sc, tmp_path / "warm.mcap")
    m = characterise_noise(tmp_path / "warm.mcap")
    assert m.temp_segments and all(abs(s.rate_degC_per_min - 0.6) < 0.1 for s in m.temp_segments)
    assert m.temp_range_degC[1] - m.temp_range_degC[0] > 1.0
    assert any("temperature-driven" in n for n in m.notes)


def test_evaluate_uses_the_calibration_noise_floor(static_mcap, tmp_path):
    """With a noise section, evaluate's standard error of the mean is at least N / sqrt(T)."""
    from accellog.navigate.evaluate import evaluate
    from accellog.store.reader import read_session

    simulate(
        Scenario(protocol="six", hold_s=4.0, move_s=2.0, sample_rate_hz=100.0, seed=1), tmp_path / "c.mcap"
    )
    assert main(["fit", str(tmp_path / "c.mcap"), "-o", str(tmp_path / "cal.json")]) == 0
    assert (
        main(["noise", str(static_mcap), "--cal", str(tmp_path / "cal.json"), "-o", str(tmp_path / "n.json")])
        == 0
    )
    s = read_session(static_mcap)
    plain = evaluate(s, load_calibration(tmp_path / "cal.json"))
    c = load_calibration(tmp_path / "n.json")
    acc = c.noise.accel  # a floor far above the data's own sem
    axes = {ax: replace(t, white=replace(t.white, value=t.white.value * 1e3)) for ax, t in acc.axes.items()}
    c.noise = replace(c.noise, accel=replace(acc, axes=axes))
    floored = evaluate(s, c)
    assert floored.chi2_noise < 1e-3 * plain.chi2_noise
    assert any("noise floor" in n for n in floored.notes)


def test_obs_sigma_floored_by_the_noise_section():
    from accellog.calibrate.noise.noise_model import floor_obs_sigma
    from accellog.core.session import ObsTable

    n = 4
    obs = ObsTable(
        meas_g=np.zeros((n, 3)),
        sigma_g=np.full((n, 3), 1e-6),
        up_sensor=np.tile([0.0, 0.0, 1.0], (n, 1)),
        pose_id=np.zeros(n, int),
        pose_names=["+z"],
        t_s=np.arange(n, dtype=float),
        t_in_pose_s=np.arange(n, dtype=float),
        n_samples=np.array([100, 400, 1600, 6400]),
        std_g=np.zeros((n, 3)),
    )
    white = AxisNoiseTerms(white=NoiseTerm(value=G0 * 2e-4))
    section = NoiseSection(rate_hz=100.0, accel=SensorNoiseTerms(axes=dict.fromkeys("xyz", white)))
    out = floor_obs_sigma(obs, section)
    np.testing.assert_allclose(out.sigma_g[:, 0], 2e-4 / np.sqrt([1.0, 4.0, 16.0, 64.0]))
    assert obs.sigma_g[0, 0] == 1e-6  # the input is not altered
    out200 = floor_obs_sigma(obs, section, rate_hz=200.0)  # the session's own rate sets the window length
    np.testing.assert_allclose(out200.sigma_g[:, 0], 2e-4 / np.sqrt([0.5, 2.0, 8.0, 32.0]))


def test_diagnose_judges_chi2_against_the_characterised_noise(static_mcap, tmp_path, capsys):
    """diagnose --noise-from: a calibration whose noise section says 10x the real white noise lowers
    chi2/dof by about 100x (windows' sigma floored by N / sqrt(T)); no section is one clear line."""
    sim = tmp_path / "c.mcap"
    simulate(Scenario(protocol="six", hold_s=4.0, move_s=2.0, sample_rate_hz=200.0, seed=3), sim)
    cal, noisy = tmp_path / "cal.json", tmp_path / "cal_noise.json"
    assert main(["fit", str(sim), "-o", str(cal)]) == 0
    assert main(["noise", str(static_mcap), "--cal", str(cal), "-o", str(noisy)]) == 0
    c = json.loads(noisy.read_text())
    for ax in "xyz":
        c["noise"]["accel"]["axes"][ax]["white"]["value"] *= 10.0
    noisy.write_text(json.dumps(c))
    capsys.readouterr()
    assert main(["diagnose", str(sim), "-m", "model1", "--json"]) == 0
    plain = json.loads(capsys.readouterr().out)
    assert main(["diagnose", str(sim), "-m", "model1", "--json", "--noise-from", str(noisy)]) == 0
    floored = json.loads(capsys.readouterr().out)
    assert floored["chi2_dof"] < plain["chi2_dof"] / 20
    assert main(["diagnose", str(sim), "--noise-from", str(cal)]) != 0
    err = capsys.readouterr().err
    assert "no noise section" in err and len(err.strip().splitlines()) == 1
