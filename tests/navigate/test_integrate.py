"""integrate: double trapezoid integration over uneven timestamps."""

from __future__ import annotations

import numpy as np
import pytest

from accellog.core.errors import InputError
from accellog.navigate.integrate import displacement, values_at


def test_constant_bias_gives_half_a_t_squared_on_uneven_times():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.002, 0.012, 12000))
    t -= t[0]
    a = np.tile([0.01, -0.02, 9.81 + 0.03], (t.size, 1))
    vel, disp = displacement(t, a, remove_gravity_mps2=(0, 0, 9.81))
    # trapezoid is exact for a constant; twice integrated: 1/2 a t^2 (up to quadratic's trapezoid error)
    expect = 0.5 * np.array([0.01, -0.02, 0.03]) * t[:, None] ** 2
    assert np.allclose(vel[-1], np.array([0.01, -0.02, 0.03]) * t[-1], rtol=1e-12)
    assert np.allclose(disp, expect, rtol=1e-4, atol=1e-9)


def test_uneven_times_matter():
    """A 1 m/s^2 step for the first half (T = 20 s) gives 3 T^2 / 8 only with the real uneven times."""
    t = np.concatenate([np.linspace(0, 10, 4001), np.linspace(10, 20, 1001)[1:]])  # fast then slow
    a = np.zeros((t.size, 3))
    a[t <= 10.0] = 1.0
    _, d = displacement(t, a, remove_gravity_mps2=None)
    assert d[-1, 0] == pytest.approx(3 * 20.0**2 / 8, rel=1e-3)
    t_fixed = np.linspace(0, 20, t.size)  # what a fixed dt would assume
    _, d_fixed = displacement(t_fixed, a, remove_gravity_mps2=None)
    assert abs(d_fixed[-1, 0] - d[-1, 0]) > 0.2 * d[-1, 0]


def test_values_at_and_errors():
    t = np.linspace(0, 59.99, 1000)
    y = np.c_[t, 2 * t]
    used, v = values_at(t, y, (10, 30, 60, 90))
    assert used[2] == pytest.approx(59.99) and np.isnan(used[3])
    assert v[0] == pytest.approx([10, 20]) and np.all(np.isnan(v[3]))
    with pytest.raises(InputError, match="not strictly increasing at sample 3"):
        displacement(np.array([0, 1, 2, 2.0]), np.zeros((4, 3)))
    with pytest.raises(InputError, match="NaN at sample 1"):
        displacement(np.array([0, 1, 2.0]), np.array([[0, 0, 0], [np.nan, 0, 0], [0, 0, 0]]))
