"""ROS 2 bags (rosbag2: a directory with metadata.yaml, or a single .mcap / .db3 file) -> Session.

Decoded with ``rosbags`` (maintained; it ships the ROS 2 message definitions and uses the bag's own
when present). Units (REP 103): sensor_msgs/msg/Imu linear_acceleration in m/s^2 and
angular_velocity in rad/s; Temperature in degC; MagneticField in tesla. Conversions:

    accel_g = a_mps2 / 9.80665      gyro_dps = w_radps * 180 / pi      mag_uT = B_T * 1e6

Time: header.stamp of each message (the sensor's time); the bag's log time (when the recorder got the
message) is compared with it and the difference is reported (median offset and spread), never mixed
in. Temperature messages are interpolated linearly onto the IMU stamps. Messages whose stamps are out
of order are sorted (stable) and counted; duplicated stamps are kept (``accellog doctor`` flags them).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import Session, SessionMeta
from accellog.core.textin import file_kind, read_bytes
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.store.importers.door import GapEvents, check_increasing, check_samples
from accellog.store.importers.ros2_cdr import decode_imu

IMU_TYPE = "sensor_msgs/msg/Imu"
TEMP_TYPE = "sensor_msgs/msg/Temperature"
MAG_TYPE = "sensor_msgs/msg/MagneticField"


@dataclass(frozen=True)
class TopicInfo:
    topic: str
    msgtype: str
    count: int


def _open(path: Path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise InputError("no such file or bag directory", where=str(path))
    if path.is_dir():  # a regular metadata.yaml of at most 1 MiB before rosbags parses it
        read_bytes(path / "metadata.yaml", "bag metadata", "YAML")
    elif (kind := file_kind(path.stat().st_mode)) is not None:
        raise InputError(f"bag is {kind}, not a regular file (not read)", where=str(path))
    if path.is_file() and path.suffix not in (".mcap", ".db3"):
        raise InputError("not a rosbag2 file: give a bag directory, a .mcap or a .db3 file", where=str(path))
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises several error types for unreadable bags
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"cannot open the ROS 2 bag: {msg}", where=str(path)) from None
    return reader


def is_ros2_bag(path: str | Path) -> bool:
    """True for a rosbag2 bag: a folder with metadata.yaml, a .db3 file, or an MCAP file whose schemas
    are ROS 2 message definitions (ros2msg / ros2idl), as opposed to an accellog session."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    if p.suffix.lower() == ".db3":
        return True
    if p.suffix.lower() != ".mcap" or not p.is_file():
        return False
    from mcap.reader import make_reader

    from accellog.store.mcap.summary import summary_of

    try:
        schemas = summary_of(p).schemas  # without the chunk indexes (~75 MB for a day of 0.5 s chunks)
    except Exception:
        try:
            with open(p, "rb") as f:
                summary = make_reader(f).get_summary()
        except Exception:  # not readable as a finished MCAP: let the session reader say why
            return False
        schemas = {} if summary is None else summary.schemas
    return any(s.encoding in ("ros2msg", "ros2idl") for s in schemas.values())


def list_topics(path: str | Path) -> list[TopicInfo]:
    """Every topic of the bag with its message type and count."""
    reader = _open(Path(path))
    try:
        return [TopicInfo(c.topic, c.msgtype, int(c.msgcount)) for c in reader.connections]
    finally:
        reader.close()


def _pick(conns, topic: str | None, msgtype: str, path: Path, flag: str, required: bool):
    of_type = [c for c in conns if c.msgtype == msgtype]
    if topic is not None:
        hit = [c for c in conns if c.topic == topic]
        if not hit:
            have = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in conns})) or "none"
            raise InputError(f"{flag} {topic}: no such topic (topics: {have})", where=str(path))
        if hit[0].msgtype != msgtype:
            raise InputError(f"{flag} {topic} is {hit[0].msgtype}, not {msgtype}", where=str(path))
        return hit
    if not required:
        return []
    names = sorted({c.topic for c in of_type})
    if len(names) == 1:
        return of_type
    if not names:
        have = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in conns})) or "none"
        raise InputError(f"no {msgtype} messages in the bag (topics: {have})", where=str(path))
    counts = {n: sum(c.msgcount for c in of_type if c.topic == n) for n in names}
    listing = ", ".join(f"{n} ({counts[n]} messages)" for n in names)
    raise InputError(f"several IMU topics: choose one with --topic: {listing}", where=str(path))


