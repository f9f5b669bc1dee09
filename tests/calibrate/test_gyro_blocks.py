"""The gyro calibration is one implementation fed blocks of samples (accellog.calibrate.gyro.stream):
wherever the session is cut into blocks (whole arrays are one block, an MCAP file's chunk groups are
many; windows, hold middles and fine blocks then span block edges, down to blocks of one sample) it
recovers the chip's gyro errors the emulator drew (its truth)."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest

from accellog.acquire.emulator.sensor_model import GyroErrors
from accellog.calibrate.gyro.calibrate import calibrate_gyro, gyro_full_scale_dps
from accellog.calibrate.gyro.stream import RateBlock, calibrate_blocks
from accellog.core.errors import InputError
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session

CLIPPING = "+z,+x,+y,-x,-y,-z,+y,-y,+x"  # the +y -> -y flip in 1 s clips a 250 deg/s gyro
SCENARIOS = {
    "six": Scenario(protocol="six", hold_s=3.0, move_s=3.0, sample_rate_hz=100.0),
    "warm": Scenario(protocol="six", hold_s=3.0, move_s=3.0, sample_rate_hz=100.0,
                     temperature={"kind": "ramp", "T0": 25.0, "rate_degC_per_s": 0.2}),
    "clip": Scenario(protocol=CLIPPING, hold_s=3.0, move_s=1.0, sample_rate_hz=200.0, seed=2),
}  # fmt: skip


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("gyro_blocks")
    out = {}
    for name, sc in SCENARIOS.items():
        simulate(sc, d / f"{name}.mcap")
        out[name] = d / f"{name}.mcap"
    return out


def _cut(s, sizes):
    """The session's samples as blocks of the given sizes, cycled."""
    cuts, i, k = [], 0, 0
    while i < s.t_s.size:
        cuts.append(i)
        i, k = i + sizes[k % len(sizes)], k + 1
    return [
        RateBlock(s.t_s[a:b], s.gyro_dps[a:b], s.temp_degC[a:b])
        for a, b in zip(cuts, [*cuts[1:], s.t_s.size], strict=True)
    ]


def _assert_chip(cal, sc: Scenario, k: float = 4.0) -> None:
    """cal recovers the emulated chip's gyro errors (the emulator's truth): M = diag(1 + s) + C, the
    bias and, when fitted, its temperature slope, each within k sigma."""
    chip = GyroErrors.datasheet(sc.chip_seed)
    M = np.diag(1.0 + chip.scale) + chip.cross_axis
    assert np.all(np.abs(cal.matrix - M) < k * cal.matrix_sigma), (cal.matrix - M) / cal.matrix_sigma
    assert np.all(np.abs(cal.bias_dps - chip.bias_dps) < k * cal.bias_sigma_dps)
    if "temp_bias" in cal.effects:
        err = cal.temp_bias_dps_per_degC - chip.temp_bias_dps_per_degC
        assert np.all(np.abs(err) < k * cal.temp_bias_sigma_dps_per_degC), err


@pytest.mark.parametrize("sizes", [[1], [1000], [3, 250, 1, 40]])
@pytest.mark.parametrize("name", ["six", "warm", "clip"])
def test_any_cut_into_blocks_recovers_the_chip(sessions, name, sizes):
    """The session cut into blocks of any sizes (one sample, a hold, irregular): the calibration
    recovers the chip the emulator drew, the clipped flip left out and the warm-up's slope fitted."""
    s = read_session(sessions[name])
    fs = gyro_full_scale_dps(s.meta)
    blocks = _cut(s, sizes)
    cut = calibrate_blocks(lambda: iter(blocks), s.poses, full_scale_dps=fs)
    assert "scale" in cut.effects and cut.clipped_moves == (name == "clip")
    assert ("temp_bias" in cut.effects) == (name == "warm")
    _assert_chip(cut, SCENARIOS[name])


