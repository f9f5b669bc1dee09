"""`fit` leaves the moves whose gyro rate clips (>= 98 % of the full scale) out of the gyro
scale/misalignment fit and says how many (issue 25 item 4): emulated sessions of one chip whose
180-degree turns take 1 s (337 deg/s at a 250 deg/s full scale) or 3 s (no clipping)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from accellog.calibrate.gyro.calibrate import calibrate_gyro, gyro_full_scale_dps
from accellog.calibrate.gyro.fit import CLIP_NEAR, clipped_in_moves, pose_times
from accellog.calibrate.gyro.stream import calibrate_blocks
from accellog.cli import main
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session
from accellog.store.source import open_source

# every move turns 90 degrees except +y -> -y, which turns 180
PROTOCOL = "+z,+x,+y,-x,-y,-z,+y,-y,+x"
FLIP = 6  # the move from hold 6 (+y) to hold 7 (-y)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("clip")
    out = {}
    for name, move_s in (("fast", 1.0), ("slow", 3.0)):
        out[name] = d / f"{name}.mcap"
        simulate(
            Scenario(protocol=PROTOCOL, hold_s=3.0, move_s=move_s, sample_rate_hz=200.0, seed=2), out[name]
        )
    return out


def test_the_flip_clips_and_only_it(sessions):
    s = read_session(sessions["fast"])
    fs = gyro_full_scale_dps(s.meta)
    assert fs == 250.0
    per_move = clipped_in_moves(s.t_s, s.gyro_dps, pose_times(s.poses)[0], fs)
    assert per_move.shape == (8,) and per_move[FLIP] > 0
    assert np.all(np.delete(per_move, FLIP) == 0)
    assert np.abs(s.gyro_counts).max() >= 32767  # the recorded rate did saturate
    slow = read_session(sessions["slow"])
    assert not clipped_in_moves(slow.t_s, slow.gyro_dps, pose_times(slow.poses)[0], fs).any()
    assert np.abs(slow.gyro_dps).max() < CLIP_NEAR * fs


def _gyro(path, full_scale: bool):
    s = read_session(path)
    fs = gyro_full_scale_dps(s.meta) if full_scale else None
    return calibrate_gyro(s.t_s, s.gyro_dps, s.poses, s.temp_degC, full_scale_dps=fs)


def test_leaving_the_clipped_move_out_recovers_the_chip(sessions):
    """The same chip: the fast session's matrix with the flip left out agrees with the slow
    session's; with the clipped flip in, it does not."""
    ref = _gyro(sessions["slow"], True)
    kept_out, kept_in = _gyro(sessions["fast"], True), _gyro(sessions["fast"], False)
    assert kept_out.clipped_moves == 1 and kept_in.clipped_moves == 0 and ref.clipped_moves == 0
    sig = np.hypot(ref.matrix_sigma, kept_out.matrix_sigma)
    assert np.all(np.abs(kept_out.matrix - ref.matrix) < 5 * sig), (kept_out.matrix - ref.matrix) / sig
    # the clipped flip in: ~10 % off on a scale factor, > 50 of those sigmas (its own sigma is inflated
    # by the flip's residual, so it hides the error: 8.7 of them)
    assert np.max(np.abs(kept_in.matrix - ref.matrix) / sig) > 50
    assert kept_out.rotation_rms_deg < 0.5 * kept_in.rotation_rms_deg


def test_streamed_file_leaves_out_the_flip_too(sessions):
    """The file read in its chunk groups (calibrate_blocks on its Source) leaves the flip out as well and
    recovers the chip the slow session shows."""
    s = read_session(sessions["fast"])
    streamed = calibrate_blocks(
        open_source(sessions["fast"]), s.poses, full_scale_dps=gyro_full_scale_dps(s.meta)
    )
    ref = _gyro(sessions["slow"], True)
    assert streamed.clipped_moves == 1 and "scale" in streamed.effects
    sig = np.hypot(ref.matrix_sigma, streamed.matrix_sigma)
    assert np.all(np.abs(streamed.matrix - ref.matrix) < 5 * sig), (streamed.matrix - ref.matrix) / sig


def test_fit_says_how_many_moves_it_left_out(sessions, tmp_path, capsys):
    out = tmp_path / "cal.json"
    assert main(["fit", str(sessions["fast"]), "-o", str(out)]) in (0, None)
    printed = capsys.readouterr().out.replace("\n", " ")
    cal = json.loads(out.read_text())
    said = [w for w in cal["fit"]["warnings"] if w.startswith("gyro: 1 of 8 moves")]
    assert len(said) == 1 and "left out of the gyro scale/misalignment fit" in said[0]
    assert "gyro: 1 of 8 moves" in printed
    assert "scale" in cal["gyro"]["effects"]
    slow = tmp_path / "slow.json"
    assert main(["fit", str(sessions["slow"]), "-o", str(slow)]) in (0, None)
    assert not any(w.startswith("gyro:") for w in json.loads(slow.read_text())["fit"]["warnings"])


def test_every_move_clipped_leaves_the_bias_only(tmp_path):
    path = tmp_path / "flips.mcap"
    simulate(Scenario(protocol="+z,-z,+z", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0), path)
    cal = _gyro(path, True)
    assert cal.clipped_moves == 2 and cal.effects == ["bias"]
    assert len(cal.undetermined) == 9 and np.array_equal(cal.matrix, np.eye(3))
    assert np.all(np.isfinite(cal.bias_dps))
