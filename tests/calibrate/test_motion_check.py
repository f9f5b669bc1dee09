"""The streamed motion check (windows spilled to a file, exact medians by radix selection) against
np.median and against the moving window plain numpy finds; the reader's page release."""

from __future__ import annotations

import itertools
import mmap
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from accellog.calibrate.observe.motion import MotionCheck
from accellog.calibrate.observe.window_spill import WindowSpill, kth_smallest, median
from accellog.core.errors import InputError
from accellog.store.collect import FAULT_AROUND, release_pages


def _pieces(x: np.ndarray, rng: np.random.Generator):
    cuts = np.sort(rng.integers(0, x.size, size=5))

    def values():
        yield from np.split(x, cuts)

    return values


@pytest.mark.parametrize("n", [1, 2, 7, 1000, 1001])
@pytest.mark.parametrize("kind", ["normal", "ties", "signs", "binades"])
def test_median_in_pieces_is_np_median_bit_for_bit(n, kind):
    rng = np.random.default_rng(n)
    x = {
        "normal": rng.normal(0.002, 1e-4, n),
        "ties": rng.choice([0.5, 0.25, -0.0, 0.0, 3.0], n),  # one bucket holds most values
        "signs": rng.normal(0.0, 1.0, n) * 10.0 ** rng.integers(-300, 300, n),
        "binades": np.repeat(rng.normal(size=n // 10 + 1), 10)[:n],
    }[kind]
    got, want = median(_pieces(x, rng), n), np.median(x)
    assert got == want and (want == 0 or np.float64(got).tobytes() == want.tobytes())  # +-0: equal
    for cap in (1, 3, 1 << 16):  # small caps refine to the last 16 bits
        k = int(rng.integers(0, n))
        assert kth_smallest(_pieces(x, rng), k, cap=cap) == np.partition(x, k)[k]


def test_median_with_a_nan_is_nan_as_np_median():
    x = np.array([0.3, np.nan, 0.1, 0.2])
    assert np.isnan(median(_pieces(x, np.random.default_rng(0)), x.size)) and np.isnan(np.median(x))


def test_window_spill_reads_back_rows_in_pieces_runs_and_columns():
    rng = np.random.default_rng(3)
    rows = rng.normal(size=(1000, 7))
    spill = WindowSpill(7)
    for part in np.split(rows, [10, 400, 401]):
        spill.append(part)
    assert spill.n == 1000
    assert np.array_equal(np.concatenate(list(spill.pieces(rows=33))), rows)
    runs = list(spill.runs([10, 390, 0, 600]))
    assert [r.shape[0] for r in runs] == [10, 390, 0, 600] and np.array_equal(np.concatenate(runs), rows)
    keep = rows[:, 6] > 0
    assert np.array_equal(np.concatenate(list(spill.column(2, lambda p: p[:, 6] > 0)())), rows[keep, 2])
    assert median(spill.column(3), spill.n) == np.median(rows[:, 3])
    spill.close()


def _session(rng, n=40_000, bump=None):
    t = np.cumsum(rng.uniform(0.0009, 0.0011, n))
    acc = rng.normal(0.0, 0.002, (n, 3)) + np.array([0.01, -0.02, 1.0])
    if bump == "std":
        acc[25_000:25_300] += rng.normal(0.0, 0.05, (300, 3))
    elif bump == "mean":
        acc[30_000:31_000, 0] += 0.08
    return t, acc


def _numpy_windows(t, acc, width_s: float = 0.5):
    """(start s, mean (W,3) g, |std| (W,) g) of the width_s windows from the first sample, in numpy."""
    idx = np.unique(np.searchsorted(t, t[0] + width_s * np.arange(int((t[-1] - t[0]) / width_s) + 2)))
    wins = [(a, b) for a, b in itertools.pairwise(idx.tolist()) if b > a]
    mean = np.array([acc[a:b].mean(axis=0) for a, b in wins])
    std = np.array([np.linalg.norm(acc[a:b].std(axis=0, ddof=1)) for a, b in wins])
    return np.array([t[a] for a, _ in wins]), mean, std


@pytest.mark.parametrize("bump", [None, "std", "mean"])
@pytest.mark.parametrize("quantum", [0.0, 1 / 16384])
def test_motion_check_in_blocks_names_numpys_moving_window(bump, quantum):
    """Fed 13 uneven blocks: a still session passes; the knocked one is refused naming the window
    plain numpy finds (0.5 s windows: the largest |std| against the median, or the largest shift
    of the mean from the windows' median) with numpy's numbers."""
    rng = np.random.default_rng(11)
    t, acc = _session(rng, bump=bump)
    m = MotionCheck()
    edges = np.r_[0, np.sort(rng.integers(1, t.size, 12)), t.size]  # 13 blocks (some empty)
    for a, b in itertools.pairwise(edges.tolist()):
        m.add(t[a:b], acc[a:b])
    try:
        m.check(quantum, "w")
        got = None
    except InputError as e:
        got = str(e)
    assert m.spill.f.closed
    if bump is None:
        assert got is None
        return
    start, mean, std = _numpy_windows(t, acc)
    shift = np.linalg.norm(mean - np.median(mean, axis=0), axis=1)
    k = int(np.argmax(std if bump == "std" else shift))
    assert got is not None and f"moves at t = {start[k]:.2f}-" in got, got
    said = {
        name: float(v) for name, v in re.findall(r"(accel std|session noise|mean moved) ([0-9.]+) g", got)
    }
    want = (
        {"accel std": std[k], "session noise": np.median(std)} if bump == "std" else {"mean moved": shift[k]}
    )
    assert said.keys() == want.keys(), got
    for key, v in want.items():  # printed to 4 digits
        assert said[key] == pytest.approx(v, rel=1e-3), (key, got)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/pagemap")
def test_release_pages_drops_the_fault_around_window(tmp_path):
    """A read at the end of a released range maps the cached pages after it (fault-around): they must
    go too, or a long pass keeps ~64 KiB per chunk group resident. Checked page by page (a kernel
    with large page-cache folios maps a whole folio at a fault, beyond the window: the pass's next
    release covers those). Whether a kernel maps neighbours at a fault depends on its page cache, so
    one page on each side is also read directly: the pages such a fault maps."""
    p = tmp_path / "f.bin"
    p.write_bytes(np.random.default_rng(0).bytes(8 * FAULT_AROUND))  # in the page cache
    with open(p, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
        lo, hi = FAULT_AROUND + 4096, 2 * FAULT_AROUND + 100
        assert data[hi - 1] is not None and data[lo] is not None
        assert data[lo - FAULT_AROUND // 2] is not None and data[hi + FAULT_AROUND // 2] is not None
        window = (lo - FAULT_AROUND, hi + FAULT_AROUND)
        outside = [o for o in _mapped_pages(p, *window) if not lo - 4096 < o < hi]
        assert outside, "no page outside [lo, hi) was mapped: nothing to test"
        release_pages(data, lo, hi)
        assert _mapped_pages(p, *window) == []


def _mapped_pages(path, lo: int, hi: int) -> list[int]:
    """File offsets of the pages of [lo, hi) that this process's mapping of path has mapped
    (/proc/self/pagemap: bit 63, page present)."""
    start = next(
        int(line.split("-")[0], 16)
        for line in Path("/proc/self/maps").read_text().splitlines()
        if line.endswith(str(path))
    )
    page = mmap.PAGESIZE
    first, last = lo // page, -(-hi // page)
    with open("/proc/self/pagemap", "rb") as f:
        f.seek((start // page + first) * 8)
        words = np.frombuffer(f.read((last - first) * 8), "<u8")
    return [int(first + i) * page for i in np.flatnonzero(words >> np.uint64(63))]
