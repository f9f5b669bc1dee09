"""A real recording with an injected effect: the workbench keeps it, with the right size.

imucal's Ferraris session (a real 16-bit IMU, six faces; ../shared/data/imucal) has real noise and
its own small errors: the workbench adds nothing to model3 on it. A nonlinearity of a few mg is
injected into its samples (a_i += k2_i a_i^2, 3-5 mg at 1 g); the workbench must find nonlin2 and
keep it, and the fitted k2 must move from the untouched recording's value by the injected k2
within 3 sigma (the recording's own nonlinearity, whatever it is, is in both fits).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.calibrate.observe.segment import observations
from accellog.flows.stages import load_input
from accellog.flows.workbench import discover

K2 = np.array([4e-3, -3e-3, 5e-3])  # 1/g


@pytest.fixture(scope="module")
def sessions(shared_data):
    s = load_input(shared_data / "imucal" / "example_ferraris_session.csv")
    return s, dataclasses.replace(s, accel_g=s.accel_g + K2 * s.accel_g**2)


def test_untouched_recording_needs_nothing(sessions):
    s, _ = sessions
    assert discover(observations(s), "model3").added == []


def test_injected_nonlinearity_is_kept_with_its_size(sessions):
    s, injected = sessions
    found = discover(observations(injected), "model3")
    assert found.added == ["nonlin2"], (found.added, found.verdict)
    m = build_model("model3+nonlin2")
    r1, r0 = fit_model(observations(injected), m), fit_model(observations(s), m)
    k = [m.param_names.index(f"k2_{a}") for a in "xyz"]
    delta, sig = r1.theta[k] - r0.theta[k], np.hypot(r1.sigma[k], r0.sigma[k])
    np.testing.assert_array_less(np.abs(delta - K2), 3 * sig)


def test_a_tie_goes_to_the_lower_order_first(shared_data):
    """The same recording with a bias tempco injected over a die temperature 25 -> 40 -> 30 degC
    (piecewise linear in time): 11 windows cannot tell temp_bias from temp_bias2 (a tie, said);
    the loop takes the linear term first (Effect.extends), never the quadratic without it."""
    s = load_input(shared_data / "imucal" / "example_ferraris_session.csv")
    T = np.interp(s.t_s, [s.t_s[0], 0.5 * (s.t_s[0] + s.t_s[-1]), s.t_s[-1]], [25.0, 40.0, 30.0])
    s = dataclasses.replace(s, temp_degC=T)
    inj = dataclasses.replace(
        s, accel_g=s.accel_g + np.array([1.0e-3, -0.7e-3, 0.5e-3]) * (T - 25.0)[:, None]
    )
    found = discover(observations(inj), "model3")
    assert found.added[0] == "temp_bias", found.added
    assert any("temp_bias2" in group for group in found.undecided) or "temp_bias2" not in found.added
