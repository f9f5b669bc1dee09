"""accellog.flows.simulate and `accellog simulate`: scenario validation, TOML files, --set overrides, pose
labels against the true motion, the truth channel against the samples, reproducibility by seed.

Every session goes through the real path (emulated chip -> driver -> Recorder -> MCAP) and is read
back with read_session. Short holds at 200 Hz keep the file fast.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from accellog.acquire.emulator.sensor_model import AccelErrors, GyroErrors
from accellog.acquire.registers import ACCEL_DLPF_BANDWIDTH_HZ, GYRO_DLPF_BANDWIDTH_HZ
from accellog.cli import main
from accellog.core.session import Session
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session

RATE_HZ = 200.0
BASE = dict(protocol="six", hold_s=4.0, move_s=1.5, sample_rate_hz=RATE_HZ, chip_seed=7, seed=1)


def sim(path: Path, **kw) -> Session:
    """Simulate a scenario (BASE updated by kw) to `path` and read it back."""
    simulate(Scenario(**{**BASE, **kw}), path)
    return read_session(path)


def pose_means(s: Session) -> np.ndarray:
    """(poses,3) mean accel reading (g) inside each label."""
    return np.array([s.accel_g[s.slice_time(p.start_s, p.end_s)].mean(axis=0) for p in s.poses])


def pose_sems(s: Session) -> np.ndarray:
    """(poses,3) standard error of each pose mean (g), samples ~independent at 200 Hz / 44.8 Hz."""
    out = []
    for p in s.poses:
        a = s.accel_g[s.slice_time(p.start_s, p.end_s)]
        out.append(a.std(axis=0, ddof=1) * np.sqrt(2.0 / a.shape[0]))  # x sqrt(tau), tau <= 2
    return np.array(out)


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Session:
    """Six poses, datasheet chip, 200 Hz, local gravity 9.797 m/s^2 (not g0)."""
    return sim(tmp_path_factory.mktemp("sim") / "base.mcap", local_gravity_mps2=9.797)


# ------------------------------------------------------------------------------------------ CLI errors


def _fails(capsys, argv: list[str], *needles: str) -> str:
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert err.startswith("accellog: error: ") and "\n" not in err and "Traceback" not in err, err
    for n in needles:
        assert n in err, (n, err)
    return err


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--rate", "300"], "sample_rate_hz=300"),
        (["--errors", "bogus"], "errors='bogus'"),
        (["--motion", "fly"], "motion='fly'"),
        (["--protocol", "+q,-z"], "unknown pose name '+q'"),
        (["--hold", "0"], "--hold: 0 is out of range"),
        (["--set", "bias_g"], "FIELD=VALUE"),
        (["--set", "bias_g=a,b,c"], "not a number"),
        (["--set", "no_such_field=1"], "no_such_field"),
        (["--set", "bias_g=0.1,0.2"], "bias_g must be 3 numbers"),
        (["--temperature", "warmup:25"], "--temperature"),
        (["--temperature", "sauna:80"], "--temperature"),
        (["--scenario", "no/such/scenario.toml"], "scenario file not found"),
    ],
)
def test_cli_rejects_bad_scenario(tmp_path, capsys, args, needle):
    out = tmp_path / "out.mcap"
    _fails(capsys, ["simulate", "-o", str(out), *args], needle)
    assert list(tmp_path.iterdir()) == []  # no output, no half-written .part file


@pytest.mark.parametrize(
    "body, needles",
    [
        ("holdd_s = 3\n", ["s.toml", "unknown scenario key", "holdd_s", "did you mean hold_s?"]),
        ("hold_s = [\n", ["s.toml", "not valid TOML"]),
        ('temperature = {kind = "warmup", T_start = 20.0}\n', ["needs key 'T_end'"]),
        ('motion = "robot"\nrobot_path = "moon"\n', ["robot_path='moon'"]),
        ("move_s = -1.0\n", ["move_s=-1"]),
        ("[set]\nbias_g = [0.1, 0.2]\n", ["bias_g must be 3 numbers"]),
        ("sample_rate_hz = 333.0\n", ["s.toml", "sample_rate_hz=333"]),
    ],
)
def test_toml_scenario_errors(tmp_path, capsys, body, needles):
    (tmp_path / "s.toml").write_text(body)
    out = tmp_path / "out.mcap"
    _fails(capsys, ["simulate", "--scenario", str(tmp_path / "s.toml"), "-o", str(out)], *needles)
    assert not out.exists() and not list(tmp_path.glob("out.mcap*"))


@pytest.mark.parametrize(
    "body",
    ['hold_s = "abc"\n', 'sample_rate_hz = "fast"\n', "protocol = 6\n", 'seed = "x"\n', "set = 3\n"],
)
def test_toml_scenario_wrong_types(tmp_path, capsys, body):
    (tmp_path / "s.toml").write_text(body)
    _fails(
        capsys, ["simulate", "--scenario", str(tmp_path / "s.toml"), "-o", str(tmp_path / "o.mcap")], "s.toml"
    )


# ------------------------------------------------------------------------------------------ TOML, --set


def test_toml_scenario_file(tmp_path, capsys):
    toml = tmp_path / "scenario.toml"
    toml.write_text(
        'protocol = "+z,-z,+x"\nhold_s = 3.0\nmove_s = 1.0\nsample_rate_hz = 250.0\nchip_seed = 11\n'
        "seed = 5\nlocal_gravity_mps2 = 9.79\n[set]\nbias_g = [0.02, -0.01, 0.03]\n"
        '[temperature]\nkind = "constant"\nT = 31.5\n'
    )
    out = tmp_path / "t.mcap"
    assert main(["simulate", "--scenario", str(toml), "-o", str(out)]) == 0
    assert "wrote" in capsys.readouterr().err
    s = read_session(out)
    sc = json.loads(s.meta.extra["scenario"])
    assert sc["protocol"] == "+z,-z,+x" and sc["chip_seed"] == 11 and sc["seed"] == 5
    assert sc["set"] == {"bias_g": [0.02, -0.01, 0.03]} and sc["temperature"]["T"] == 31.5
    assert s.meta.sample_rate_hz == 250.0 and s.meta.local_gravity_mps2 == 9.79
    assert [p.name for p in s.poses] == ["+z", "-z", "+x"]
    assert abs(float(np.mean(s.temp_degC)) - 31.5) < 0.01
    assert np.all(np.abs(np.diff(s.t_s) - 1 / 250.0) < 1e-9)
    # the overridden bias is the chip's: the (+z) and (-z) means cancel S on x and y, leaving b(T) =
    # b0 + b_T (T - 25 degC), b_T the chip's datasheet temperature coefficient (not overridden)
    m = pose_means(s)
    b_T = AccelErrors.datasheet(11).temp_bias_g_per_degC[:2]
    np.testing.assert_allclose(0.5 * (m[0] + m[1])[:2], np.array([0.02, -0.01]) + b_T * 6.5, atol=3e-4)


def test_set_override_reaches_chip(tmp_path, capsys):
    """Same seeds, bias_g and temperature replaced: every pose mean moves by exactly what the chip's
    measurement equation says."""
    argv = ["simulate", "--protocol", "+z,-z,+y", "--hold", "3", "--rate", "200", "--seed", "3"]
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    assert main([*argv, "-o", str(a)]) == 0
    assert main([*argv, "-o", str(b), "--set", "bias_g=0.05,-0.03,0.02", "--temperature", "constant:40"]) == 0
    capsys.readouterr()
    sa, sb = read_session(a), read_session(b)
    # expected: the chip's own measurement equation with the new bias and temperature, same noise
    chip = AccelErrors.datasheet(7)
    new = dataclasses.replace(chip, bias_g=np.array([0.05, -0.03, 0.02]))
    up = np.array([p.up_sensor for p in sa.poses])
    zero = np.zeros(len(up))
    shift = new.apply(up, zero + 40.0, zero) - chip.apply(up, zero + 25.0, zero)
    assert np.abs(shift - (new.bias_g - chip.bias_g)).max() > 1e-3  # the temperature matters too
    d = pose_means(sb) - pose_means(sa)
    # identical noise: only rounding to 1 LSB (61 ug) differs sample by sample
    assert np.allclose(d, shift, atol=2.0 / 16384), (d, shift)
    assert abs(float(np.mean(sb.temp_degC)) - 40.0) < 0.01 and abs(float(np.mean(sa.temp_degC)) - 25.0) < 0.01
    # the scenario stored in the file says what was overridden
    assert json.loads(sb.meta.extra["scenario"])["set"] == {"bias_g": [0.05, -0.03, 0.02]}


# ------------------------------------------------------------------------------------------ labels and truth


def test_labels_lie_inside_the_true_holds(base):
    s, tr = base, base.truth
    assert [p.name for p in s.poses] == ["+z", "-z", "+y", "-y", "+x", "-x"]
    assert tr is not None
    moving = np.linalg.norm(tr.omega_dps, axis=1) > 0
    g_ratio = 9.797 / STANDARD_GRAVITY_MPS2
    for p in s.poses:
        inside = (tr.t_s >= p.start_s) & (tr.t_s <= p.end_s)
        assert inside.sum() >= 300  # ~3.5 s of 100 Hz truth
        assert not moving[inside].any(), p  # the sensor is static within every label
        # ... in the labelled orientation, with the site's gravity
        np.testing.assert_allclose(
            tr.specific_force_g[inside], np.tile(p.up_sensor, (inside.sum(), 1)) * g_ratio, atol=1e-12
        )
        # the label covers the hold minus the margins (0.25 s each side): motion just outside it
        before = (tr.t_s < p.start_s) & (tr.t_s > p.start_s - 0.35)
        after = (tr.t_s > p.end_s) & (tr.t_s < p.end_s + 0.35)
        if p.hold_index > 0:
            assert moving[before].any(), p
        if p.hold_index < len(s.poses) - 1:
            assert moving[after].any(), p
        assert abs((p.end_s - p.start_s) - (BASE["hold_s"] - 0.5)) < 2.0 / RATE_HZ
    # and the samples agree: still (noise only) inside every label
    for p in s.poses:
        a = s.accel_g[s.slice_time(p.start_s, p.end_s)]
        assert a.std(axis=0).max() < 0.004  # noise 300 ug/rtHz over 44.8 Hz ~ 2.5 mg


def test_truth_channel_aligned_with_samples(base):
    """reading = S f(t) + b + noise with f from the stored truth at the sample times; no time lag."""
    s, tr = base, base.truth
    assert tr.t_s[0] == 0.0 and tr.t_s[-1] >= s.t_s[-1] - 0.011
    assert np.allclose(np.diff(tr.t_s), 0.01)
    keep = s.t_s <= tr.t_s[-1]
    t = s.t_s[keep]
    f = np.stack([np.interp(t, tr.t_s, tr.specific_force_g[:, k]) for k in range(3)], axis=1)
    w = np.stack([np.interp(t, tr.t_s, tr.omega_dps[:, k]) for k in range(3)], axis=1)
    ae, ge = AccelErrors.datasheet(7), GyroErrors.datasheet(7)
    r = s.accel_g[keep] - ae.apply(f, np.full(t.size, 25.0), t)
    noise_g = 300e-6 * np.sqrt(np.pi / 2 * ACCEL_DLPF_BANDWIDTH_HZ[3])
    rms = np.sqrt(np.mean(r**2, axis=0))
    assert np.all((rms > 0.8 * noise_g) & (rms < 1.2 * noise_g)), (rms, noise_g)
    # lag: regress the residual on df/dt over the moves (1 ms of lag ~ 2 mg at the fastest turn)
    dfdt = np.gradient(f, t, axis=0)
    lag_s = float(np.sum(r * dfdt) / np.sum(dfdt * dfdt))
    assert abs(lag_s) < 5e-4, lag_s
    # gyro: the truth's rate through the chip's gyro errors
    rg = s.gyro_dps[keep] - ge.apply(w, np.full(t.size, 25.0))
    noise_dps = 0.01 * np.sqrt(np.pi / 2 * GYRO_DLPF_BANDWIDTH_HZ[3])
    assert np.sqrt(np.mean(rg**2)) < 1.5 * noise_dps + 0.5 / 131.0
    assert np.abs(w).max() > 50.0  # the moves were really seen


# ------------------------------------------------------------------------------------------ seeds


def test_same_seed_reproduces_counts(tmp_path, base):
    again = sim(tmp_path / "again.mcap", local_gravity_mps2=9.797)
    assert np.array_equal(again.accel_counts, base.accel_counts)
    assert np.array_equal(again.gyro_counts, base.gyro_counts)
    assert np.array_equal(again.temp_counts, base.temp_counts)
    assert np.array_equal(again.sample_index, base.sample_index)
    assert again.poses == base.poses
    assert np.array_equal(again.truth.specific_force_g, base.truth.specific_force_g)


def test_other_seed_other_noise_same_chip(tmp_path, base):
    other = sim(tmp_path / "seed2.mcap", local_gravity_mps2=9.797, seed=2)
    n = min(other.n, base.n)
    differ = np.any(other.accel_counts[:n] != base.accel_counts[:n], axis=1)
    assert differ.mean() > 0.9  # new noise nearly everywhere
    assert [p.name for p in other.poses] == [p.name for p in base.poses]
    # same chip: the pose means agree within the noise ...
    sem = np.hypot(pose_sems(base), pose_sems(other))
    z = (pose_means(other) - pose_means(base)) / sem
    assert np.abs(z).max() < 5.0, z
    # ... while another chip's errors (tens of mg) do not
    chip8 = sim(tmp_path / "chip8.mcap", local_gravity_mps2=9.797, chip_seed=8)
    z8 = (pose_means(chip8) - pose_means(base)) / np.hypot(pose_sems(base), pose_sems(chip8))
    assert np.abs(z8).max() > 50.0


def test_perfect_chip_reads_truth(tmp_path):
    """errors='perfect': the pose means are the true specific force (up * g_local/g0) to 1 LSB."""
    s = sim(tmp_path / "p.mcap", errors="perfect", local_gravity_mps2=9.81, protocol="+z,-x", hold_s=2.0)
    want = np.array([p.up_sensor for p in s.poses]) * 9.81 / STANDARD_GRAVITY_MPS2
    assert np.abs(pose_means(s) - want).max() < 1.0 / 16384
