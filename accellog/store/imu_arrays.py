"""The Session's sample columns built group by group while the fast reader walks a file.

``ImuAccumulator`` is the ``BatchAccumulator`` of the /imu channel for ``read_session``: after each
group's ImuBatch messages are decoded into it, it converts their samples at once, while they are in
the CPU cache and while the reader's other thread decompresses the next group, into arrays sized
once: t_s (ns -> s, in place of t_ns: the integer times are not kept), accel_g and gyro_dps (counts /
LSB), temp_degC (counts / 333.87 + 21), host_time_s (each message's host time on its samples) and
sample_index. Every conversion is elementwise, so the values are those of converting the whole
arrays at the end (bit for bit); ``read_session`` decides at the end which ones it uses (a file that
stores values instead of counts, or mixed batches, take its usual path).
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from accellog.core.errors import InputError
from accellog.core.units import TEMP_LSB_PER_DEGC, temp_counts_to_degC
from accellog.store.layout import NS_PER_S
from accellog.store.mcap.batch_decode import BatchAccumulator, DecodedBatch

F8 = np.dtype(np.float64)
INT64_MAX = np.iinfo(np.int64).max


def first_indexes(first, n_per: np.ndarray, where: str) -> np.ndarray:
    """Each message's first_sample_index (a proto uint64: list or array) as int64; InputError (one
    line) if a message's samples would go beyond int64 (the sample indexes are int64)."""
    top = 0 if not len(first) else int(first.max() if isinstance(first, np.ndarray) else max(first))
    if top > INT64_MAX:  # (checked first: asarray of a list mixing int64 and uint64 values is float)
        raise InputError(f"first_sample_index {top} is beyond int64", where=where)
    a = np.asarray(first, dtype=np.int64)
    if np.any(a - 1 > INT64_MAX - n_per):  # a + n_per - 1 without overflow (a >= 0)
        raise InputError("IMU sample indexes beyond int64 (first_sample_index near 2**63)", where=where)
    return a


def lsb_scales(meta_kv: dict[str, str]) -> tuple[float | None, float | None]:
    """(accel LSB per g, gyro LSB per deg/s) of the 'session' metadata, None where absent/invalid/0
    (read_session checks and reports the metadata itself)."""

    def num(key: str) -> float | None:
        try:
            v = float(meta_kv.get(key) or 0.0)
        except ValueError:
            return None
        return v or None

    return num("accel_lsb_per_g"), num("gyro_lsb_per_dps")


def per_sample(first: np.ndarray, host_s: np.ndarray, n_per: np.ndarray, idx: np.ndarray, host: np.ndarray):
    """Fill idx and host for the samples of messages with first sample index ``first``, host time
    ``host_s`` (s) and ``n_per`` samples each: message k's samples get first[k] + 0, 1, ... and
    host_s[k] (as read_session computes them for the whole session)."""
    m = int(n_per[0]) if n_per.shape[0] else 0
    if m and np.all(n_per == m):  # equal reads (the usual case): written in place, no temporaries
        host.reshape(-1, m)[...] = host_s[:, None]
        np.add(first[:, None], np.arange(m, dtype=np.int64), out=idx.reshape(-1, m))
        return
    host[...] = np.repeat(host_s, n_per)
    offset = first - (np.cumsum(n_per) - n_per)  # sample_index[i] = offset[k] + i
    idx[...] = np.repeat(offset, n_per) + np.arange(idx.shape[0], dtype=np.int64)