_BLOCK = 65536


def _messages(reader, conns, start=None, stop=None):
    """(connection, log time, raw) of conns in log-time order, start <= log time < stop; a single bag
    is read directly (no merge)."""
    if len(reader.readers) == 1:
        return reader.readers[0].messages(connections=conns, start=start, stop=stop)
    return reader.messages(connections=conns, start=start, stop=stop)


def _read_range(path: str, topic: str, start: int, stop: int):
    """Worker: the IMU messages of ``topic`` with start <= log time < stop (own reader, own process)."""
    reader = _open(Path(path))
    try:
        conns = [c for c in reader.connections if c.topic == topic and c.msgtype == IMU_TYPE]
        return _read_imu(reader, conns, start, stop, path=Path(path))
    finally:
        reader.close()


def _read_imu_parallel(reader, conns, path: Path, jobs: int):
    """_read_imu split into ``jobs`` equal log-time ranges decoded in parallel (forked processes: each
    opens the bag itself; results come back as arrays, concatenated in time order)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    t0, t1 = int(reader.start_time), int(reader.end_time) + 1
    edges = [t0 + (t1 - t0) * k // jobs for k in range(jobs + 1)]
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("fork")) as ex:
        futs = [ex.submit(_read_range, str(path), conns[0].topic, a, b) for a, b in itertools.pairwise(edges)]
        parts = [f.result() for f in futs]
    frames = set().union(*(p[4] for p in parts))
    first = next((p for p in parts if p[0].size), parts[0])
    cat = [np.concatenate([p[i] for p in parts]) for i in range(4)]
    return (*cat, frames, first[5], first[6])


MAX_PREALLOC = 1 << 22
"""Messages preallocated from a bag's declared count (64 bytes each: 256 MiB): a count a damaged or
hostile metadata.yaml inflates costs no more; beyond it the decoded blocks are kept and joined."""


def _read_imu(reader, conns, start=None, stop=None, progress=None, path: Path | None = None):
    """Arrays of the IMU messages: stamp ns, log ns, accel m/s^2, gyro rad/s, frame ids, covariances.

    Raw messages are gathered _BLOCK at a time and decoded together (ros2_cdr.decode_imu; rosbags'
    deserialize_cdr one by one for blocks it does not take) into arrays sized from the bag's message
    count; progress(done, total messages) after each block. Memory: the arrays plus one block."""
    total = sum(int(c.msgcount) for c in conns)
    gather = _Gather(min(total, MAX_PREALLOC) if start is None and stop is None else 0)
    raws: list[bytes] = []
    logs: list[int] = []
    msgtype = conns[0].msgtype if conns else IMU_TYPE
    label = f"{path}: {conns[0].topic}" if conns else str(path)
    for _conn, t_log, raw in _messages(reader, conns, start, stop):
        raws.append(raw)
        logs.append(t_log)
        if len(raws) == _BLOCK:
            gather.add(_decode_block(reader, msgtype, raws, logs, label, gather.n))
            raws, logs = [], []
            if progress is not None:
                progress(gather.n, total)
    if raws or not gather.n:
        gather.add(_decode_block(reader, msgtype, raws, logs, label, gather.n))
    return gather.result()


class _Gather:
    """Decoded blocks written into preallocated arrays (capacity: the expected message count), or kept
    and joined at the end beyond it; frame ids and the first message's covariances kept."""

    def __init__(self, capacity: int) -> None:
        self.arrays = [np.empty(capacity, np.int64), np.empty(capacity, np.int64),
                       np.empty((capacity, 3)), np.empty((capacity, 3))]  # fmt: skip
        self.n = 0
        self.extra: list[tuple] = []
        self.frames: set[str] = set()
        self.cov: tuple = (None, None)

    def add(self, block: tuple) -> None:
        m = block[0].shape[0]
        self.frames |= block[4]
        if self.cov[0] is None and m:
            self.cov = (block[5], block[6])
        if not self.extra and self.n + m <= self.arrays[0].shape[0]:
            for i in range(4):
                self.arrays[i][self.n : self.n + m] = block[i]
        else:
            self.extra.append(block)
        self.n += m

    def result(self) -> tuple:
        k = self.n - sum(b[0].shape[0] for b in self.extra)
        cat = [a[:k] for a in self.arrays]
        if self.extra:
            cat = [np.concatenate([cat[i], *(b[i] for b in self.extra)]) for i in range(4)]
        return (*cat, self.frames, *self.cov)


