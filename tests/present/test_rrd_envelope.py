"""Display envelopes (present/rrd/envelope.py): min/max per time bucket, independent of batching."""

from __future__ import annotations

import itertools

import numpy as np

from accellog.present.rrd.envelope import EnvelopeBuilder, bucket_width_s, minmax_envelope
from accellog.present.rrd.series import SeriesLogs


def _reference(t, v, t0, w):
    """Per bucket floor((t - t0) / w): (min, max) of every column, by numpy on each bucket."""
    b = np.floor((t - t0) / w).astype(np.int64)
    ids = np.unique(b)
    return (
        ids,
        np.array([np.nanmin(v[b == k], axis=0) for k in ids]),
        np.array([np.nanmax(v[b == k], axis=0) for k in ids]),
    )


def test_envelope_is_numpys_min_max_per_bucket_whatever_the_batches() -> None:
    rng = np.random.default_rng(3)
    n = 50_000
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n))  # irregular sampling
    v = rng.normal(size=(n, 3))
    v[rng.integers(0, n, 20), rng.integers(0, 3, 20)] = 40.0  # single-sample spikes
    v[1000:1010, 1] = np.nan  # NaNs are ignored
    w = bucket_width_s(t[-1] - t[0], 700)
    one = minmax_envelope(t, v, buckets=700)
    ids, mn, mx = _reference(t, v, t[0], w)
    np.testing.assert_array_equal(one.bucket[0::2], ids)
    np.testing.assert_array_equal(np.minimum(one.values[0::2], one.values[1::2]), mn)
    np.testing.assert_array_equal(np.maximum(one.values[0::2], one.values[1::2]), mx)
    assert np.all(np.diff(one.t_s) >= 0) and (one.values == 40.0).sum() == 20
    # the same samples pushed in random pieces give the same rows
    eb = EnvelopeBuilder(t[0], w)
    cuts = np.sort(rng.choice(np.arange(1, n), 60, replace=False))
    parts = [eb.push(t[a:b], v[a:b]) for a, b in zip(np.r_[0, cuts], np.r_[cuts, n], strict=True)]
    parts.append(eb.finish())
    np.testing.assert_array_equal(np.concatenate([p.values for p in parts]), one.values)
    np.testing.assert_array_equal(np.concatenate([p.t_s for p in parts]), one.t_s)
    np.testing.assert_array_equal(np.concatenate([p.row_index for p in parts]), one.row_index)


def test_envelope_keeps_the_order_of_min_and_max() -> None:
    """Within a bucket the earlier extreme comes first (a line through the rows keeps the shape)."""
    t = np.arange(8, dtype=float)
    v = np.array([[0.0, 5], [3, 4], [9, 1], [1, 0], [2, 2], [-4, 7], [0, 3], [1, 1]])
    env = minmax_envelope(t, v, buckets=2)  # width 3.5 s: samples 0-3, 4-6, 7
    np.testing.assert_array_equal(env.t_s, [0, 3, 4, 6, 7, 7])
    np.testing.assert_array_equal(env.values[:2], [[0, 5], [9, 0]])  # x: min first; y: max first
    np.testing.assert_array_equal(env.values[2:4], [[2, 2], [-4, 7]])  # x: max (2) first, y: min first


