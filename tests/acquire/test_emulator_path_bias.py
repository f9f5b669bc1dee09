"""The emulator's switchable effects outside the library (issue 25): a bias following the rate of
the die temperature, b += r dT/dt, and a thermal hysteresis, b += h s(t) with s = -1 while heating
and +1 while cooling (a play operator of width w on T)."""

from __future__ import annotations

import numpy as np
import pytest

from accellog.acquire.emulator.poses import PoseSequenceMotion
from accellog.acquire.emulator.sensor_model import AccelErrors, SensorModel
from accellog.acquire.emulator.temperature import TemperaturePath
from accellog.core.errors import InputError
from accellog.core.protocol import parse_protocol

KW = dict(
    accel_lsb_per_g=16384.0,
    gyro_lsb_per_dps=131.0,
    odr_hz=100.0,
    accel_bandwidth_hz=44.8,
    gyro_bandwidth_hz=41.0,
)
HEAT_COOL = TemperaturePath.points([0.0, 100.0, 200.0], [25.0, 35.0, 25.0])


def _x_g(acc: AccelErrors, temp: TemperaturePath, t: np.ndarray) -> np.ndarray:
    model = SensorModel(
        PoseSequenceMotion(parse_protocol("+z", 300.0), start_delay_s=0.0), acc, temperature=temp
    )
    return model.sample(t, **KW).accel_counts[:, 0] / 16384.0


def test_play_operator_lags_by_half_its_width_and_ignores_chunking():
    t = np.array([50.0, 90.0, 150.0, 190.0])
    P = HEAT_COOL.play_degC(t, 2.0, 250.0)
    assert np.allclose(P, HEAT_COOL.degC(t) + np.array([-1.0, -1.0, 1.0, 1.0]), rtol=0, atol=1e-9)
    assert np.array_equal(
        np.concatenate([HEAT_COOL.play_degC(t[:2], 2.0, 250.0), HEAT_COOL.play_degC(t[2:], 2.0, 250.0)]), P
    )
    assert HEAT_COOL.rate_degC_per_s(t) == pytest.approx([0.1, 0.1, -0.1, -0.1])
    with pytest.raises(InputError, match="width"):
        HEAT_COOL.play_degC(t, 0.0, 250.0)
    with pytest.raises(InputError, match="temp_hysteresis_width_degC"):
        AccelErrors(temp_hysteresis_g=[1e-3, 0, 0], temp_hysteresis_width_degC=-1.0)


def test_rate_and_hysteresis_biases_reach_the_counts():
    t = np.array([50.0, 150.0])
    rate = _x_g(AccelErrors(temp_rate_bias_g_per_degC_per_s=[0.05, 0, 0]), HEAT_COOL, t)
    assert rate[0] - rate[1] == pytest.approx(0.05 * 0.2, abs=2 / 16384)  # +0.1 vs -0.1 degC/s
    acc = AccelErrors(temp_hysteresis_g=[3e-3, 0, 0], temp_hysteresis_width_degC=2.0)
    hyst = _x_g(acc, HEAT_COOL, t)
    assert hyst[1] - hyst[0] == pytest.approx(6e-3, abs=2 / 16384)  # heating -h, cooling +h
    off = _x_g(AccelErrors(), HEAT_COOL, t)
    assert off[0] == off[1] == 0.0  # both switched off by default
