"""MCAP read-back speed: read_session of a 1 kHz session vs reading the same arrays from raw binary files.

Usage: python benchmarks/bench_readback.py [--minutes 60] [--repeat 5] [--no-generic]

Data: a simulated static recording (seeded): accel/gyro/temp counts with noise, one host time per
36-sample FIFO read. MCAP layouts (same format, same schema, one message per batch):
- recorder: 36-sample messages (one FIFO read each) written by SessionWriter with its defaults
  (chunk ended and flushed every 0.5 s: crash-safe), zstd (default) or lz4;
- recorder, varying reads: the same with FIFO reads of 30-42 samples (seeded), as a live recorder
  polling a FIFO writes them: message lengths change from one message to the next, zstd or lz4;
- write_session: whole-session writer (imports, simulations), 1 MiB chunks, zstd (default) or lz4
  (messages are still split wherever host time changes, i.e. every 36 samples here).
Baselines, holding exactly the arrays a Session gets (same dtypes; t_ns i8, sample_index i8,
accel/gyro counts i4 (n,3), temp counts i4, host time ns i8 per sample):
- raw binary: one flat uncompressed .bin file read with one readinto + zero-copy views;
- raw binary + conversions: the same followed by read_session's unit conversions (ns -> s,
  counts -> g, deg/s, degC);
- raw .npy: one np.load per array (for reference).
Floors: mapping the MCAP file and decompressing its chunks (no parsing, no decoding): the part of
read_session no decoder can avoid. 'streamed' rows: the same file through iter_imu (blocks of
one chunk group, the same samples, checked once), every block handed out and dropped. 'generic'
rows are the reader before the vectorised path (mcap's reader + per-message BatchDecoder;
accellog.store.reader.FAST_READ = False), timed once.
Every file is read once before timing (page cache warm); each figure is the best of --repeat runs,
interleaved round-robin so that load from other processes hits all variants alike. Each row shows its
wall time and CPU time (user + sys of every thread: read_session decompresses on other threads and
converts units on one), each MCAP row both as a ratio to its own floor (issue #11: <= 1.5x) and the
ratio of the median walls ('med': a run's spread on this VM is mostly page zeroing), and the
peak traced memory of one more run (tracemalloc: numpy arrays and Python objects, not the mapped file).
The floor leaves out what read_session must do besides decompressing: the CRC checks of every chunk
and of the data section, and the unit conversions (the 'raw binary + conversions' row less the 'raw
binary' row prices those alone). --dir DIR keeps the generated files there and reuses them.
"""

from __future__ import annotations

import argparse
import itertools
import mmap
import os
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np

from accellog.core.session import Session, SessionMeta
from accellog.core.units import temp_counts_to_degC
from accellog.store import reader
from accellog.store.reader import read_session
from accellog.store.stream import iter_imu
from accellog.store.writer import DEFAULT_COMPRESSION, SessionWriter, write_session

NS = 1_000_000_000