def test_whole_series_envelope_and_full_rate_from_the_command_line(tmp_path, monkeypatch, capsys) -> None:
    """A whole long series logged at once (fit / evaluate / demo recordings) is an envelope with its
    device sample numbers; ACCELLOG_RRD_FULL=1 (full data on demand) logs every sample."""
    import sys
    from pathlib import Path

    from accellog.present.rrd.envelope import ENVELOPE_BUCKETS, FULL_RATE_MAX_SAMPLES
    from accellog.present.rrd.recording import RunRecording

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from rrd_readback import load_rrd

    n = 3 * FULL_RATE_MAX_SAMPLES
    t = np.arange(n) / 1000.0
    v = np.random.default_rng(5).normal(size=(n, 3))
    idx = np.arange(n) + 1000
    monkeypatch.delenv("ACCELLOG_RRD_FULL", raising=False)
    with RunRecording(f"save:{tmp_path / 'env.rrd'}") as rec:
        rec.log_samples("raw", t, idx, v, "g")
    s_idx, vals = load_rrd(tmp_path / "env.rrd").series("accel/raw", timeline="sample")
    assert len(vals) <= 2 * (ENVELOPE_BUCKETS + 1)
    np.testing.assert_array_equal(vals, minmax_envelope(t, v).values)
    np.testing.assert_array_equal(s_idx, minmax_envelope(t, v, index=idx).row_index)
    # the command line turns ACCELLOG_RRD_FULL=1 into the default; the library reads no environment
    from accellog.cli import main

    monkeypatch.setattr(RunRecording, "DEFAULT_FULL_RATE", False)
    monkeypatch.setenv("ACCELLOG_RRD_FULL", "1")
    with RunRecording(f"save:{tmp_path / 'lib.rrd'}") as rec:
        assert not rec.full_rate
    assert main(["effects"]) == 0 and RunRecording.DEFAULT_FULL_RATE
    with RunRecording(f"save:{tmp_path / 'full.rrd'}") as rec:
        assert rec.full_rate
        rec.log_samples("raw", t, idx, v, "g")
    np.testing.assert_array_equal(load_rrd(tmp_path / "full.rrd").series("accel/raw")[1], v)


