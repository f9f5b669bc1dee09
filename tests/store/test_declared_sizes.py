"""An MCAP chunk that declares a huge uncompressed size (issue 46: 1.8 GB, in its header and in its
chunk index alike) is read within a small memory budget, for every compression: the declared size is
never allocated."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from support.sessions import synth_session

from accellog.store.writer import write_session

HUGE = 1_800_000_000
BUDGET_KB = 500 * 1024
CHUNK, CHUNK_INDEX, FOOTER = 0x06, 0x08, 0x02


def declare_huge(data: bytes, which: int = 1) -> bytes:
    """The file with chunk number `which` (0-based) declaring HUGE uncompressed bytes, header and index."""
    d = bytearray(data)
    i, n, target = 8, 0, None
    while i < len(d) - 8:
        op, length = d[i], struct.unpack_from("<Q", d, i + 1)[0]
        body = i + 9
        if op == CHUNK:
            if n == which:
                target = i
                struct.pack_into("<Q", d, body + 16, HUGE)  # after message start/end times
            n += 1
        elif op == CHUNK_INDEX and struct.unpack_from("<Q", d, body + 16)[0] == target:
            p = body + 32  # after start/end times, chunk offset and length
            p += 4 + struct.unpack_from("<I", d, p)[0] + 8  # message index offsets, their length
            p += 4 + struct.unpack_from("<I", d, p)[0] + 8  # compression, compressed size
            struct.pack_into("<Q", d, p, HUGE)
        elif op == FOOTER and i > 8:
            break
        i = body + length
    assert target is not None
    return bytes(d)


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_a_chunk_declaring_1_8_GB_costs_no_memory(compression, tmp_path):
    s = synth_session(seed=4, hold_s=5.0, move_s=1.0, rate_hz=100.0)
    good = write_session(tmp_path / "good.mcap", s, chunk_size=8 * 1024, compression=compression)
    bad = tmp_path / "huge.mcap"
    bad.write_bytes(declare_huge(good.read_bytes()))
    code = (
        "import sys; from accellog.cli import main; rc = main(['segment', sys.argv[1]]); "
        "hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0].split()[1]; "
        "print(rc, hwm)"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    r = subprocess.run(
        [sys.executable, "-c", code, str(bad)], capture_output=True, text=True, env=env, timeout=120
    )
    rc, hwm_kb = map(int, r.stdout.split()[-2:])
    assert "Traceback" not in r.stderr, r.stderr
    assert hwm_kb < BUDGET_KB, f"peak {hwm_kb / 1024:.0f} MB"
    assert rc == 0 or r.stderr.strip().splitlines()[-1].startswith("accellog: error: "), r.stderr
