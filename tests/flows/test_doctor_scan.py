"""The doctor's block-by-block checks (accellog.flows.doctor_scan) give what the whole series gives:
Tally's median and percentiles are numpy's, bit for bit; the flat-top runs and the timing findings do
not depend on where the blocks are cut; a streamed file's report is the in-memory session's."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from accellog.flows import doctor_scan
from accellog.flows.doctor import examine, open_any
from accellog.flows.doctor_scan import Extreme, Scan, Tally, flat_tops, kept_times
from accellog.flows.simulate import Scenario, simulate
from accellog.store.mcap import fastread
from accellog.store.reader import read_session
from accellog.store.stream import ImuBlock
from accellog.store.writer import write_session


@pytest.mark.parametrize("n", [1, 2, 7, 100, 1001])
def test_tally_quantiles_are_numpys(n):
    rng = np.random.default_rng(n)
    for x in (rng.normal(size=n), np.round(rng.normal(size=n), 1), np.full(n, 0.001)):
        t = Tally()
        for part in np.array_split(x, 3):
            t.add(part)
        assert t.median() == np.median(x)
        for p in (0, 1, 37.5, 50, 99, 100):
            assert t.percentile(p) == np.percentile(x, p), p
        assert t.max() == x.max() and t.n == n


def test_tally_rounds_beyond_its_cap():
    x = np.random.default_rng(0).uniform(1.0, 1.1, 20_000)
    t = Tally(cap=1000)
    for part in np.array_split(x, 40):
        t.add(part)
    assert not t.exact and t.values.size <= 1000 and t.n == x.size
    assert t.median() == pytest.approx(np.median(x), rel=1e-4)
    assert t.percentile(99) == pytest.approx(np.percentile(x, 99), rel=1e-4)


def _flat_whole(v: np.ndarray) -> np.ndarray:
    """The flat-top rule on the whole series: runs of >= 3 samples at the max or the min."""
    flat = np.zeros(v.size, bool)
    for ext in (v.max(), v.min()):
        run3 = np.convolve((v == ext).astype(np.int8), np.ones(3, np.int8), mode="valid") == 3
        idx = np.flatnonzero(run3)
        flat[idx] = flat[idx + 1] = flat[idx + 2] = True
    return flat


@pytest.mark.parametrize("seed", range(6))
def test_flat_tops_do_not_depend_on_the_blocks(seed):
    rng = np.random.default_rng(seed)
    v = rng.integers(-4, 5, 3000).astype(float)  # quantised: the extremes recur, in runs of any length
    for a in rng.integers(0, 2990, 8):
        v[a : a + rng.integers(1, 9)] = 4.0 if a % 2 else -4.0
    t = np.arange(v.size) * 0.01
    cuts = np.sort(rng.choice(np.arange(1, v.size), 30, replace=False))
    exts = [Extreme(1), Extreme(-1)]
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, v.size], strict=True):
        for e in exts:
            e.add(v[a:b], t[a:b], int(a))
    for e in exts:
        e._close()
    count, where = flat_tops(exts, kept_times)
    want = np.flatnonzero(_flat_whole(v))
    assert count == want.size and where == [float(x) for x in t[want[:50]]]


def _scan(s, cuts) -> Scan:
    scan = Scan(bounded=True)
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, s.n], strict=True):
        sl = slice(int(a), int(b))
        scan.add(
            ImuBlock(s.meta, s.t_s[sl], s.sample_index[sl], s.accel_g[sl], s.gyro_dps[sl], s.temp_degC[sl])
        )
    return scan


@pytest.fixture(scope="module")
def six(tmp_path_factory):
    p = tmp_path_factory.mktemp("scan") / "six.mcap"
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0, seed=5), p)
    return p


def test_streamed_report_is_the_in_memory_one(six, tmp_path, monkeypatch):
    monkeypatch.setattr(fastread, "_GROUP_BYTES", 32 << 10)  # small groups: many blocks
    s = read_session(six)
    t = s.t_s.copy()
    t[500], t[501] = t[501], t[500]  # out of order
    t[700] = t[699]  # a duplicate
    keep = np.ones(s.n, bool)
    keep[900:950] = False
    bad = dataclasses.replace(
        s, t_s=t[keep], sample_index=np.arange(keep.sum()), accel_g=s.accel_g[keep], accel_counts=None,
        gyro_dps=s.gyro_dps[keep], gyro_counts=None, temp_degC=s.temp_degC[keep], temp_counts=None,
        host_time_s=None, truth=None, meta=s.meta.replace(accel_lsb_per_g=None, gyro_lsb_per_dps=None),
    )  # fmt: skip
    path = tmp_path / "bad.mcap"
    write_session(path, bad, chunk_size=16 * 1024)
    src = open_any(path)
    assert not src.in_memory and sum(1 for _ in src.blocks()) > 3  # streamed, in several blocks
    streamed, _ = examine(src)
    whole, _ = examine(read_session(path))
    assert json.loads(streamed.to_json()) == json.loads(whole.to_json())
    assert {f.kind for f in streamed.findings} >= {"gap", "duplicate", "out_of_order"}


def test_thinned_series_is_bounded(six, monkeypatch):
    s = read_session(six)
    monkeypatch.setattr(doctor_scan, "THIN_CAP", 1000)
    scan = _scan(s, np.arange(97, s.n, 97))
    m = scan.thin.m  # the least power of 2 keeping <= 1000 samples
    assert s.n > 2000 and scan.thin.kept <= 1000 < -(-s.n // (m // 2))
    kept = scan.thin.session(s.meta, s.poses, s.events, None)
    assert np.array_equal(kept.t_s, s.t_s[::m]) and np.array_equal(kept.accel_g, s.accel_g[::m])
