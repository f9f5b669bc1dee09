"""Streaming CSV reading: header/preamble detection, then byte blocks parsed by pyarrow (vectorised).

Memory is one block (``block_bytes`` of text, default 16 MB) plus its parsed columns, whatever the
file's length. Line numbers stay exact: a block knows its first line, and rows map to lines in O(1)
unless the block holds blank or comment lines (then a Python scan of that block, only when asked).
A block pyarrow refuses, or one with empty/non-finite cells, is re-read line by line in Python to name
the first bad line (``file:line``), so errors cost time only when there is an error; with
``bad_rows='skip'`` the bad lines are blanked and listed (``Block.skipped``) instead. ``read_ahead``
parses the next block on a second thread while the current one is written.
"""

from __future__ import annotations

import math
import queue
import re
import threading
from collections.abc import Generator, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.store.importers.csv_options import OPTIONAL_VALUES, CsvOptions
from accellog.store.importers.text import check_text_file

BLOCK_BYTES = 16 * 1024 * 1024
_HEAD_BYTES = 1 << 20
_RATE_RES = (
    re.compile(r"(\d+(?:\.\d+)?)\s*hz\b", re.IGNORECASE),
    re.compile(r"\b(?:rate|frequency|freq|fs|odr)\b\D{0,24}?(\d+(?:\.\d+)?)", re.IGNORECASE),
)


@dataclass
class Header:
    """The column header row and what precedes it (comments, a rate line)."""

    names: list[str]
    line: int
    """1-based line number of the header row."""
    data_offset: int
    """Byte offset of the line after the header."""
    preamble: list[str] = field(default_factory=list)
    rate_hz: float | None = None
    """Sample rate stated in the preamble ('# rate: 100 Hz', 'Sample rate,100'), if any."""


def _rate_in(lines: list[str]) -> float | None:
    for line in lines:
        for rx in _RATE_RES:
            m = rx.search(line)
            if m and float(m.group(1)) > 0:
                return float(m.group(1))
    return None


def read_header(path: Path, opts: CsvOptions) -> Header:
    """Find the header row: the first line that is not blank, not a comment and has >= 3 fields."""
    check_text_file(path)
    with open(path, "rb") as f:
        head = f.read(_HEAD_BYTES)
    bom = 3 if head.startswith(b"\xef\xbb\xbf") else 0
    if not head[bom:].strip():
        raise InputError("empty file", where=str(path))
    offset, preamble = bom, []
    for no, raw in enumerate(head[bom:].splitlines(keepends=True), start=1):
        end = offset + len(raw)
        if not raw.endswith((b"\n", b"\r")) and len(head) == _HEAD_BYTES:
            break
        try:
            line = raw.decode("utf-8").strip()
        except UnicodeDecodeError:
            raise InputError("not a text (UTF-8) CSV file", where=f"{path}:{no}") from None
        offset = end
        if not line or (opts.comment and line.startswith(opts.comment)):
            preamble.append(line)
            continue
        fields = [c.strip().strip('"').strip() for c in line.split(opts.delimiter)]
        if len(fields) < 3:
            preamble.append(line)
            continue
        if all(_is_number(c) for c in fields if c):
            raise InputError(
                "no header row: the first data line holds only numbers; add a line naming the columns "
                "(e.g. t,ax,ay,az,gx,gy,gz) and map them with --columns",
                where=f"{path}:{no}",
            )
        return Header(fields, no, offset, preamble, _rate_in(preamble))
    raise InputError(
        f"no header row with 3 or more {opts.delimiter!r}-separated columns (check --delimiter)",
        where=str(path),
    )


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


