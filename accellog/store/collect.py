"""The generic MCAP reader: mcap's SeekingReader + ``BatchDecoder`` per topic, and salvage of unfinished files.

``recover`` scans an unfinished file front to back and keeps every complete chunk (all or nothing per
chunk). The fast reader (accellog.store.mcap.fastread) falls back here on anything outside the canonical
layout; both give identical results where both apply.

Corruption: every chunk's uncompressed CRC is checked (when the writer stored one); a chunk that
fails (CRC, decompression, size, or a header that disagrees with its chunk index) is skipped whole
and named in ``Collected.damaged`` (byte offset, log-time range, reason), never decoded. The data
section CRC (DataEnd) and the summary CRC (Footer) cover every other byte: a mismatch that no chunk
explains is reported as damage outside the chunks, and a damaged summary is not trusted (the file
is read by scanning its data section).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterable
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from accellog.core.errors import InputError
from accellog.store.codec import BatchDecoder
from accellog.store.layout import MCAP_MAGIC
from accellog.store.mcap.batch_decode import DecodedBatch
from accellog.store.mcap.records import scanned_metadata

try:  # ISA-L's CRC-32: the same polynomial and values as zlib.crc32, ~7x faster (PCLMUL); optional
    from isal.isal_zlib import crc32
except ImportError:  # pragma: no cover - the extra "fast" is not installed
    from zlib import crc32
from accellog.store.schema import MESSAGE_DEFS, PACKAGE

_GIL_PIECE = 4096  # bytes: ISA-L's and zlib's crc32 release the GIL above ~5 KiB, not below


def crc32_holding_gil(view: memoryview, crc: int = 0) -> int:
    """crc32 of a chunk-sized buffer in pieces that keep the GIL: a worker thread that released it
    for each chunk would wait for the decoder to hand it back (up to the 5 ms switch interval)."""
    for lo in range(0, len(view), _GIL_PIECE):
        crc = crc32(view[lo : lo + _GIL_PIECE], crc)
    return crc


# ---------------------------------------------------------------------------------------------
# reader


Decoder = BatchDecoder | DecodedBatch  # n_messages and result() (arrays, scalars, counts)


@dataclasses.dataclass(frozen=True)
class Damage:
    """A part of the file that failed its integrity check and was not decoded."""

    offset: int
    """Byte offset of the damaged record (a chunk) or region."""
    start_ns: int
    """Log time of the first message the damaged chunk held (ns; -1 if unknown)."""
    end_ns: int
    """Log time of its last message (ns; -1 if unknown)."""
    reason: str
    """What failed: 'CRC mismatch', 'does not decompress', ..."""
    chunk: bool = True
    """True: a whole chunk was skipped; False: damage outside the chunks (nothing skipped)."""

    def describe(self) -> str:
        if not self.chunk:
            return f"damaged bytes outside the chunks ({self.reason}) before byte {self.offset}"
        span = f"t {self.start_ns / 1e9:.3f}-{self.end_ns / 1e9:.3f} s" if self.start_ns >= 0 else "t unknown"
        return f"damaged chunk at byte {self.offset} ({span}): {self.reason}; skipped"


@dataclasses.dataclass
class Collected:
    metadata: dict[str, str]
    topics: dict[str, str]  # topic -> schema name
    decoders: dict[str, Decoder]
    recovered: str | None  # None: finished file; else what was salvaged
    damaged: list[Damage] = dataclasses.field(default_factory=list)


def chunk_records(chunk: Chunk, offset: int) -> list | Damage:
    """The records of one chunk after mcap's decompress-and-CRC check, or its Damage."""
    try:
        return breakup_chunk(chunk, validate_crc=True)
    except Exception as exc:  # CRC mismatch, bad frame, truncated record inside: the chunk is damaged
        reason = (
            "CRC mismatch" if "crc" in type(exc).__name__.lower() else f"unreadable ({type(exc).__name__})"
        )
        return Damage(offset, int(chunk.message_start_time), int(chunk.message_end_time), reason)


def stored_data_crc(data, summary_start: int) -> int:
    """The DataEnd record's CRC of the data section (every byte from the magic to that record); 0 if
    the writer stored none."""
    at = summary_start - 13  # DataEnd: opcode 0x0F, length 4, crc u32
    if at < 8 or data[at] != 0x0F or int.from_bytes(data[at + 1 : at + 9], "little") != 4:
        return 0
    return int.from_bytes(data[at + 9 : at + 13], "little")


def data_section_damage(data, summary_start: int) -> Damage | None:
    """Check the DataEnd CRC (every byte from the magic to the DataEnd record) when it was stored."""
    at, want = summary_start - 13, stored_data_crc(data, summary_start)
    if want == 0:
        return None
    got, mv, step = 0, memoryview(data), 4 << 20
    for lo in range(0, at, step):  # in pieces, dropping each piece's mapped pages behind us
        got = crc32(mv[lo : min(lo + step, at)], got)
        release_pages(data, lo, min(lo + step, at))
    mv.release()
    return None if got == want else Damage(at, -1, -1, "data section CRC mismatch", chunk=False)