def test_a_hold_labelled_past_the_end(sessions):
    """Bias windows and a hold middle past the last sample (found only at the end of the pass)."""
    s = read_session(sessions["six"])
    poses = [*s.poses[:-1], replace(s.poses[-1], end_s=float(s.t_s[-1]) + 5.0)]
    blocks = _cut(s, [37])
    cal = calibrate_blocks(lambda: iter(blocks), poses)
    assert cal.n_holds == 6 and "scale" in cal.effects
    _assert_chip(cal, SCENARIOS["six"])


def test_the_file_is_read_in_its_chunk_groups(sessions, monkeypatch):
    """calibrate_blocks on a file's Source reads its chunk groups: many of them here, two passes."""
    from accellog.store import source as stream
    from accellog.store.mcap import fastread

    monkeypatch.setattr(fastread, "_GROUP_BYTES", 8 << 10)
    seen = []
    real = stream.iter_imu

    def counted(path):
        seen.append([])
        for blk in real(path):
            seen[-1].append(blk.n)
            yield blk

    monkeypatch.setattr(stream, "iter_imu", counted)
    s = read_session(sessions["warm"])
    cal = calibrate_blocks(stream.open_source(sessions["warm"]), s.poses)
    assert len(seen) == 2 and len(seen[0]) > 10 and len(seen[1]) > 10 and sum(seen[0]) == s.t_s.size
    assert cal.effects == ["bias", "temp_bias", "scale", "cross_axis"]
    assert cal.rotation_rms_deg < 1.0 and np.all(np.abs(cal.matrix - np.eye(3)) < 0.15)


def test_no_gyro_and_no_samples(sessions):
    s = read_session(sessions["six"])
    no_gyro = [RateBlock(s.t_s, None, s.temp_degC)]
    assert calibrate_blocks(lambda: iter(no_gyro), s.poses) is None
    with pytest.raises(InputError, match="no gyro rate"):
        calibrate_gyro(s.t_s, None, s.poses)
    with pytest.raises(InputError, match="fewer than 2 windows"):
        calibrate_gyro(np.zeros(0), np.zeros((0, 3)), s.poses)


@pytest.mark.parametrize("rate_hz", [20.0, 99.0, 1000.0])
def test_block_edges_made_pair_by_pair(rate_hz):
    """fine_pieces / coarse_plan (one hold pair in memory at a time): fine edges strictly increasing
    from the first hold middle to the last, through every middle, ceil(span / 10 ms) blocks between
    two middles (one a sample when 10 ms is shorter); the coarse edges are fine edges with their index in them; also when two holds
    share a middle."""
    from accellog.calibrate.gyro.rotation import coarse_plan, fine_pieces

    rng = np.random.default_rng(int(rate_hz))
    for trial in range(40):
        n = int(rng.integers(50, 3000))
        t = np.cumsum(rng.uniform(0.5, 1.5, n)) / rate_hz
        k = int(rng.integers(2, 6))
        starts = np.sort(rng.integers(0, n, k))
        ends = np.maximum(np.sort(np.minimum(starts + rng.integers(0, n // k + 1, k), n - 1)), starts)
        mids = np.sort((starts + ends) // 2)
        if trial % 5 == 0:
            mids[1] = mids[0]
        fine = np.concatenate([mids[:1], *fine_pieces(t, mids, 0.01)])
        assert fine[0] == mids[0] and fine[-1] == mids[-1] and np.all(np.diff(fine) > 0)
        assert np.isin(mids, fine).all()
        for a, b in itertools.pairwise(mids):  # ceil(span / 10 ms) blocks, at most one a sample
            want = min(b - a, max(1, int(np.ceil((t[b] - t[a]) / 0.01)))) if b > a else 0
            assert np.count_nonzero((fine > a) & (fine <= b)) == want
        coarse, at, n_fine = coarse_plan(t, mids, ends, starts, 0.01)
        assert n_fine == fine.size and np.all(np.diff(coarse) > 0) and np.isin(mids, coarse).all()
        np.testing.assert_array_equal(fine[at], coarse[:-1])
        assert coarse[-1] == fine[-1]