def _decode_block(reader, msgtype: str, raws: list, logs: list, label: str = "", first: int = 0) -> tuple:
    """(stamp ns, log ns, accel m/s^2, gyro rad/s, frame ids, cov accel, cov gyro) of one block
    (messages first, first+1, ...: a message that does not decode is an InputError at
    '{label} message {index}')."""
    log = np.asarray(logs, dtype=np.int64)
    fast = decode_imu(raws)
    if fast is not None:
        stamp, acc, gyr, frames, cov_a, cov_g = fast
        return stamp, log, acc, gyr, frames, cov_a, cov_g
    des = reader.typestore.deserialize_cdr
    rows, frames, head = [], set(), None
    for j, raw in enumerate(raws):
        try:
            m = des(raw, msgtype)
            st, la, av = m.header.stamp, m.linear_acceleration, m.angular_velocity
            rows.append((st.sec, st.nanosec, la.x, la.y, la.z, av.x, av.y, av.z))
        except Exception as exc:
            raise InputError(
                f"cannot decode {msgtype} ({type(exc).__name__}: {exc})", where=f"{label} message {first + j}"
            ) from None
        frames.add(m.header.frame_id)
        head = head or m
    if not rows:
        return np.empty(0, np.int64), log, np.empty((0, 3)), np.empty((0, 3)), frames, None, None
    assert head is not None  # the first message of the rows
    ints = np.array([r[:2] for r in rows], dtype=np.int64)
    vals = np.array([r[2:] for r in rows], dtype=np.float64)
    cov_a = np.array(head.linear_acceleration_covariance)
    cov_g = np.array(head.angular_velocity_covariance)
    return ints[:, 0] * 1_000_000_000 + ints[:, 1], log, vals[:, :3], vals[:, 3:], frames, cov_a, cov_g


def _read_scalar(reader, conns, kind: str, path: Path):
    """(stamp ns, values) of the temperature (kind 'temp', degC) or magnetometer (T) messages; a
    message that does not decode is one InputError naming its topic and index."""
    t: list[int] = []
    v: list[float | tuple[float, float, float]] = []  # degC, or a magnetic field (x, y, z) T
    des = reader.typestore.deserialize_cdr
    for i, (conn, t_log, raw) in enumerate(_messages(reader, conns)):
        try:
            m = des(raw, conn.msgtype)
            st = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            if kind == "temp":
                v.append(float(m.temperature))
            else:
                f = m.magnetic_field
                v.append((float(f.x), float(f.y), float(f.z)))
        except Exception as exc:
            raise InputError(
                f"cannot decode {conn.msgtype} ({type(exc).__name__}: {exc})",
                where=f"{path}: {conn.topic} message {i}",
            ) from None
        t.append(st or t_log)
    return np.asarray(t, np.int64), np.asarray(v, float)


def check_imu(
    path: Path, topic: str, stamp, acc_mps2, gyr_radps, first: int = 0, prev: int | None = None
) -> None:
    """The importers' door (store.importers.door) for IMU messages first, first+1, ... of
    ``topic``: stamps (ns) not negative and strictly increasing (prev: the last stamp before),
    accelerations and rates finite and within any MEMS range; InputError naming topic and index."""

    def where_of(i: int) -> str:
        return f"{path}: {topic} message {first + i}"

    neg = np.flatnonzero(stamp < 0)
    if neg.size:
        raise InputError(
            f"header stamp {int(stamp[neg[0]])} ns is before 1970 (out of range)", where=where_of(int(neg[0]))
        )
    base = int(stamp[0]) if prev is None else prev
    check_increasing((stamp - base) / 1e9, where_of, None if prev is None else 0.0)
    if acc_mps2 is not None:
        check_samples(acc_mps2 / STANDARD_GRAVITY_MPS2, np.rad2deg(gyr_radps), where_of)