@dataclass
class Block:
    """Parsed rows of one byte block: columns by accellog name, and the map from rows to file lines."""

    cols: dict[str, np.ndarray]
    n: int
    first_line: int
    text: bytes
    clean: bool
    comment: bytes
    skipped: list[tuple[int, str]] = field(default_factory=list)
    """Lines dropped with bad_rows='skip': (file line, why it is not a row)."""
    _lines: np.ndarray | None = None

    def line_of(self, row: int) -> int:
        """1-based file line of data row ``row`` of this block."""
        if self.clean:
            return self.first_line + row
        lines = self._line_numbers()
        return int(lines[row]) if row < lines.shape[0] else self.first_line

    def _line_numbers(self) -> np.ndarray:
        """File line of every data row of a block with blank or comment lines (made once)."""
        if self._lines is None:
            nos = [
                self.first_line + i
                for i, ln in enumerate(self.text.split(b"\n"))
                if ln.strip() and not (self.comment and ln.lstrip().startswith(self.comment))
            ]
            self._lines = np.asarray(nos, dtype=np.int64)
        return self._lines

    def rows_before(self, line: int) -> int:
        """How many data rows of this block lie on file lines before ``line``."""
        if self.clean:
            return max(min(line - self.first_line, self.n), 0)
        return int(np.searchsorted(self._line_numbers(), line))