class ImuAccumulator(BatchAccumulator):
    """ImuBatch parts joined as by BatchAccumulator, each part's samples converted as it is added
    (see module doc) on a worker thread while the next group is decoded here (numpy releases the
    GIL); ``finish()`` returns the batch without t_ns and with ``derived`` columns."""

    scalar_arrays = True  # first_sample_index, host_time_ns as arrays: no lists of 100 k ints per hour

    def __init__(self, message: str, accel_lsb: float | None, gyro_lsb: float | None) -> None:
        super().__init__(message)
        self._scalar_parts: dict[str, list] = {}
        self._lsb = {"accel_counts": accel_lsb, "gyro_counts": gyro_lsb, "temp_counts": TEMP_LSB_PER_DEGC}
        self._phys = {"accel_counts": "accel_g", "gyro_counts": "gyro_dps", "temp_counts": "temp_degC"}
        self._done: dict[str, int] = {}  # items of each stored field already handed to a conversion
        self._derived = BatchAccumulator(message)  # the float and index columns (worker thread only)
        self._pool: ThreadPoolExecutor | None = None
        self._pending: Future | None = None

    def _wait(self) -> None:
        """Wait for the conversion in flight (raises its exception)."""
        if self._pending is not None:
            pending, self._pending = self._pending, None
            pending.result()

    def _add_scalars(self, part: DecodedBatch) -> None:
        for name, v in part.scalars.items():
            self._scalar_parts.setdefault(name, []).append(v)

    def reserve(self, name: str, dtype: np.dtype, count: int, done: float) -> np.ndarray:
        store = self._store.get(name)
        if store is not None and self._used.get(name, 0) + count > store.shape[0]:
            self._wait()  # the store grows (may move): no conversion may be reading it
        return super().reserve(name, dtype, count, done)

    def add(self, part: DecodedBatch, done: float) -> None:
        super().add(part, done)
        views = {}
        for name in ("t_ns", *self._lsb):
            lo, hi = self._done.get(name, 0), self._used.get(name, 0)
            self._done[name] = hi
            if hi > lo and (name == "t_ns" or self._lsb[name] is not None):
                views[name] = self._store[name][lo:hi]
        self._wait()  # one conversion in flight: the previous group's
        if done >= 1.0:  # the file's last group: nothing left to decode meanwhile (core.threads)
            self._convert(views, part, done)
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1)
        self._pending = self._pool.submit(self._convert, views, part, done)

    def _convert(self, views: dict[str, np.ndarray], part: DecodedBatch, done: float) -> None:
        """The conversions of one part (worker thread): views of its new stored items."""
        t = views.pop("t_ns", None)
        if t is not None:  # ns -> s in place: the float64 times overwrite the int64 ones (same size)
            np.divide(t, NS_PER_S, out=t.view(F8))
        for name, counts in views.items():
            out = self._derived.reserve(self._phys[name], F8, counts.shape[0], done)
            if name == "temp_counts":
                temp_counts_to_degC(counts, out=out)
            else:
                lsb = self._lsb[name]
                if lsb is None:
                    raise RuntimeError(f"{name} stored without its LSB in the session metadata")
                np.divide(counts, lsb, out=out)
        n_per = part.counts.get("t_ns")
        if n_per is not None and n_per.shape[0]:
            self._per_message(part, n_per, done)

    def _per_message(self, part: DecodedBatch, n_per: np.ndarray, done: float) -> None:
        """host_time_s and sample_index of the part's samples (per_sample)."""
        k = int(n_per.sum())
        per_sample(
            np.asarray(part.scalars["first_sample_index"], dtype=np.int64),
            np.asarray(part.scalars["host_time_ns"], dtype=np.int64) / NS_PER_S,
            n_per,
            self._derived.reserve("sample_index", np.dtype(np.int64), k, done),
            self._derived.reserve("host_time_s", F8, k, done),
        )

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool, self._pending = None, None

    def finish(self) -> DecodedBatch:
        self._wait()
        self.close()
        out = super().finish()
        for name, parts in self._scalar_parts.items():
            if all(isinstance(v, np.ndarray) for v in parts):
                out.scalars[name] = np.concatenate(parts)
            else:  # a part decoded with lists
                out.scalars[name] = [
                    x for v in parts for x in (v.tolist() if isinstance(v, np.ndarray) else v)
                ]
        derived = self._derived.finish().arrays
        derived["t_s"] = out.arrays.pop("t_ns").view(F8)
        out.derived = derived
        return out