def _stamp_report(stamp: np.ndarray, log: np.ndarray) -> dict[str, str]:
    """How header stamps relate to the bag's log time (the recorder's receive time)."""
    d = (log - stamp).astype(np.float64) / 1e6
    med = float(np.median(d))
    spread = float(np.percentile(np.abs(d - med), 99)) if d.size else 0.0
    out = {"log_minus_stamp_ms": f"median {med:.3f}, 99th pct |deviation| {spread:.3f}"}
    if abs(med) > 1.0 or spread > 5.0:
        out["stamp_warning"] = (
            f"header stamps disagree with the bag's log time (median offset {med:.3f} ms, 99% within "
            f"{spread:.3f} ms of it): header stamps are used"
        )
    return out


def _namespace(topic: str) -> str:
    """'/imu/data' -> '/imu'; '/imu' -> '/'."""
    return topic.rsplit("/", 1)[0] or "/"


def companion(conns, imu_topic: str, msgtype: str) -> list:
    """The connections of the bag's ``msgtype`` topic that goes with ``imu_topic``: the only topic of that
    type, or the only one in the IMU topic's namespace (or the IMU topic's own name as a namespace:
    /imu with /imu/temperature); none when that is ambiguous."""
    of_type = [c for c in conns if c.msgtype == msgtype]
    names = sorted({c.topic for c in of_type})
    if len(names) == 1:
        return of_type
    near = [n for n in names if _namespace(n) in (_namespace(imu_topic), imu_topic)]
    return [c for c in of_type if c.topic == near[0]] if len(near) == 1 else []


def _topics(conns, path: Path, topic, temperature_topic, mag_topic) -> tuple[list, list, list]:
    """Connections of the IMU topic, its temperature topic and its magnetometer topic (see _read_bag)."""
    imu = _pick(conns, topic, IMU_TYPE, path, "--topic", True)
    tc = _pick(conns, temperature_topic, TEMP_TYPE, path, "--temperature-topic", False)
    mc = _pick(conns, mag_topic, MAG_TYPE, path, "--mag-topic", False)
    tc = tc if temperature_topic else companion(conns, imu[0].topic, TEMP_TYPE)
    mc = mc if mag_topic else companion(conns, imu[0].topic, MAG_TYPE)
    return imu, tc, mc


def _read_bag(path: Path, topic, temperature_topic, mag_topic, jobs, progress=None):
    """IMU arrays (+ temperature and magnetometer messages) of the chosen topics; without a
    temperature or magnetometer topic, the one that goes with the IMU topic (``companion``)."""
    import multiprocessing

    reader = _open(path)
    try:
        imu, tc, mc = _topics(reader.connections, path, topic, temperature_topic, mag_topic)
        jobs = 1 if jobs is None else jobs
        if jobs > 1 and len(imu) == 1 and "fork" in multiprocessing.get_all_start_methods():
            arrays = _read_imu_parallel(reader, imu, path, jobs)
        else:
            arrays = _read_imu(reader, imu, progress=progress, path=path)
        temp = (tc[0].topic, *_read_scalar(reader, tc, "temp", path)) if tc else None
        mag = (mc[0].topic, *_read_scalar(reader, mc, "mag", path)) if mc else None
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"cannot decode the ROS 2 bag: {exc}", where=str(path)) from None
    finally:
        reader.close()
    return imu[0].topic, arrays, temp, mag


