"""The one evaluate / drift / integrate path against plain numpy on the same samples.

A static emulated session is read as many small blocks (store.source streams it chunk group by
chunk group); its numbers must equal what a few lines of numpy compute from the whole sample arrays
with the calibration's own S and b: f = (a' - b) S^-T, a = f g_local / truth_g - u g_local, v and d
by cumulative trapezoid over the recorded times (scipy), the drift polynomial by least squares on
[1, t, t^2 / 2].
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from accellog.flows.simulate import Scenario, simulate
from accellog.flows.stages import run_drift, run_evaluate, run_fit, run_integrate
from accellog.store.mcap import fastread
from accellog.store.reader import read_session
from accellog.store.source import open_source


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("oracle")
    simulate(Scenario(protocol="six", hold_s=4.0, move_s=1.0, sample_rate_hz=500.0, seed=5), d / "six.mcap")
    simulate(Scenario(protocol="+z", hold_s=40.0, move_s=1.0, sample_rate_hz=500.0, seed=6), d / "z.mcap")
    cal = run_fit(d / "six.mcap", gyro=False).cal
    return d, cal


@pytest.fixture
def small_groups(monkeypatch):
    monkeypatch.setattr(fastread, "_GROUP_BYTES", 16 << 10)


def _numpy_track(cal, path):
    """(t, v, d) of the session at path with the calibration applied, in plain numpy."""
    s = read_session(path)
    S, b = cal.S_b()
    f = (s.accel_g - b) @ np.linalg.inv(S).T
    g = cal.local_gravity_mps2
    a = f * g / cal.truth_g - np.asarray(s.poses[0].up_sensor, float) * g
    v = cumulative_trapezoid(a, s.t_s, axis=0, initial=0.0)
    return s.t_s, v, cumulative_trapezoid(v, s.t_s, axis=0, initial=0.0)


def test_streamed_evaluate_equals_numpy(files, small_groups):
    d, cal = files
    assert sum(1 for _ in open_source(d / "z.mcap").blocks()) > 10  # really many blocks
    ev = run_evaluate(d / "z.mcap", cal, include_raw=False, stream=True)[0]
    t, _v, disp = _numpy_track(cal, d / "z.mcap")
    assert ev.t_end_s == pytest.approx(t[-1])
    np.testing.assert_allclose(ev.disp_end_m, disp[-1], rtol=1e-9, atol=1e-12)
    k = np.searchsorted(t, 30.0)  # the 30 s figure: the sample at or just after 30 s
    assert np.all(np.abs(ev.disp_at(30.0) - disp[k]) <= np.abs(disp[k] - disp[k - 1]) + 1e-12)


def test_integrate_csv_equals_numpy(files, small_groups, tmp_path):
    d, cal = files
    res = run_integrate(d / "z.mcap", cal, output=tmp_path / "i.csv")
    rows = np.loadtxt(tmp_path / "i.csv", delimiter=",", skiprows=1)
    t, v, disp = _numpy_track(cal, d / "z.mcap")
    np.testing.assert_allclose(rows[:, 0], t, rtol=1e-8)
    np.testing.assert_allclose(rows[:, 1:4], v, rtol=1e-7, atol=1e-9)  # the CSV holds 9 digits
    np.testing.assert_allclose(rows[:, 4:7], disp, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(res.evaluation.disp_end_m, disp[-1], rtol=1e-9)


def test_drift_polynomial_equals_numpy_least_squares(files, small_groups):
    d, cal = files
    out = run_drift(d / "z.mcap", cal)
    t, _v, disp = _numpy_track(cal, d / "z.mcap")
    A = np.column_stack([np.ones_like(t), t, 0.5 * t**2])
    q = np.linalg.lstsq(A, disp, rcond=None)[0].T  # rows x, y, z; columns q0, q1, q2
    np.testing.assert_allclose(out.drift.q, q, rtol=1e-6, atol=1e-9)
    after = disp[-1] - A[-1] @ q.T
    np.testing.assert_allclose(out.fit_eval.disp_end_drift_m, after, rtol=1e-5, atol=1e-6)


def test_streamed_fit_recovers_the_emulators_truth(tmp_path, small_groups):
    """fit on a file read in many blocks against the chip's known errors (the emulator's truth):
    the bias within 3 sigma (sigma with the 2 mg bound of the emulator's placement), S to 1e-3."""
    chip = {
        "bias_g": [0.030, -0.020, 0.050],
        "scale": [0.010, -0.020, 0.015],
        "cross_axis": [[0.0, 0.005, -0.004], [0.003, 0.0, 0.006], [-0.005, 0.002, 0.0]],
        "noise_density_g_per_rtHz": [300e-6] * 3,
    }
    p = tmp_path / "chip.mcap"
    simulate(Scenario(protocol="six", hold_s=6.0, move_s=1.0, sample_rate_hz=500.0, seed=8,
                      errors="perfect", gyro_errors="perfect", set=chip), p)  # fmt: skip
    assert sum(1 for _ in open_source(p).blocks()) > 10
    out = run_fit(p, gyro=False)
    S, b = out.cal.S_b()
    sig_b = out.fit.sigma[:3]
    np.testing.assert_array_less(np.abs(b - chip["bias_g"]), 3 * np.hypot(sig_b, 1e-5))
    S_true = np.eye(3) + np.diag(chip["scale"]) + np.asarray(chip["cross_axis"])
    np.testing.assert_allclose(S, S_true, atol=1e-3)
