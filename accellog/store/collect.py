"""The generic MCAP reader: mcap's SeekingReader + ``BatchDecoder`` per topic, and salvage of unfinished files.

``recover`` scans an unfinished file front to back and keeps every complete chunk (all or nothing per
chunk). The fast reader (accellog.store.fastread) falls back here on anything outside the canonical
layout; both give identical results where both apply.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from accellog.core.errors import InputError
from accellog.store.batch_decode import DecodedBatch
from accellog.store.codec import BatchDecoder
from accellog.store.layout import MCAP_MAGIC
from accellog.store.schema import MESSAGE_DEFS, PACKAGE

# ---------------------------------------------------------------------------------------------
# reader


Decoder = BatchDecoder | DecodedBatch  # n_messages and result() (arrays, scalars, counts)


@dataclasses.dataclass
class Collected:
    metadata: dict[str, str]
    topics: dict[str, str]  # topic -> schema name
    decoders: dict[str, Decoder]
    recovered: str | None  # None: finished file; else what was salvaged


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


class _Sink:
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
        self.n_messages += 1
        if self.want is not None and channel.topic not in self.want:
            return
        dec = self.decoders.get(channel.topic)
        if dec is None:
            msg = self.channel(schema, channel)
            if msg is None:
                return
            dec = self.decoders[channel.topic] = BatchDecoder(msg)
        dec.add(data)


def generic_collect(path: Path, topics: Iterable[str] | None = None) -> Collected:
    """``_collect`` with mcap's SeekingReader and one ``BatchDecoder.add`` per message."""
    sink = _Sink(topics)
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                raise McapError("no summary section")
            for sch, ch, msg in reader.iter_messages(topics=topics, log_time_order=False):
                sink.add(sch, ch, msg.data)
            for md in reader.iter_metadata():
                if md.name == "session":
                    sink.metadata = dict(md.metadata)
            for ch in summary.channels.values():
                sink.channel(summary.schemas.get(ch.schema_id), ch)
        return Collected(sink.metadata, sink.topics, sink.decoders, None)
    except (McapError, EOFError, ValueError, OSError, IndexError, KeyError) as exc:
        fast_error = exc
    return recover(path, topics, fast_error)


def recover(path: Path, topics: Iterable[str] | None, why: Exception) -> Collected:
    """Scan the file front to back and keep every complete chunk (all-or-nothing per chunk)."""
    sink = _Sink(topics)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    n_chunks = 0
    stop = ""

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
            for rec in StreamReader(f, emit_chunks=True).records:
                if isinstance(rec, Chunk):
                    inner = breakup_chunk(rec, validate_crc=True)  # whole chunk or nothing
                    for r in inner:
                        handle(r)
                    n_chunks += 1
                else:
                    handle(rec)
        except Exception as exc:  # anything unreadable ends the salvage: keep what is complete
            stop = f"{type(exc).__name__} at byte {f.tell()}"
    size = path.stat().st_size
    detail = (
        f"file was not finished ({type(why).__name__}: {why}); salvaged {sink.n_messages} messages "
        f"in {n_chunks} chunks of {size} bytes; reading stopped: {stop or 'end of data'}"
    )
    return Collected(sink.metadata, sink.topics, sink.decoders, detail)
