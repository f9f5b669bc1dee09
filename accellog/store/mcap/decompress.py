"""Decompression of a run of MCAP chunks into one reused buffer, for ``fastread``'s walk.

A group of small zstd chunks (recorder files: ~18 kB each) is decompressed by one call that keeps the
GIL released; larger or other chunks one by one straight into the buffer. Each chunk's header must
agree with its chunk index; a chunk that does not decompress, has the wrong size or fails its CRC is
left out and named (``Damage``).
"""

from __future__ import annotations

import lz4.frame
import numpy as np
import zstandard

from accellog.store.collect import Damage, crc32_holding_gil, release_pages
from accellog.store.mcap.index import Bytes, NotFast, header_agrees

SMALL_CHUNK = 128 << 10  # decompressed bytes of a chunk below which zstd chunks go a group at a time
PAD = 16  # zero bytes after the decompressed records (vectorised reads may look a few bytes ahead)


class GroupDecompressor:
    """Decompresses runs of chunks into one reused buffer (fresh memory per group would cost page faults);
    a chunk whose header disagrees with its index, that does not decompress, has the wrong size or
    fails its CRC (check_crcs) is left out and noted (a disagreeing header without a summary CRC:
    NotFast, the index itself may be the damage)."""

    def __init__(
        self,
        data: Bytes,
        idx,
        keep,
        verified: bool | None,
        damaged: list[Damage],
        slots: int,
        check_crcs: bool = True,
    ) -> None:
        self.data = data
        self.zstd = [zstandard.ZstdDecompressor() for _ in range(slots)]  # one per slot: not thread-safe
        self.group_zstd = "multi_decompress_to_buffer" in zstandard.backend_features  # C backend
        self.lz4 = lz4.frame.decompress
        self.bufs = [bytearray() for _ in range(slots)]
        self.verified = verified
        self.idx = idx
        self.keep = np.ones(idx.ci.shape[0], bool) if keep is None else keep
        self.damaged = damaged  # appended to (list.append is atomic)
        self.check_crcs = check_crcs  # False: the data section CRC vouches for the chunks (fastread)

    def _into(self, comp: bytes | bytearray, raw, dst: memoryview, slot: int) -> str | None:
        """Decompress one chunk's records into dst (zstd straight into it, no copy); None if they
        fill it exactly, else the reason why not."""
        u = len(dst)
        try:
            if comp == b"zstd":
                reader = self.zstd[slot].stream_reader(raw, read_across_frames=False)
                got = 0
                while got < u and (k := reader.readinto(dst[got:])):
                    got += k
                if got == u and reader.read(1):
                    return f"decompresses to more than {u} bytes"
            elif comp in (b"lz4", b""):
                out = self.lz4(raw) if comp == b"lz4" else raw
                got = len(out)
                if got == u:
                    dst[:] = out
            else:
                raise NotFast(f"compression {comp!r}")
        except NotFast:
            raise
        except Exception as exc:
            return f"does not decompress ({type(exc).__name__})"
        return None if got == u else f"decompresses to {got} bytes, not {u}"

    def records(self, g0: int, g1: int, slot: int = 0) -> tuple[bytearray, int, list[int]]:
        """(buffer, n, sizes): the sound records of chunks g0..g1 back to back in buffer[:n], then
        PAD zero bytes; sizes[k] is what chunk g0 + k contributed (0: damaged or not wanted).

        One buffer per slot: the others are filled (each on its thread) while one is decoded; the
        mapped pages of the group are dropped after (read once)."""
        sel = g0 + np.flatnonzero(self.keep[g0:g1])  # the wanted chunks (labels: a few of a group)
        tab = self.idx.rows(self.data, sel)
        cols = (tab.chunk_at, tab.chunk_len, tab.usize, tab.csize, tab.name_at, tab.name_len)
        index = list(zip(*(a.tolist() for a in cols), strict=True))  # what the headers must say
        total = sum(ix[2] for ix in index)
        if len(self.bufs[slot]) < total + PAD:
            self.bufs[slot] = bytearray((total + PAD) * 5 // 4)
        buf, data = self.bufs[slot], self.data
        out = memoryview(buf)
        sizes = [0] * (g1 - g0)
        pos = self._zstd_group(index, out, slot)
        if pos is not None:
            for j, ix in zip((sel - g0).tolist(), index, strict=True):
                sizes[j] = ix[2]
        else:
            pos = self._chunk_by_chunk(index, tab, sel - g0, out, sizes, slot)
        buf[pos : pos + PAD] = bytes(PAD)
        if sel.shape[0]:  # the pages read: the records and the chunk indexes (summary)
            release_pages(data, int(tab.rec_at.min()), int(tab.rec_end.max()))
            release_pages(data, int(tab.ci.min()), int((tab.ci + 64 + tab.map_len + tab.name_len).max()))
        return buf, pos, sizes

    def _zstd_group(self, index: list[tuple[int, ...]], out: memoryview, slot: int) -> int | None:
        """Bytes written to out if every chunk of the group is sound zstd, decompressed by one call that
        keeps the GIL released throughout (a call per chunk hands it back and forth with the decoder:
        ~200 round trips a group of recorder chunks, each up to the 5 ms switch interval). None if the
        chunks are large (a mean of SMALL_CHUNK or more), or if any chunk is not zstd, disagrees with
        its index, fails or has the wrong size or CRC: chunk by chunk then says which."""
        data = self.data
        if not self.group_zstd or not index or sum(ix[2] for ix in index) >= SMALL_CHUNK * len(index):
            return None  # large chunks (write_session's 1 MiB) go straight into out, a few calls a group
        crcs = []
        for ix in index:
            at, nl = ix[0], ix[5]
            crcs.append(header_agrees(data, *ix))
            if crcs[-1] is None or data[at + 41 : at + 41 + nl] != b"zstd":
                return None
        frames = np.array([(at + 49 + nl, csize) for at, _, _, csize, _, nl in index], np.uint64)
        usize = np.array([ix[2] for ix in index], np.uint64)
        spans: zstandard.BufferWithSegments | None = None
        try:
            # zstandard's stubs leave out mmap, which it takes as any buffer
            spans = zstandard.BufferWithSegments(data, frames.tobytes())  # type: ignore[arg-type]
            parts = self.zstd[slot].multi_decompress_to_buffer(
                spans, decompressed_sizes=usize.tobytes(), threads=1
            )
        except zstandard.ZstdError:
            return None
        finally:
            spans = None  # exports the mapped file until released (the walk unmaps it after)
        pos = 0
        for k, (crc, u) in enumerate(zip(crcs, usize.tolist(), strict=True)):
            part = parts[k]
            if len(part) != u:
                return None
            dst = out[pos : pos + u]
            # zstandard's stubs do not give BufferSegment the buffer protocol it has
            dst[:] = part  # type: ignore[call-overload]
            if crc and self.check_crcs and crc32_holding_gil(dst) != crc:
                return None
            pos += u
        return pos

    def _chunk_by_chunk(self, index, tab, at_in_group: np.ndarray, out: memoryview, sizes, slot: int) -> int:
        """The group's chunks decompressed one by one into out; damaged ones left out and named (sizes[j]:
        what chunk j of the group gave). Returns the bytes written."""
        data, mv = self.data, memoryview(self.data)  # released on return
        pos = 0
        why: str | None
        for k, (j, ix) in enumerate(zip(at_in_group.tolist(), index, strict=True)):
            at, _, u, csize, _, nl = ix
            crc = header_agrees(data, *ix)
            if crc is None:
                why = "chunk header disagrees with its index"
                if not self.verified:
                    raise NotFast(why)
            else:
                rec = at + 49 + nl
                dst = out[pos : pos + u]
                why = self._into(data[at + 41 : at + 41 + nl], mv[rec : rec + csize], dst, slot)
                if why is None and crc and self.check_crcs and crc32_holding_gil(dst) != crc:
                    why = "CRC mismatch"
            if why is not None:
                self.damaged.append(Damage(at, int(tab.t_first[k]), int(tab.t_last[k]), why))
                continue
            pos += u
            sizes[j] = u
        return pos