class BlockReader:
    """Iterate over ``Block``s of a CSV whose header is ``header``; ``wanted`` maps accellog name ->
    file column; ``int_cols`` are parsed as int64 (e.g. nanosecond stamps), ``string_cols`` as str."""

    def __init__(
        self,
        path: Path,
        header: Header,
        opts: CsvOptions,
        wanted: dict[str, str],
        *,
        int_cols=(),
        string_cols=(),
        block_bytes: int = BLOCK_BYTES,
    ) -> None:
        self.path, self.header, self.opts, self.wanted = path, header, opts, wanted
        self.int_cols, self.string_cols = set(int_cols), set(string_cols)
        self.block_bytes = int(block_bytes)
        self._comment = opts.comment.encode() if opts.comment else b""

    def __iter__(self) -> Iterator[Block]:
        line = self.header.line + 1
        carry = b""
        with open(self.path, "rb") as f:
            f.seek(self.header.data_offset)
            while True:
                buf = f.read(self.block_bytes)
                data = carry + buf
                if buf:
                    cut = data.rfind(b"\n") + 1
                    if cut == 0:
                        carry = data
                        continue
                    data, carry = data[:cut], data[cut:]
                n_nl = data.count(b"\n")
                if data and not data.isspace():
                    yield self._parse(data, line, n_nl + (not data.endswith(b"\n")))
                line += n_nl
                if not buf:
                    return

    # -- one block ---------------------------------------------------------------------------------
    def _parse(self, data: bytes, first_line: int, n_lines: int) -> Block:
        """Parse one block of ``n_lines`` lines. Rows map to lines in O(1) ('clean') when pyarrow made
        one row of every line (no comment, blank or multi-line row); the scans for comments test the
        single comment byte first (memchr), since a two-byte search costs ~1 ns per byte."""
        import pyarrow as pa
        import pyarrow.csv as pacsv

        c = self._comment
        has_comment = bool(c) and c in data and (data.lstrip().startswith(c) or b"\n" + c in data)
        body = data
        if has_comment:
            body = b"\n".join(ln for ln in data.split(b"\n") if not ln.lstrip().startswith(c))
        types = {}
        for key, col in self.wanted.items():
            types[col] = (
                pa.string()
                if key in self.string_cols
                else pa.int64()
                if key in self.int_cols
                else pa.float64()
            )
        skip = self.opts.bad_rows == "skip"
        try:
            table = pacsv.read_csv(
                pa.BufferReader(body),
                read_options=pacsv.ReadOptions(column_names=self.header.names, encoding="utf8"),
                parse_options=pacsv.ParseOptions(delimiter=self.opts.delimiter),
                convert_options=pacsv.ConvertOptions(
                    column_types=types,
                    include_columns=list(types),
                    null_values=[""],
                    strings_can_be_null=False,
                    quoted_strings_can_be_null=False,
                ),
            )
        except (pa.ArrowInvalid, UnicodeDecodeError) as exc:
            if skip:
                return self._skip_bad_lines(data, first_line, n_lines, exc)
            self._diagnose(data, first_line)
            where = f"{self.path}:{first_line}"
            raise InputError(f"cannot parse CSV: {str(exc).splitlines()[0]}", where=where) from None
        cols: dict[str, np.ndarray] = {}
        bad = False
        for key, col in self.wanted.items():
            arr = table.column(col)
            if key in self.string_cols:
                cols[key] = arr.to_numpy(zero_copy_only=False).astype(object)
                continue
            null = arr.null_count > 0
            if null and key not in OPTIONAL_VALUES:
                bad = True
            values = arr.to_numpy(zero_copy_only=False)
            if key in self.int_cols:
                cols[key] = values.astype(np.int64, copy=False)
                continue
            values = np.asarray(values, dtype=np.float64)
            finite = values if not null else values[~np.isnan(values)]
            bad = bad or not np.isfinite(finite).all()
            cols[key] = values
        if bad and skip:
            return self._skip_bad_lines(data, first_line, n_lines, None)
        if bad:
            self._diagnose(data, first_line)
        clean = not has_comment and table.num_rows == n_lines
        return Block(cols, table.num_rows, first_line, data, clean, c)

    def _skip_bad_lines(self, data: bytes, first_line: int, n_lines: int, exc) -> Block:
        """The block parsed again with its bad lines blanked (their line numbers kept); each one is
        listed in Block.skipped. A failure no line explains is raised as without skipping."""
        lines = data.split(b"\n")
        skipped = []
        for k, raw in enumerate(lines):
            why = self._problem(raw)
            if why is not None:
                skipped.append((first_line + k, why))
                lines[k] = b""
        if not skipped:
            where = f"{self.path}:{first_line}"
            reason = "non-finite or empty values" if exc is None else str(exc).splitlines()[0]
            raise InputError(f"cannot parse CSV: {reason}", where=where)
        block = self._parse(b"\n".join(lines), first_line, n_lines)
        block.skipped = skipped + block.skipped
        return block

    def _problem(self, raw: bytes) -> str | None:
        """Why one line is not a data row (column count, empty or non-number cells, not UTF-8); None
        for a good row, a blank line or a comment."""
        names = self.header.names
        try:
            line = raw.decode("utf-8").strip()
        except UnicodeDecodeError:
            return "not UTF-8 text"
        if not line or (self.opts.comment and line.startswith(self.opts.comment)):
            return None
        parts = line.split(self.opts.delimiter)
        if len(parts) != len(names):
            return f"expected {len(names)} columns ({','.join(names)}), found {len(parts)}"
        for key, col in self.wanted.items():
            if key in self.string_cols:
                continue
            v = parts[names.index(col)].strip().strip('"')
            if v == "":
                if key in OPTIONAL_VALUES:
                    continue
                return f"empty value in column {col!r}"
            try:
                x = int(v) if key in self.int_cols else float(v)
            except ValueError:
                return f"column {col!r}: {v!r} is not {'an integer' if key in self.int_cols else 'a number'}"
            if not math.isfinite(x):
                return f"column {col!r}: {v!r} is not a finite number"
        return None

    def _diagnose(self, data: bytes, first_line: int) -> None:
        """Raise InputError at the first bad line of the block (column count, empty or non-number cells)."""
        for k, raw in enumerate(data.split(b"\n")):
            why = self._problem(raw)
            if why is not None:
                hint = (
                    "" if why.startswith("not UTF-8") else " (--bad-rows skip drops such rows, each an event)"
                )
                raise InputError(why + hint, where=f"{self.path}:{first_line + k}")


def read_ahead(items: Iterable, name: str = "read-ahead") -> Generator:
    """Yield ``items`` while a second thread already makes the next one (at most one ahead).

    The producer's exception is raised here, at its place in the sequence; leaving the loop early
    (break, an error, Ctrl-C) stops the producer before this generator returns. Used to parse the next
    CSV block (pyarrow and numpy release the GIL) while the current one is encoded, compressed and written.
    """
    slots = threading.Semaphore(2)  # items alive: the one the consumer holds and the one being made
    out: queue.SimpleQueue = queue.SimpleQueue()
    stop = threading.Event()
    end = object()

    def produce() -> None:
        it = iter(items)
        try:
            while True:
                while not slots.acquire(timeout=0.05):
                    if stop.is_set():
                        return
                if stop.is_set():
                    return
                item = next(it, end)
                out.put((item, None))
                if item is end:
                    return
        except BaseException as exc:  # handed to the consumer, raised there
            out.put((end, exc))
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                close()

    worker = threading.Thread(target=produce, name=name, daemon=True)
    worker.start()
    try:
        while True:
            item, exc = out.get()
            if exc is not None:
                raise exc
            if item is end:
                return
            yield item
            del item
            slots.release()
    finally:
        stop.set()
        worker.join()