FAULT_AROUND = 64 << 10
"""Bytes the kernel maps around a page fault of a file mapping (Linux fault_around_bytes: a window of
that size holding the faulting page, aligned on the virtual address, not on the file offset)."""


def release_pages(data, lo: int, hi: int) -> None:
    """Tell the kernel the mapped file bytes [lo, hi) are not needed any more (MADV_DONTNEED), so a
    pass over a long file keeps its resident memory bounded; a no-op for bytes objects.

    The range is widened by FAULT_AROUND on both sides: a read near an end of [lo, hi) also maps the
    cached pages of its fault-around window outside it (a chunk header, the message indexes between
    two chunk groups), which no later release covered (~20 MB resident after a 24 h pass).
    Advice only: a kernel that refuses it (EINVAL for the locked pages of an mlockall'd process)
    leaves the pages mapped."""
    import mmap

    if isinstance(data, mmap.mmap) and hasattr(mmap, "MADV_DONTNEED"):
        lo = max(lo - FAULT_AROUND, 0)
        lo -= lo % mmap.PAGESIZE
        hi = min(hi + FAULT_AROUND, len(data))
        if hi > lo:
            with contextlib.suppress(OSError):
                data.madvise(mmap.MADV_DONTNEED, lo, hi - lo)


def check_file(path: Path) -> None:
    if not path.is_file():
        raise InputError("no such file", where=str(path))
    try:
        with open(path, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", where=str(path)) from None
    if not head:
        raise InputError("empty file (0 bytes), not an MCAP session", where=str(path))
    if head != MCAP_MAGIC:
        raise InputError("not an MCAP file (bad magic bytes)", where=str(path))


class Sink:
    """Routes (schema, channel, data) of accellog topics into per-topic batch decoders."""

    def __init__(self, topics: Iterable[str] | None) -> None:
        self.want = None if topics is None else set(topics)
        self.topics: dict[str, str] = {}
        self.decoders: dict[str, Decoder] = {}
        self.metadata: dict[str, str] = {}
        self.n_messages = 0

    def channel(self, schema: Schema | None, channel: Channel) -> str | None:
        """Message type of the channel if it is an accellog.v1 protobuf channel, else None."""
        name = "" if schema is None else schema.name
        if schema is None or schema.encoding != "protobuf" or channel.message_encoding != "protobuf":
            self.topics.setdefault(channel.topic, f"{name or 'no schema'} as {channel.message_encoding}")
            return None
        self.topics.setdefault(channel.topic, name)
        msg = name[len(PACKAGE) + 1 :] if name.startswith(PACKAGE + ".") else ""
        return msg if msg in MESSAGE_DEFS else None

    def add(self, schema: Schema | None, channel: Channel, data: bytes) -> None:
        """Decode one message (a message that does not decode raises and is not counted)."""
        if self.want is None or channel.topic in self.want:
            dec = self._decoder(schema, channel)
            if dec is not None:
                dec.add(data)
        self.n_messages += 1

    def _decoder(self, schema: Schema | None, channel: Channel) -> BatchDecoder | None:
        dec = self.decoders.get(channel.topic)
        assert dec is None or isinstance(dec, BatchDecoder)  # DecodedBatch: the fast path's, never here
        if dec is None:
            msg = self.channel(schema, channel)
            if msg is not None:
                dec = self.decoders[channel.topic] = BatchDecoder(msg)
        return dec


def file_damage(path: Path) -> tuple[Exception | None, Damage | None]:
    """Summary and data-section CRC checks of a finished file: (an exception if the summary fails
    the footer's CRC, the data section's Damage if it fails the DataEnd CRC); (None, None) for an
    unfinished file (recover() decides) or CRCs the writer did not store."""
    import mmap

    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
        footer = len(data) - len(MCAP_MAGIC) - 29
        if footer < 8 or data[-len(MCAP_MAGIC) :] != MCAP_MAGIC or data[footer] != 0x02:
            return None, None
        start = int.from_bytes(data[footer + 9 : footer + 17], "little")
        if not 0 < start <= footer:
            return None, None
        want = int.from_bytes(data[footer + 25 : footer + 29], "little")
        if want and want != crc32(data[footer : footer + 25], crc32(memoryview(data)[start:footer])):
            return McapError("summary section CRC mismatch"), None
        return None, data_section_damage(data, start)


def generic_collect(path: Path, topics: Iterable[str] | None = None) -> Collected:
    """``_collect`` with mcap's SeekingReader and one ``BatchDecoder.add`` per message."""
    sink = Sink(topics)
    bad_summary, outside = file_damage(path)
    if bad_summary is not None:
        return recover(path, topics, bad_summary)
    try:
        with open(path, "rb") as f:
            reader = make_reader(f, validate_crcs=True)
            summary = reader.get_summary()
            if summary is None:
                raise McapError("no summary section")
            for sch, ch, msg in reader.iter_messages(topics=topics, log_time_order=False):
                sink.add(sch, ch, msg.data)
            # a summary without metadata index (another writer's choice): the records between chunks
            metas = reader.iter_metadata() if summary.metadata_indexes else scanned_metadata(path)
            for md in metas:
                if md.name == "session":
                    sink.metadata = dict(md.metadata)
            for ch in summary.channels.values():
                sink.channel(summary.schemas.get(ch.schema_id), ch)
        return Collected(sink.metadata, sink.topics, sink.decoders, None, [outside] if outside else [])
    except (McapError, EOFError, ValueError, OSError, IndexError, KeyError) as exc:
        fast_error: Exception = exc
    except Exception as exc:  # e.g. a damaged chunk that fails inside the decompressor
        fast_error = exc
    return recover(path, topics, fast_error)


class ZeroFilled(Exception):
    """The scan reached a record opcode that is not an MCAP record: 0 (zero-filled space) or one of
    no MCAP record type (garbage, or a private extension no accellog file has)."""

    def __init__(self, start: int, size: int, opcode: int = 0) -> None:
        what = "zero-filled space" if opcode == 0 else f"no MCAP record (opcode {opcode:#04x})"
        super().__init__(f"{what} at byte {start}; the last {(size - start) / 2**20:.1f} MiB not read")


_LAST_OPCODE = 0x0F  # DataEnd: MCAP's record opcodes are 0x01..0x0F


class _SalvageReader(StreamReader):
    """mcap's StreamReader for the salvaging scan, ending it (O(1)) at a record that is not an MCAP
    record: opcode 0 is zero-filled space (a preallocated or crash-damaged tail), above 0x0F garbage;
    both would otherwise be walked as empty records of 9 bytes, ~1 s per MiB, 2 GB for half an
    hour. A record length past the end of the file fails before anything is allocated for it."""

    def __init__(self, f, size: int) -> None:
        super().__init__(f, emit_chunks=True)
        self._f, self._size = f, size

    def _read_record(self, opcode: int, length: int):
        if not 1 <= opcode <= _LAST_OPCODE:
            raise ZeroFilled(self._f.tell() - 9, self._size, opcode)
        if length > self._size - self._f.tell():
            raise EOFError(
                f"a record at byte {self._f.tell() - 9} claims {length} bytes, past the end of the file"
            )
        return super()._read_record(opcode, length)


def recover(path: Path, topics: Iterable[str] | None, why: Exception) -> Collected:
    """Scan the file front to back and keep every sound chunk (all-or-nothing per chunk).

    A chunk that fails its CRC or does not decompress is skipped and named (Damage); the scan goes
    on past it (its record length is what the stream reader steps by). The scan stops at the first
    unreadable record (a truncated file): what came before is kept and the stop is described."""
    from mcap.records import DataEnd, Footer

    sink = Sink(topics)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    damaged: list[Damage] = []
    n_chunks = 0
    stop = ""
    finished = False
    data_end_at = -1

    def handle(rec) -> None:
        if isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            channels[rec.id] = rec
            sink.channel(schemas.get(rec.schema_id), rec)
        elif isinstance(rec, Message):
            ch = channels.get(rec.channel_id)
            if ch is not None:
                sink.add(schemas.get(ch.schema_id), ch, rec.data)
        elif isinstance(rec, Metadata) and rec.name == "session":
            sink.metadata = dict(rec.metadata)

    with open(path, "rb") as f:
        try:
            for rec in _SalvageReader(f, path.stat().st_size).records:
                if isinstance(rec, Chunk):
                    at = f.tell() - 9 - (40 + len(rec.compression.encode()) + len(rec.data))
                    inner = chunk_records(rec, at)
                    if isinstance(inner, Damage):
                        damaged.append(inner)
                        continue
                    for r in inner:
                        handle(r)
                    n_chunks += 1
                elif isinstance(rec, DataEnd):  # the data section is complete: the rest is indexes
                    data_end_at = f.tell() - 13
                    finished = True
                    break
                elif isinstance(rec, Footer):
                    finished = True
                else:
                    handle(rec)
        except ZeroFilled as exc:
            stop = str(exc)
        except Exception as exc:  # anything unreadable ends the salvage: keep what is complete
            stop = f"{type(exc).__name__} at byte {f.tell()}"
    if data_end_at > 0 and not damaged:
        import mmap

        with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            outside = data_section_damage(data, data_end_at + 13)
        if outside is not None:
            damaged.append(outside)
    size = path.stat().st_size
    with open(path, "rb") as f:
        f.seek(max(size - len(MCAP_MAGIC), 0))
        has_end = f.read() == MCAP_MAGIC
    detail: str | None
    if not has_end:
        detail = (
            f"file was not finished ({type(why).__name__}: {why}); salvaged {sink.n_messages} messages "
            f"in {n_chunks} chunks of {size} bytes; reading stopped: {stop or 'end of data'}"
        )
    elif finished and not stop:
        summary = f"summary unreadable ({type(why).__name__}: {why}); read by scanning the file"
        detail = None if damaged else summary
    else:  # a whole file whose data section cannot be walked to the end: damaged, not truncated
        detail = (
            f"damaged file: unreadable record ({stop or why}); salvaged {sink.n_messages} messages in "
            f"{n_chunks} chunks before it, of {size} bytes"
        )
    return Collected(sink.metadata, sink.topics, sink.decoders, detail, damaged)
