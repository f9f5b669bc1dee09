"""`accellog import ros2 BAG -o OUT.mcap` streamed: IMU messages decoded and written a block at a time.

The same file as ``write_session(out, import_ros2(bag))`` (the same batches, values and meta; the meta
known only at the end, e.g. the sample rate and the stamp/log-time report, is written as a later
'session' metadata record, which readers take), in flat memory: only the stamps and log times of the
whole bag are kept (16 bytes a message), not the decoded session (72+ bytes a message).

Streaming needs header stamps in non-decreasing order and non-zero; a bag without them (stamps to
sort, or time taken from the log) is left to the in-memory import (``None``; nothing is written).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import SessionMeta
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.store.atomic import AtomicOutput
from accellog.store.importers import ros2
from accellog.store.importers.door import GapEvents
from accellog.store.layout import to_ns_array
from accellog.store.writer import SessionWriter


class _Unordered(Exception):
    """Stamps that the streamed import cannot take (zero: the in-memory import may use log time)."""


def import_ros2_to_mcap(
    path: str | Path,
    out: str | Path,
    *,
    topic: str | None = None,
    temperature_topic: str | None = None,
    mag_topic: str | None = None,
    batch_size: int = 500,
    compression: str = "zstd",
    overwrite: bool = False,
    progress=None,
) -> dict | None:
    """Import the bag's IMU topic (+ temperature, magnetometer; see ros2.import_ros2) into ``out``
    (atomic); the facts the CLI prints (as for a Session), or None when the stamps need the in-memory
    import (zero stamps: nothing written). Stamps and samples pass ros2.check_imu as they stream."""
    path, out = Path(path), Path(out)
    reader = ros2._open(path)
    ao = AtomicOutput(out, inputs=(path,), overwrite=overwrite)
    try:
        imu, tc, mc = ros2._topics(reader.connections, path, topic, temperature_topic, mag_topic)
        temp = (tc[0].topic, *ros2._read_scalar(reader, tc, "temp", path)) if tc else None
        mag = (mc[0].topic, *ros2._read_scalar(reader, mc, "mag", path)) if mc else None
        job = _Stream(reader, imu, path, ao, temp, batch_size, compression)
        try:
            job.run(progress)
        except _Unordered:
            job.abort()
            return None
        except InputError:
            job.abort()
            raise
        except Exception as exc:
            job.abort()
            raise InputError(f"cannot decode the ROS 2 bag: {exc}", where=str(path)) from None
        return job.finish(imu[0].topic, temp, mag, batch_size)
    finally:
        reader.close()


class _Stream:
    """One streamed import: blocks of messages -> IMU batches in the writer; stamps and log kept."""

    def __init__(self, reader, conns, path: Path, ao: AtomicOutput, temp, batch_size: int, compression: str):
        self.reader, self.conns, self.path, self.ao, self.temp = reader, conns, path, ao, temp
        self.batch = batch_size
        self.block = batch_size * max(1, ros2._BLOCK // batch_size)  # whole batches, as write_session cuts
        self.compression = compression
        self.total = sum(int(c.msgcount) for c in conns)
        self.n = 0
        cap = min(self.total, ros2.MAX_PREALLOC)  # the declared count may be absurd
        self.stamp = np.empty(cap, np.int64)  # filled in place (no join at the end)
        self.log = np.empty(cap, np.int64)
        self.frames: set[str] = set()
        self.cov: tuple = (None, None)
        self.writer: SessionWriter | None = None
        self.t0 = 0
        self.last = -(2**63)

    def run(self, progress) -> None:
        raws: list[bytes] = []
        logs: list[int] = []
        msgtype = self.conns[0].msgtype
        label = f"{self.path}: {self.conns[0].topic}"
        for _conn, t_log, raw in ros2._messages(self.reader, self.conns):
            raws.append(raw)
            logs.append(t_log)
            if len(raws) == self.block:
                self._write(ros2._decode_block(self.reader, msgtype, raws, logs, label, self.n))
                raws, logs = [], []
                if progress is not None:
                    progress(self.n, self.total)
        if raws:
            self._write(ros2._decode_block(self.reader, msgtype, raws, logs, label, self.n))

    def _write(self, block: tuple) -> None:
        stamp, _log, acc, gyr = block[:4]
        if not stamp.size:
            return
        if self.writer is None and not stamp[0]:
            raise _Unordered  # zero stamps: the in-memory import decides (log time when all are zero)
        k = self.n
        ros2.check_imu(
            self.path, self.conns[0].topic, stamp, acc, gyr, k, None if self.writer is None else self.last
        )
        self.last = int(stamp[-1])
        self.n += stamp.size
        if self.n > self.stamp.size:  # more messages than preallocated: grow geometrically
            size = max(self.n, 2 * self.stamp.size)
            self.stamp = np.concatenate([self.stamp[:k], np.empty(size - k, np.int64)])
            self.log = np.concatenate([self.log[:k], np.empty(size - k, np.int64)])
        self.stamp[k : self.n], self.log[k : self.n] = stamp, block[1]
        self.frames |= block[4]
        if self.writer is None:
            self.t0 = int(stamp[0])
            self.cov = block[5:7]
            extra = {"source_file": self.path.name}
            meta = SessionMeta(source="import:ros2", chip="unknown", start_time_unix_ns=self.t0, extra=extra)
            self.writer = SessionWriter(
                self.ao.begin(), meta, flush_interval_s=math.inf, chunk_size=1024 * 1024,
                compression=self.compression,
            )  # fmt: skip
        t_ns = to_ns_array((stamp - self.t0) / 1e9, str(self.path))
        acc_g = acc / STANDARD_GRAVITY_MPS2
        gyro_dps = np.rad2deg(gyr)
        temp = ros2.temp_on(self.temp, stamp)
        for s in range(0, stamp.size, self.batch):
            e = min(s + self.batch, stamp.size)
            self.writer.write_imu(k + s, t_ns[s:e], accel_g=acc_g[s:e], gyro_dps=gyro_dps[s:e],
                                  temp_degC=None if temp is None else temp[s:e])  # fmt: skip

    def abort(self) -> None:
        try:
            if self.writer is not None and not self.writer.closed:
                self.writer.close()  # may fail again (a full disk): the temporary file goes all the same
        except Exception:
            pass
        finally:
            self.ao.abort()

    def finish(self, topic: str, temp, mag, batch_size: int) -> dict:
        """The magnetometer, the final meta, the file committed; the facts."""
        n = self.n
        if n < 2:
            self.abort()
            raise InputError(f"{topic}: {n} IMU message(s); need at least two", where=str(self.path))
        arrays = (self.stamp[:n], self.log[:n], None, None, self.frames, *self.cov)
        try:
            stamp, _, _, extra = ros2._provenance(self.path, topic, arrays)
            t_s = (stamp - self.t0) / 1e9
            mag_t, mag_uT = ros2.side_extras(extra, temp, mag, self.t0)
            meta = ros2.session_meta(self.t0, t_s, extra)
            w = self.writer
            if w is None:  # the writer opens at the first IMU message, and n >= 2 came
                raise RuntimeError("IMU messages counted without a writer")
            if mag_t is not None and mag_uT is not None:
                m_ns = to_ns_array(mag_t)
                for i in range(0, m_ns.shape[0], batch_size):
                    w.write_mag(m_ns[i : i + batch_size], mag_uT=mag_uT[i : i + batch_size], first_index=i)
            gaps = GapEvents()
            gaps.add(t_s)
            for e in gaps.events:
                w.write_event(e)
            w.update_meta(meta)
            w.close()
        except BaseException:
            self.abort()
            raise
        self.ao.commit()
        return _facts(meta, n, float(t_s[-1] - t_s[0]), len(gaps.events))


def _facts(meta, n: int, duration_s: float, events: int) -> dict:
    """What accellog.cli.imports._facts says of the same session."""
    return {
        "samples": n,
        "duration_s": duration_s,
        "sample_rate_hz": meta.sample_rate_hz,
        "accel_storage": "g (float64)",
        "source_unit": meta.extra.get("source_unit", ""),
        "gyro": True,
        "poses": [],
        "events": events,
        "notes": {
            k: v for k, v in meta.extra.items() if k.startswith(("ros2_topic", "stamp_", "out_of", "dup"))
        },
    }