def simulate(n: int, seed: int = 0) -> Session:
    """n samples at 1 kHz: counts of a nearly level sensor with noise, warm-up temperature, FIFO host times."""
    rng = np.random.default_rng(seed)
    t_ns = np.arange(n, dtype=np.int64) * 1_000_000
    up = np.array([0.02, -0.01, 1.0])
    ac = np.round((up + rng.normal(0, 0.004, (n, 3))) * 16384).astype(np.int32)
    gc = np.round(rng.normal(0, 0.05, (n, 3)) * 131 + [30, -12, 5]).astype(np.int32)
    tc = np.round((30 + 5 * (1 - np.exp(-np.arange(n) / 6e5)) - 21) * 333.87 + rng.normal(0, 3, n)).astype(
        np.int32
    )
    host_ns = (np.arange(n) // 36 + 1) * 36_000_000 + 250_000
    meta = SessionMeta(
        source="emulator", accel_lsb_per_g=16384.0, gyro_lsb_per_dps=131.0, sample_rate_hz=1000.0
    )
    return Session(
        meta=meta,
        t_s=t_ns / NS,
        sample_index=np.arange(n, dtype=np.int64),
        accel_g=ac / 16384.0,
        accel_counts=ac,
        gyro_dps=gc / 131.0,
        gyro_counts=gc,
        temp_degC=temp_counts_to_degC(tc.astype(np.float64)),
        temp_counts=tc,
        host_time_s=host_ns / NS,
    )


def fifo_reads(n: int, vary: bool) -> np.ndarray:
    """Start of each FIFO read (and n at the end): 36 samples each, or 30-42 (seeded) when vary."""
    sizes = np.random.default_rng(1).integers(30, 43, n // 30 + 1) if vary else np.full(n // 36 + 1, 36)
    starts = np.concatenate([[0], np.cumsum(sizes)])
    return np.append(starts[starts < n], n)


def stored_host_ns(s: Session, vary: bool) -> np.ndarray:
    """The host time (ns) of each sample as the recorder stores it: that of its read's last sample."""
    host = np.round(s.host_time_s * NS).astype(np.int64)
    bounds = fifo_reads(s.n, vary)
    return np.repeat(host[bounds[1:] - 1], np.diff(bounds))


def write_recorder_layout(
    path: Path, s: Session, compression: str = DEFAULT_COMPRESSION, vary: bool = False
) -> None:
    """As the recorder writes: one message per FIFO read (36 samples; vary: 30-42), SessionWriter
    defaults otherwise."""
    t_ns = np.round(s.t_s * NS).astype(np.int64)
    host = stored_host_ns(s, vary)
    bounds = fifo_reads(s.n, vary).tolist()
    with SessionWriter(path, s.meta, compression=compression) as w:
        for i, j in itertools.pairwise(bounds):
            w.write_imu(
                i, t_ns[i:j], s.accel_counts[i:j], s.gyro_counts[i:j], s.temp_counts[i:j], int(host[i])
            )


# the arrays of a Session that are stored, in the raw files: name -> (dtype, shape per sample)
RAW = {
    "t_ns": ("<i8", ()),
    "sample_index": ("<i8", ()),
    "accel_counts": ("<i4", (3,)),
    "gyro_counts": ("<i4", (3,)),
    "temp_counts": ("<i4", ()),
    "host_time_ns": ("<i8", ()),
}


def raw_arrays(s: Session) -> dict[str, np.ndarray]:
    return {
        "t_ns": np.round(s.t_s * NS).astype(np.int64),
        "sample_index": s.sample_index.astype(np.int64),
        "accel_counts": s.accel_counts,
        "gyro_counts": s.gyro_counts,
        "temp_counts": s.temp_counts,
        "host_time_ns": np.round(s.host_time_s * NS).astype(np.int64),
    }


def read_raw_bin(path: Path, n: int) -> dict[str, np.ndarray]:
    """One readinto of the flat file, then zero-copy views (the cheapest way to get the arrays)."""
    buf = np.empty(path.stat().st_size, np.uint8)
    with open(path, "rb", buffering=0) as f:
        f.readinto(buf)
    out, pos = {}, 0
    for name, (dt, shape) in RAW.items():
        count = n * int(np.prod(shape, dtype=np.int64))
        out[name] = np.frombuffer(buf, dt, count, pos).reshape((n, *shape))
        pos += count * np.dtype(dt).itemsize
    return out


def convert(a: dict[str, np.ndarray]) -> tuple:
    """read_session's unit conversions: ns -> s, counts -> g, deg/s, degC."""
    return (
        a["t_ns"] / NS,
        a["accel_counts"] / 16384.0,
        a["gyro_counts"] / 131.0,
        temp_counts_to_degC(a["temp_counts"].astype(np.float64)),
        a["host_time_ns"] / NS,
    )


def decompress_floor(path: Path) -> Callable[[], None]:
    """Read the file and decompress every chunk (spans from mcap's summary, found once, untimed)."""
    import lz4.frame
    import zstandard
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        spans = []
        for ci in summary.chunk_indexes:
            f.seek(ci.chunk_start_offset + 9 + 28)
            name_len = int.from_bytes(f.read(4), "little")
            start = ci.chunk_start_offset + 9 + 32 + name_len + 8
            spans.append((start, start + ci.compressed_size, ci.uncompressed_size, ci.compression))

    def run() -> None:  # the file mapped as read_session maps it (no copy)
        with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            data = memoryview(mm)
            dctx = zstandard.ZstdDecompressor()
            for a, b, u, comp in spans:
                if comp == "zstd":
                    dctx.decompress(data[a:b], max_output_size=u)
                elif comp == "lz4":
                    lz4.frame.decompress(data[a:b])
            data.release()

    return run


def timed(fn: Callable[[], object]) -> tuple[float, float]:
    """(wall s, CPU s of the whole process: every thread) of one call."""
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def peak_mb(fn: Callable[[], object]) -> float:
    """Peak traced memory (MB) of one call: what it allocates, not the mapped file."""
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


def load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def stream_all(path: Path) -> int:
    """The streamed reader (iter_imu) over the whole file: every block handed out (the samples
    read_session returns, in blocks of one chunk group), nothing kept."""
    return sum(b.n for b in iter_imu(path))


def generic_read(path: Path) -> Session:
    reader.FAST_READ = False
    try:
        return read_session(path)
    finally:
        reader.FAST_READ = True


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-generic", action="store_true", help="skip the (slow) generic-reader rows")
    ap.add_argument("--dir", type=Path, help="keep the generated files here and reuse them")
    args = ap.parse_args()
    n = int(args.minutes * 60 * 1000)
    s = simulate(n)
    rows: list[tuple[str, Callable[[], object], Path | list[Path], float]] = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) if args.dir is None else args.dir / f"{args.minutes:g}min"
        d.mkdir(parents=True, exist_ok=True)
        arrays = raw_arrays(s)
        raw_bin = d / "raw.bin"
        with open(raw_bin, "wb") as f:
            for name in RAW:
                f.write(np.ascontiguousarray(arrays[name]).tobytes())
        npys = [d / f"{name}.npy" for name in RAW]
        for name, p in zip(RAW, npys, strict=True):
            np.save(p, arrays[name])

        files: dict[str, tuple[Path, float]] = {}
        for key, writer in (
            ("rec", lambda p: write_recorder_layout(p, s, "lz4")),
            ("rec_zstd", lambda p: write_recorder_layout(p, s, "zstd")),
            ("rec_vary", lambda p: write_recorder_layout(p, s, "lz4", vary=True)),
            ("rec_vary_zstd", lambda p: write_recorder_layout(p, s, "zstd", vary=True)),
            ("ws", lambda p: write_session(p, s, compression="lz4")),
            ("ws_zstd", lambda p: write_session(p, s, compression="zstd")),
        ):
            p = d / f"{key}.mcap"
            t0 = time.perf_counter()
            fresh = not p.exists()  # --dir: written once, then reused (write time not measured)
            if fresh:
                writer(p)
            files[key] = (p, time.perf_counter() - t0 if fresh else float("nan"))
            r = read_session(p)
            blocks = list(iter_imu(p))  # the streamed reader hands out the same samples
            for name in ("t_s", "sample_index", "accel_g", "gyro_dps", "temp_degC", "host_time_s"):
                assert np.array_equal(np.concatenate([getattr(b, name) for b in blocks]), getattr(r, name))
            del blocks
            for name, a in raw_arrays(r).items():
                want = arrays[name]
                if key.startswith("rec") and name == "host_time_ns":  # one host time per read
                    want = stored_host_ns(s, key.startswith("rec_vary"))
                assert np.array_equal(a, want), (key, name)
            del r

        rows += [
            ("raw binary (1 flat .bin, readinto)", lambda: read_raw_bin(raw_bin, n), raw_bin, float("nan")),
            (
                "raw binary + the same conversions",
                lambda: convert(read_raw_bin(raw_bin, n)),
                raw_bin,
                float("nan"),
            ),
            ("raw .npy (np.load per array)", lambda: [np.load(p) for p in npys], npys, float("nan")),
        ]
        mark = {c: " (default)" if c == DEFAULT_COMPRESSION else "" for c in ("lz4", "zstd")}
        labels = {
            "rec": f"MCAP recorder 36/msg, lz4{mark['lz4']}",
            "rec_zstd": f"MCAP recorder 36/msg, zstd{mark['zstd']}",
            "rec_vary": f"MCAP recorder 30-42/msg (varying reads), lz4{mark['lz4']}",
            "rec_vary_zstd": f"MCAP recorder 30-42/msg (varying reads), zstd{mark['zstd']}",
            "ws": f"MCAP write_session, 1 MiB lz4 chunks{mark['lz4']}",
            "ws_zstd": f"MCAP write_session, 1 MiB zstd chunks{mark['zstd']}",
        }
        for key, (p, tw) in files.items():
            rows.append((labels[key] + ": read_session", lambda p=p: read_session(p), p, tw))
            rows.append(
                (f"  streamed ({key}): iter_imu, every block", lambda p=p: stream_all(p), p, float("nan"))
            )
            rows.append(
                (f"  floor ({key}): map file + decompress only", decompress_floor(p), p, float("nan"))
            )

        best = {name: float("inf") for name, *_ in rows}
        best_cpu = dict(best)
        walls: dict[str, list[float]] = {name: [] for name, *_ in rows}
        load_before = load()
        for fn in (r[1] for r in rows):  # warm the page cache and every code path
            fn()
        for _ in range(args.repeat):
            for name, fn, _, _ in rows:
                wall, cpu = timed(fn)
                walls[name].append(wall)
                best[name] = min(best[name], wall)
                best_cpu[name] = min(best_cpu[name], cpu)
        load_after = load()
        median = {name: float(np.median(w)) for name, w in walls.items()}
        peak = {name: peak_mb(fn) for name, fn, _, _ in rows}
        generic: dict[str, float] = {}
        if not args.no_generic:
            for key in ("rec", "rec_zstd", "ws_zstd"):
                t0 = time.perf_counter()
                generic_read(files[key][0])
                generic[key] = time.perf_counter() - t0

        def size(p: Path | list[Path]) -> float:
            return sum(q.stat().st_size for q in (p if isinstance(p, list) else [p])) / 1e6

        sizes = {name: size(p) for name, _, p, _ in rows}
        file_mb = {key: size(p) for key, (p, _) in files.items()}

    t_raw = best["raw binary (1 flat .bin, readinto)"]
    t_rawc = best["raw binary + the same conversions"]
    floor_of = {
        labels[key] + ": read_session": f"  floor ({key}): map file + decompress only" for key in files
    } | {
        f"  streamed ({key}): iter_imu, every block": f"  floor ({key}): map file + decompress only"
        for key in files
    }
    print(
        f"read-back of {args.minutes:g} min at 1 kHz = {n:,} samples (accel+gyro+temp counts, t_ns, "
        f"sample index, host time); best of {args.repeat}; {load_before} before, {load_after} after"
    )
    head = (
        f"{'variant':<60} {'wall s':>7} {'CPU s':>7} {'vs raw':>7} {'vs raw+conv':>11} "
        f"{'vs floor wall':>13} {'CPU':>5} {'med':>5} {'peak MB':>8} {'size MB':>8} {'write s':>8}"
    )
    print(head)
    print("-" * len(head))
    for name, _, _, tw in rows:
        t, c = best[name], best_cpu[name]
        fl = floor_of.get(name)
        vs_floor = (
            f"{t / best[fl]:13.2f} {c / best_cpu[fl]:5.2f} {median[name] / median[fl]:5.2f}"
            if fl
            else f"{'':13} {'':5} {'':5}"
        )
        print(
            f"{name:<60} {t:7.3f} {c:7.3f} {t / t_raw:7.2f} {t / t_rawc:11.2f} {vs_floor} "
            f"{peak[name]:8.1f} {sizes[name]:8.1f} {tw:8.2f}"
        )
    conv = t_rawc - t_raw
    lz4_floor = best[floor_of[labels["ws"] + ": read_session"]]
    print(
        f"the unit conversions alone (raw + conversions less raw): {conv:.3f} s wall, "
        f"{conv / lz4_floor:.2f}x the write_session lz4 floor"
    )
    for key, t in generic.items():
        name = labels[key] + ": generic reader (before), 1 run"
        print(f"{name:<60} {t:7.3f} {'':7} {t / t_raw:7.2f} {t / t_rawc:11.2f} {'':36} {file_mb[key]:8.1f}")


if __name__ == "__main__":
    main()