def _provenance(path: Path, topic: str, arrays) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Stamps (checked: check_imu), accel, gyro and meta.extra: time source, stamp/log agreement."""
    stamp, log, acc, gyr, frames, cov_a, cov_g = arrays
    extra = {
        "source_file": path.name,
        "ros2_topic": topic,
        "ros2_frame_id": ",".join(sorted(frames)),
        "source_unit": "m/s^2",
        "conversion": "accel_g = a_mps2 / 9.80665; gyro_dps = w_radps * 180 / pi",
        "time_source": "header.stamp",
    }
    if not stamp.any():
        stamp = log.copy()
        extra["time_source"] = "bag log time (every header stamp is zero)"
    else:
        extra.update(_stamp_report(stamp, log))
    check_imu(path, topic, stamp, acc, gyr)
    if cov_a is not None:
        extra["ros2_linear_acceleration_covariance"] = ",".join(f"{v:.6g}" for v in cov_a)
        extra["ros2_angular_velocity_covariance"] = ",".join(f"{v:.6g}" for v in cov_g)
    return stamp, acc, gyr, extra


def temp_on(temp, stamp: np.ndarray) -> np.ndarray | None:
    """The temperature messages (topic, stamp ns, degC) interpolated linearly onto IMU stamps ns."""
    if temp is None or not temp[1].size:
        return None
    return np.interp(stamp.astype(np.float64), temp[1].astype(np.float64), temp[2])


def side_extras(extra: dict, temp, mag, t0: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """meta.extra lines of the temperature and magnetometer topics; the magnetometer's t s and uT."""
    if temp is not None and temp[1].size:
        extra["temperature"] = f"{temp[0]}: {temp[1].size} messages, interpolated onto the IMU stamps"
        extra["ros2_temperature_topic"] = temp[0]
    if mag is None or not mag[1].size:
        return None, None
    extra["magnetometer"] = f"{mag[0]}: tesla -> uT (x 1e6)"
    extra["ros2_mag_topic"] = mag[0]
    return (mag[1] - t0) / 1e9, mag[2] * 1e6


def session_meta(t0: int, t_s: np.ndarray, extra: dict) -> SessionMeta:
    """The imported session's meta: rate 1 / median interval of t_s (s)."""
    med = float(np.median(np.diff(t_s)))
    return SessionMeta(
        source="import:ros2",
        chip="unknown",
        sample_rate_hz=1.0 / med if med > 0 else 0.0,
        start_time_unix_ns=t0,
        extra=extra,
    )


def import_ros2(
    path: str | Path,
    *,
    topic: str | None = None,
    temperature_topic: str | None = None,
    mag_topic: str | None = None,
    jobs: int | None = None,
    progress=None,
) -> Session:
    """A rosbag2 IMU topic (plus optional Temperature and MagneticField topics) -> Session.

    Without ``topic`` the bag's only sensor_msgs/msg/Imu topic is used; with several, the error
    lists them. Without ``temperature_topic`` / ``mag_topic`` the bag's topic of that type that goes
    with the IMU topic is read (the only one, or the only one in its namespace; ``companion``). Provenance (bag, topic, frame_id, stamp/log-time agreement, the bag's covariances)
    goes to meta.extra. jobs: decoding processes (default 1: decoding is vectorised, so the
    read dominates, and each process holds its own arrays; an hour at 1 kHz takes ~11 s CPU, 380 MB). progress(done, total): IMU messages decoded
    (every 65536 in one process; at the end with several).
    """
    path = Path(path)
    imu_topic, arrays, temp, mag = _read_bag(path, topic, temperature_topic, mag_topic, jobs, progress)
    if progress is not None:
        progress(arrays[0].shape[0], arrays[0].shape[0])
    if arrays[0].shape[0] < 2:
        raise InputError(
            f"{imu_topic}: {arrays[0].shape[0]} IMU message(s); need at least two", where=str(path)
        )
    stamp, acc, gyr, extra = _provenance(path, imu_topic, arrays)
    t0 = int(stamp[0])
    t_s = (stamp - t0) / 1e9
    temp_degC = temp_on(temp, stamp)
    mag_t, mag_uT = side_extras(extra, temp, mag, t0)
    meta = session_meta(t0, t_s, extra)
    gaps = GapEvents()
    gaps.add(t_s)
    return Session(
        meta=meta,
        t_s=t_s,
        sample_index=np.arange(t_s.shape[0], dtype=np.int64),
        accel_g=np.divide(acc, STANDARD_GRAVITY_MPS2, out=acc),  # in place: the decoded arrays are ours
        gyro_dps=np.rad2deg(gyr, out=gyr),
        temp_degC=temp_degC,
        mag_t_s=mag_t,
        mag_uT=mag_uT,
        events=gaps.events,
        path=str(path),
    )