def test_bucket_edges_are_exactly_floor_of_time_over_width() -> None:
    """The builder finds bucket edges by searching the times (not bucketing every sample): on edges
    that fall exactly on samples, repeated times, a jump in time and a large time offset it still
    cuts exactly where floor((t - t0) / w) changes, whatever the batches."""
    rng = np.random.default_rng(11)
    n = 6000
    cases = {
        "regular, edges on samples": (np.arange(n) * 1e-3, 0.0, 0.3),
        "repeated times": (np.sort(rng.choice(np.arange(n // 4) * 0.01, n)), 0.0, 0.05),
        "jump in time": (np.r_[np.arange(n // 2), 1e7 + np.arange(n // 2)] * 1e-3, 0.0, 0.001),
        "large offset": (1e9 + np.arange(n) * 0.1, 1e9 - 0.05, 0.7),
    }
    for name, (t, t0, w) in cases.items():
        v = np.round(rng.normal(size=(n, 2)) * 4)  # many equal values: ties between min and max
        ids, mn, mx = _reference(t, v, t0, w)
        eb = EnvelopeBuilder(t0, w)
        cuts = np.r_[0, np.sort(rng.choice(np.arange(1, n), 25, replace=False)), n]
        parts = [eb.push(t[a:b], v[a:b]) for a, b in itertools.pairwise(cuts)] + [eb.finish()]
        bucket = np.concatenate([p.bucket for p in parts])
        rows = np.concatenate([p.values for p in parts])
        np.testing.assert_array_equal(bucket[0::2], ids, err_msg=name)
        np.testing.assert_array_equal(np.minimum(rows[0::2], rows[1::2]), mn, err_msg=name)
        np.testing.assert_array_equal(np.maximum(rows[0::2], rows[1::2]), mx, err_msg=name)
        b = np.floor((t - t0) / w)
        first = np.r_[0, np.flatnonzero(np.diff(b)) + 1]  # first and last sample of every bucket
        np.testing.assert_array_equal(np.concatenate([p.row_index for p in parts])[0::2], first, err_msg=name)


def _ordered_reference(t, v, t0, w):
    """Per bucket and column, by numpy on each bucket: the first-occurring of (min, max) then the
    other (NaNs ignored; NaN, NaN for a bucket of only NaNs)."""
    b = np.floor((t - t0) / w).astype(np.int64)
    rows = []
    for k in np.unique(b):
        seg = v[b == k]
        pair = np.full((2, v.shape[1]), np.nan)
        for j in range(v.shape[1]):
            col = seg[:, j]
            if np.isnan(col).all():
                continue
            lo, hi = np.nanmin(col), np.nanmax(col)
            first_lo, first_hi = np.flatnonzero(col == lo)[0], np.flatnonzero(col == hi)[0]
            pair[:, j] = (lo, hi) if first_lo <= first_hi else (hi, lo)
        rows.extend(pair)
    return np.array(rows)


def test_envelope_rows_in_order_with_ties_nans_and_infs_on_even_and_uneven_buckets() -> None:
    """Every bucket's extremes in the order they occur, whether the buckets of a batch all hold the
    same number of samples (regular sampling) or not, with ties, NaNs (also a bucket of only NaNs),
    infinities and a jump in time, however the series is cut into batches."""
    rng = np.random.default_rng(29)
    n = 9000
    regular = np.arange(n) * 1e-3
    cases = {
        "regular": regular,
        "jittered": regular + rng.uniform(0, 4e-4, n),
        "jump in time": np.r_[regular[: n // 2], 50.0 + regular[n // 2 :]],
    }
    for name, t in cases.items():
        v = np.round(rng.normal(size=(n, 3)) * 3)  # many ties, also between min and max
        if name != "regular":
            v[2000:2003, 0] = np.nan
            v[4000:4100, 1] = np.nan  # a whole bucket
            v[[10, 6000], [2, 0]] = np.inf, -np.inf
        w = 0.1  # 100 samples per bucket when regular
        want = _ordered_reference(t, v, 0.0, w)
        for n_cuts in (0, 7, 40):
            eb = EnvelopeBuilder(0.0, w)
            cuts = np.r_[0, np.sort(rng.choice(np.arange(1, n), n_cuts, replace=False)), n]
            got = [eb.push(t[a:b], v[a:b]).values for a, b in itertools.pairwise(cuts)] + [eb.finish().values]
            np.testing.assert_array_equal(np.concatenate(got), want, err_msg=f"{name}, {n_cuts} cuts")


class _Rows(SeriesLogs):
    """SeriesLogs writing each series' rows into a dict (entity -> list of (t, values))."""

    full_rate = False

    def __init__(self) -> None:
        self._init_series()
        self.rows: dict[str, list] = {}

    def _guarded(self, fn, *args, **kw):
        return fn(*args, **kw)

    def _write_series(self, entity, t, v, *rest) -> None:
        self.rows.setdefault(entity, []).append((np.array(t), np.array(v)))

    def _end_rows(self) -> None:
        pass


def test_batched_series_sharing_times_each_get_their_own_envelope() -> None:
    """Series of one batch share the buckets of their common times (computed once); every series
    still gets exactly its one-shot envelope, also when a caller refills one time array in place."""
    rng = np.random.default_rng(5)
    n, k = 60_000, 2_000
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n))
    a, b = rng.normal(size=(n, 3)), rng.normal(size=(n, 1))
    for refill in (False, True):
        rec = _Rows()
        rec.begin_batches(t[0], t[-1], n)
        buf = np.empty(k)
        for lo in range(0, n, k):
            if refill:  # the same array object, new times: its buckets must be found again
                buf[:] = t[lo : lo + k]
                tb = buf
            else:
                tb = t[lo : lo + k].copy()
            rec.log_series("a", tb, a[lo : lo + k], ["x", "y", "z"])
            rec.log_series("b", tb, b[lo : lo + k], ["T"])
        rec.end_batches()
        for name, v in (("a", a), ("b", b)):
            one = minmax_envelope(t, v)
            np.testing.assert_array_equal(np.concatenate([r[0] for r in rec.rows[name]]), one.t_s)
            np.testing.assert_array_equal(np.concatenate([r[1] for r in rec.rows[name]]), one.values)


def test_long_and_short_buckets_give_the_same_rows(monkeypatch) -> None:
    """Long buckets are reduced one by one, short ones all at once: the rows (which extreme comes
    first included, on ties too) do not depend on the way."""
    from accellog.present.rrd import envelope

    rng = np.random.default_rng(8)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 20_000))
    v = np.round(rng.normal(size=(t.shape[0], 3)) * 3)  # many ties between min and max candidates
    rows = {}
    for way, least in (("one by one", 0), ("all at once", 10**9)):
        monkeypatch.setattr(envelope, "LOOP_MIN_SAMPLES", least)
        for buckets in (50, 700, 5000):
            env = minmax_envelope(t, v, buckets=buckets)
            rows[way, buckets] = (env.values, env.row_index)
    for buckets in (50, 700, 5000):
        for a, b in zip(rows["one by one", buckets], rows["all at once", buckets], strict=True):
            np.testing.assert_array_equal(a, b)
