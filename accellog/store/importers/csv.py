"""Any logger's CSV -> Session (``import_csv``) or straight to MCAP in bounded memory (``import_csv_to_mcap``).

A header row names the columns; accellog's names (t, ax, ay, az, temp, gx, gy, gz, pose, true_x..z,
qw..qz) are mapped onto the file's with ``CsvOptions.columns``. Units and conversions are in
``accellog.store.importers.csv_options``; the source units, offsets and conversions are recorded in
meta.extra. The file is parsed in byte blocks (``csv_blocks``), converted and checked block by block:
time must strictly increase (duplicates and backward steps are refused with their line), a file needs
two rows spanning a non-zero duration; a gyro read as deg/s that turns ~57x less than gravity does
between the file's rests is refused after its last row (rad/s: ``csv_checks.check_gyro_motion``).
``import_csv_to_mcap`` parses the next block on a second thread
while the current one is encoded, compressed and written (``read_ahead``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.core.plausible import GYRO_WINDOW_S, GravityTurns
from accellog.core.session import Event, Session, SessionMeta
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.store.atomic import AtomicOutput
from accellog.store.importers.csv_blocks import BLOCK_BYTES, Block, BlockReader, read_ahead, read_header
from accellog.store.importers.csv_checks import (
    check_accel,
    check_gyro,
    check_gyro_motion,
    check_offsets,
    check_rate,
    check_time_range,
)
from accellog.store.importers.csv_options import FIELDS, GROUPS, TIME_UNITS, CsvOptions
from accellog.store.importers.csv_poses import PoseRuns
from accellog.store.importers.door import GapEvents, check_increasing, check_samples

CSV_UNITS = ("g", "m/s^2", "counts")
_T_DIV = {"s": 1.0, "ms": 1e3, "us": 1e6, "ns": 1e9}
_HEAD_ROWS = 20_000
"""Rows used to judge units and the nominal rate (the first block's head)."""
_ABSOLUTE_CLOCK_S = 1e6
"""A first stamp beyond this many seconds is a wall clock: times are then counted from it."""


@dataclass
class Chunk:
    """Converted rows of one block (accellog units)."""

    first_index: int
    t_s: np.ndarray
    accel_g: np.ndarray
    accel_counts: np.ndarray | None = None
    gyro_dps: np.ndarray | None = None
    gyro_counts: np.ndarray | None = None
    temp_degC: np.ndarray | None = None


@dataclass
class CsvImport:
    """One CSV being imported: iterate ``chunks()``; afterwards ``meta`` and ``poses`` are final."""

    path: Path
    opts: CsvOptions
    block_bytes: int = BLOCK_BYTES
    meta: SessionMeta | None = None
    poses: list = field(default_factory=list)
    events: list = field(default_factory=list)
    """One Event('skipped_row') per row dropped with bad_rows='skip' (its file line and why), one
    Event('gap') per gap in the time column (door.GapEvents), in time order."""
    n: int = 0

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        self.header = read_header(self.path, self.opts)
        self.cols = self._resolve()
        self.rate_hz = self._rate()
        strings = ("pose",) if "pose" in self.cols else ()
        ints = ("t",) if "t" in self.cols and self.opts.time_unit == "ns" else ()
        self.reader = BlockReader(
            self.path,
            self.header,
            self.opts,
            self.cols,
            int_cols=ints,
            string_cols=strings,
            block_bytes=self.block_bytes,
        )

    # -- header ------------------------------------------------------------------------------------
    def _resolve(self) -> dict[str, str]:
        names, o, where = self.header.names, self.opts, f"{self.path}:{self.header.line}"
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise InputError(f"duplicate column(s) {', '.join(dup)}", where=where)
        bad = [f"{k}={v}" for k, v in o.columns.items() if v not in names]
        if bad:
            raise InputError(
                f"--columns {','.join(bad)}: no such column in the header {','.join(names)}", where=where
            )
        cols = {k: o.column(k) for k in FIELDS if o.column(k) in names}
        missing = [c for c in ("ax", "ay", "az") if c not in cols]
        if "t" not in cols and not (o.rate_hz or self.header.rate_hz):
            missing.append("t")
        if missing:
            hint = ", ".join(f"{c}=NAME" for c in missing)
            also = " or give the sample rate with --rate HZ" if "t" in missing else ""
            raise InputError(
                f"missing column(s) {', '.join(missing)} in the header {','.join(names)!r}: "
                f"map them with --columns {hint}{also}",
                where=where,
            )
        for group in GROUPS:
            present = [c for c in group if c in cols]
            if present and len(present) != len(group):
                raise InputError(f"columns {', '.join(group)} must be given together", where=where)
        if "t" in cols and o.rate_hz:
            raise InputError(
                f"--rate is for files without a time column, and column {cols['t']!r} holds the time: "
                "drop --rate (or map the time column away with --columns)",
                where=where,
            )
        return cols

    def _rate(self) -> float | None:
        if "t" in self.cols:
            return None
        rate = self.opts.rate_hz or self.header.rate_hz
        assert rate, "_resolve refuses a file without time column or rate"
        return float(rate)

    # -- blocks ------------------------------------------------------------------------------------
    def chunks(self) -> Iterator[Chunk]:
        """Converted blocks; raises InputError (file:line) on the first bad row."""
        runs = PoseRuns(self.path) if "pose" in self.cols else None
        turns: GravityTurns | None = None
        t_prev = t0 = None
        t_first_s = dt_s = 0.0
        gaps = GapEvents()
        for block in self.reader:
            if block.n == 0:  # every line of the block skipped
                self._skipped(block, np.empty(0), t_prev)
                continue
            t_s, t0 = self._time(block, t0)
            if self.opts.strict_time and (t_prev is not None or block.n > 1):
                self._check_time(block, t_s, t_prev)
            if "t" in self.cols:
                check_time_range(self.path, block.cols["t"], t_s, block.line_of)
                gaps.add(t_s)
            if self.meta is None:
                t_first_s = float(t_s[0])
                head = t_s[:_HEAD_ROWS]
                dt_s = float(np.median(np.diff(head))) if head.shape[0] > 1 else 0.0
                self._check_units(block, dt_s)
                self.meta = self._meta(t0, dt_s)
                if "gx" in self.cols and self.opts.check_units and dt_s > 0:
                    turns = GravityTurns(round(GYRO_WINDOW_S / dt_s))
            if runs is not None:
                true = _stack(block, ("true_x", "true_y", "true_z"))
                quat = _stack(block, ("qw", "qx", "qy", "qz"))
                runs.feed(block.cols["pose"], t_s, true, quat, block.line_of)
            self._skipped(block, t_s, t_prev)
            ch = self._convert(block, t_s)
            check_samples(ch.accel_g, ch.gyro_dps, lambda i, b=block: f"{self.path}:{b.line_of(i)}")
            if turns is not None and ch.gyro_dps is not None:
                turns.feed(ch.t_s, ch.accel_g, ch.gyro_dps)
            n, t_prev = block.n, (float(t_s[-1]), block.line_of(block.n - 1))
            del block, t_s  # what the chunk does not use is freed before the chunk waits to be written
            yield ch
            del ch  # the consumer's, not kept while the next block is parsed (read_ahead)
            self.n += n
        if self.n == 0 or t_prev is None:
            raise InputError("no data rows", where=str(self.path))
        if self.n < 2 or (self.opts.strict_time and t_prev[0] <= t_first_s):
            raise InputError(
                f"only {self.n} row(s) spanning {t_prev[0] - t_first_s:g} s: a recording needs at least two "
                "samples at distinct times",
                where=str(self.path),
            )
        if turns is not None:
            turns.finish()
            check_gyro_motion(self.path, turns, self.opts)
        self.events = sorted([*self.events, *gaps.events], key=lambda e: e.t_s)
        if runs is not None:
            dt = dt_s if dt_s > 0 else 0.0
            self.poses = runs.finish(t_prev[0] + dt)
            self.meta = self.session_meta().replace(protocol=",".join(p.name for p in self.poses))

    def session_meta(self) -> SessionMeta:
        """meta once chunks() has read the first rows."""
        if self.meta is None:
            raise RuntimeError("the CSV's metadata is known after its first rows")
        return self.meta

    def _skipped(self, block: Block, t_s: np.ndarray, prev) -> None:
        """An Event per skipped line of the block, at the time of the row before it (s)."""
        for line, why in block.skipped:
            i = block.rows_before(line)
            t = float(t_s[i - 1]) if i > 0 else (prev[0] if prev is not None else 0.0)
            detail = f"{self.path.name}:{line}: {why}; row skipped (--bad-rows skip)"
            self.events.append(Event(t, "skipped_row", detail, self.n + i, 1))

    def _time(self, block: Block, t0):
        """Block times in s since the session origin (row / rate without a time column)."""
        if self.rate_hz is not None:
            return (self.n + np.arange(block.n, dtype=np.float64)) / self.rate_hz, 0
        t = block.cols["t"]
        if t0 is None:
            first = t[0] / _T_DIV[self.opts.time_unit]
            t0 = t[0] if first > _ABSOLUTE_CLOCK_S else 0
        if t.dtype == np.int64:
            return (t - t0) / 1e9, t0
        return (t - t0) / _T_DIV[self.opts.time_unit] if t0 or self.opts.time_unit != "s" else t, t0

    def _check_time(self, block: Block, t_s: np.ndarray, prev) -> None:
        check_increasing(t_s, lambda i: f"{self.path}:{block.line_of(i)}", None if prev is None else prev[0])

    def _check_units(self, block: Block, dt_s: float) -> None:
        """Units and rate judged on the first rows (up to _HEAD_ROWS) of the file (csv_checks)."""
        o = self.opts
        if not o.check_units:
            return
        column = self.cols.get("t")
        t = block.cols.get("t")
        whole = t is not None and bool(np.all(t[:_HEAD_ROWS] == np.round(t[:_HEAD_ROWS])))
        header_rate = None if o.rate_hz else self.header.rate_hz
        check_rate(self.path, dt_s * _T_DIV[o.time_unit], o, column, header_rate, whole)
        raw = _stack_of(block, ("ax", "ay", "az"))[:_HEAD_ROWS]
        w = _stack(block, ("gx", "gy", "gz"))
        w = None if w is None else w[:_HEAD_ROWS]
        check_offsets(self.path, raw, w, o)
        check_accel(self.path, raw, o)
        if w is not None:
            check_gyro(self.path, w, o)

    def _meta(self, t0, dt_s: float) -> SessionMeta:
        o = self.opts
        extra = {"source_file": self.path.name, "source_unit": o.unit}
        if o.columns:
            extra["column_map"] = ",".join(f"{k}={v}" for k, v in o.columns.items())
        used = set(self.cols.values())
        ignored = [n for n in self.header.names if n not in used]
        if ignored:
            extra["ignored_columns"] = ",".join(ignored)
        if o.unit == "counts":
            off = f" - {o.count_offset:g})" if o.count_offset else ")"
            extra["conversion"] = f"accel_counts = (raw{off}; accel_g = accel_counts / {o.lsb_per_g:g}"
        elif o.unit == "m/s^2":
            extra["conversion"] = "accel_g = a_mps2 / 9.80665 (original: a_mps2 = accel_g * 9.80665)"
        if o.accel_scale != 1.0:
            before = extra.get("conversion", "accel_g = a_g").split(" (")[0]
            extra["accel_scale"] = f"{o.accel_scale:g}"
            extra["conversion"] = f"{before} * {o.accel_scale:g} (--accel-scale: a full-scale mismatch)"
        if "gx" in self.cols:
            extra["source_gyro_unit"] = o.gyro_unit
            if o.gyro_unit == "rad/s":
                extra["gyro_conversion"] = "gyro_dps = w_radps * 180 / pi"
            elif o.gyro_unit == "counts":
                off = f" - {o.gyro_offset:g})" if o.gyro_offset else ")"
                extra["gyro_conversion"] = (
                    f"gyro_counts = (raw{off}; gyro_dps = gyro_counts / {o.gyro_lsb_per_dps:g}"
                )
        if o.count_offset:
            extra["count_offset"] = f"{o.count_offset:g}"
        if o.count_offset or o.gyro_offset:
            extra["count_offset_columns"] = o.offset_columns()
        start_ns = 0
        if self.rate_hz is not None:
            src = "--rate" if o.rate_hz else f"header line: {self.header.rate_hz:g} Hz"
            extra["time_source"] = f"row / {self.rate_hz:g} Hz ({src}); no time column"
        else:
            extra["time_source"] = f"column {self.cols['t']!r} in {o.time_unit}"
            if t0:
                extra["time_origin"] = f"{t0} {o.time_unit} (first stamp; t_s counts from it)"
                t0_s = float(t0) / _T_DIV[o.time_unit]
                if 1e9 < t0_s < 5e9:  # a Unix time stamp
                    per = {"s": 10**9, "ms": 10**6, "us": 10**3, "ns": 1}[o.time_unit]
                    exact = float(t0).is_integer()
                    start_ns = int(t0) * per if exact else round(float(t0) * per)
        rate = self.rate_hz if self.rate_hz is not None else (1.0 / dt_s if dt_s > 0 else 0.0)
        return SessionMeta(
            source="import:csv",
            chip="unknown",
            accel_lsb_per_g=float(o.counts_lsb_per_g()) if o.unit == "counts" else None,
            gyro_lsb_per_dps=float(o.counts_lsb_per_dps())
            if o.gyro_unit == "counts" and "gx" in self.cols
            else None,
            sample_rate_hz=rate,
            start_time_unix_ns=start_ns,
            extra=extra,
        )

    def _convert(self, block: Block, t_s: np.ndarray) -> Chunk:
        o = self.opts
        raw = _stack_of(block, ("ax", "ay", "az"))
        ch = Chunk(self.n, t_s, raw)
        if o.unit == "counts":
            ch.accel_counts = _counts(self.path, block, raw, o.count_offset, "ax,ay,az")
            ch.accel_g = ch.accel_counts / o.counts_lsb_per_g()
        elif o.unit == "m/s^2":
            ch.accel_g = raw / STANDARD_GRAVITY_MPS2
        if o.accel_scale != 1.0:
            ch.accel_g = ch.accel_g * o.accel_scale
        if "gx" in self.cols:
            w = _stack_of(block, ("gx", "gy", "gz"))
            if o.gyro_unit == "counts":
                ch.gyro_counts = _counts(self.path, block, w, o.gyro_offset, "gx,gy,gz")
                ch.gyro_dps = ch.gyro_counts / o.counts_lsb_per_dps()
            else:
                ch.gyro_dps = np.rad2deg(w) if o.gyro_unit == "rad/s" else w
        if "temp" in self.cols:
            ch.temp_degC = block.cols["temp"]
        return ch


def _stack(block: Block, names) -> np.ndarray | None:
    """The (n, len(names)) columns, None when the block has not the first of them."""
    return _stack_of(block, names) if names[0] in block.cols else None


def _stack_of(block: Block, names) -> np.ndarray:
    """The (n, len(names)) columns (KeyError for one the block has not)."""
    return np.stack([block.cols[n] for n in names], 1)


def _counts(path: Path, block: Block, raw: np.ndarray, offset: float, what: str) -> np.ndarray:
    c = raw - offset
    frac = np.flatnonzero(np.any(c != np.round(c), axis=1) | np.any(np.abs(c) > 2**31 - 1, axis=1))
    if frac.size:
        raise InputError(
            f"counts expected but {what} are not integers", where=f"{path}:{block.line_of(int(frac[0]))}"
        )
    return c.astype(np.int32)


def _options(opts: CsvOptions | None, kw: dict) -> CsvOptions:
    if opts is not None and kw:
        raise TypeError("give either options or keyword options")
    return opts if opts is not None else CsvOptions.make(**kw)


def import_csv(path: str | Path, options: CsvOptions | None = None, **kw) -> Session:
    """Generic CSV -> in-memory Session (keywords as ``CsvOptions.make``: unit, lsb_per_g, columns, ...).

    For long files prefer ``import_csv_to_mcap``, whose memory does not grow with the file.
    """
    block_bytes = kw.pop("block_bytes", BLOCK_BYTES)
    imp = CsvImport(Path(path), _options(options, kw), block_bytes)
    parts = list(imp.chunks())

    def cat(name):
        arrs = [getattr(c, name) for c in parts]
        return None if arrs[0] is None else np.concatenate(arrs)

    return Session(
        meta=imp.session_meta(),
        t_s=cat("t_s"),
        sample_index=np.arange(imp.n, dtype=np.int64),
        accel_g=cat("accel_g"),
        accel_counts=cat("accel_counts"),
        gyro_dps=cat("gyro_dps"),
        gyro_counts=cat("gyro_counts"),
        temp_degC=cat("temp_degC"),
        poses=imp.poses,
        events=list(imp.events),
        path=str(path),
    )


@dataclass
class CsvImportResult:
    """What ``import_csv_to_mcap`` wrote."""

    input: str
    output: str
    source: str
    samples: int
    duration_s: float
    sample_rate_hz: float
    source_unit: str
    accel_storage: str
    gyro: bool
    poses: list[str]
    skipped_rows: list[str]
    extra: dict[str, str]

    def to_dict(self) -> dict:
        from dataclasses import asdict

        return asdict(self)


def import_csv_to_mcap(
    path: str | Path,
    out: str | Path,
    options: CsvOptions | None = None,
    *,
    batch_size: int = 500,
    block_bytes: int = BLOCK_BYTES,
    compression: str | None = None,
    overwrite: bool = True,
    progress=None,
) -> CsvImportResult:
    """Stream a CSV into an accellog MCAP (accellog.store.atomic: locked temp file, fsync, rename;
    nothing half-written on error, never over the CSV itself, nor over an existing file with
    overwrite=False).

    Memory: two blocks of text (``block_bytes``) and their columns (the block being written and the
    next one, parsed meanwhile on a second thread: ``read_ahead``), plus the MCAP chunk being built.
    progress(done_MB, total_MB): after every block (done counted in whole blocks read).
    """
    from accellog.store.writer import DEFAULT_COMPRESSION, SessionWriter

    path, out = Path(path), Path(out)
    imp = CsvImport(path, options or CsvOptions(), block_bytes)
    ao = AtomicOutput(out, inputs=(path,), what="output session", overwrite=overwrite)
    tmp = ao.begin()
    w = None
    t_first = t_last = 0.0
    size_mb = path.stat().st_size / 1e6 if progress is not None else 0.0
    chunks = read_ahead(imp.chunks(), "csv-parse")  # the next block is parsed while this one is written
    try:
        for k, ch in enumerate(chunks):
            if progress is not None:
                progress(min((k + 1) * block_bytes / 1e6, size_mb), size_mb)
            if w is None:
                w = SessionWriter(
                    tmp,
                    imp.session_meta(),
                    flush_interval_s=math.inf,
                    chunk_size=1024 * 1024,
                    compression=compression or DEFAULT_COMPRESSION,
                )
                t_first = float(ch.t_s[0])
            t_ns = np.round(ch.t_s * 1e9).astype(np.int64)
            for s in range(0, t_ns.shape[0], batch_size):
                e = s + batch_size
                w.write_imu(
                    ch.first_index + s,
                    t_ns[s:e],
                    accel_counts=None if ch.accel_counts is None else ch.accel_counts[s:e],
                    gyro_counts=None if ch.gyro_counts is None else ch.gyro_counts[s:e],
                    accel_g=ch.accel_g[s:e] if ch.accel_counts is None else None,
                    gyro_dps=ch.gyro_dps[s:e] if ch.gyro_dps is not None and ch.gyro_counts is None else None,
                    temp_degC=None if ch.temp_degC is None else ch.temp_degC[s:e],
                )
            t_last = float(ch.t_s[-1])
        if w is None:  # chunks() refuses a file without rows
            raise InputError("no data rows", where=str(path))
        for p in imp.poses:
            w.write_pose(p)
        for e in imp.events:
            w.write_event(e)
        w.update_meta(imp.session_meta())
        w.close()
    except BaseException:
        try:
            chunks.close()
            if w is not None and not w.closed:
                w.close()  # may fail again (a full disk): the temporary file goes all the same
        except Exception:
            pass
        finally:
            ao.abort()
        raise
    ao.commit()
    return _result(imp, path, out, t_last - t_first)


def _result(imp: CsvImport, path: Path, out: Path, duration_s: float) -> CsvImportResult:
    m = imp.session_meta()
    return CsvImportResult(
        input=str(path),
        output=str(out),
        source=m.source,
        samples=imp.n,
        duration_s=duration_s,
        sample_rate_hz=m.sample_rate_hz,
        source_unit=imp.opts.unit,
        accel_storage=f"counts ({m.accel_lsb_per_g:g} LSB/g)" if m.accel_lsb_per_g else "g (float64)",
        gyro=m.extra.get("source_gyro_unit") is not None,
        poses=[p.name for p in imp.poses],
        skipped_rows=[e.detail for e in imp.events if e.kind == "skipped_row"],
        extra=dict(m.extra),
    )


__all__ = [
    "CSV_UNITS",
    "TIME_UNITS",
    "CsvImport",
    "CsvImportResult",
    "CsvOptions",
    "import_csv",
    "import_csv_to_mcap",
]
