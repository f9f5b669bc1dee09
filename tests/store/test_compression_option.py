"""--compression of the commands that write sessions (record, simulate, import, apply): the chunks
are compressed as asked (zstd by default, the writer's default), the samples read back the same, an
unknown name is one line and no file."""

from __future__ import annotations

import numpy as np
from mcap.reader import make_reader

from accellog.cli import main
from accellog.flows.stages import run_fit
from accellog.store.reader import read_session
from accellog.store.writer import DEFAULT_COMPRESSION


def _chunk_compressions(path) -> set[str]:
    with open(path, "rb") as f:
        return {ci.compression for ci in make_reader(f).get_summary().chunk_indexes}


def _csv(path, n: int = 2000) -> None:
    rng = np.random.default_rng(5)
    acc = np.array([0.01, -0.02, 1.0]) + rng.normal(0, 0.003, (n, 3))
    rows = [f"{i / 1000:.3f},{a[0]:.6f},{a[1]:.6f},{a[2]:.6f}" for i, a in enumerate(acc)]
    path.write_text("t,ax,ay,az\n" + "\n".join(rows) + "\n")


def test_import_writes_the_compression_asked_for(tmp_path, capsys):
    src = tmp_path / "log.csv"
    _csv(src)
    read = {}
    for comp in (None, "lz4", "none"):
        out = tmp_path / f"{comp}.mcap"
        argv = ["import", "csv", str(src), "-o", str(out)] + ([] if comp is None else ["--compression", comp])
        assert main(argv) == 0, capsys.readouterr().err
        want = DEFAULT_COMPRESSION if comp is None else "" if comp == "none" else comp
        assert _chunk_compressions(out) == {want}
        read[comp] = read_session(out)
    assert DEFAULT_COMPRESSION == "zstd"
    for comp in ("lz4", "none"):
        assert np.array_equal(read[comp].accel_g, read[None].accel_g)
        assert np.array_equal(read[comp].t_s, read[None].t_s)


def test_unknown_compression_is_one_line_and_no_file(tmp_path, capsys):
    src, out = tmp_path / "log.csv", tmp_path / "o.mcap"
    _csv(src, 50)
    assert main(["import", "csv", str(src), "-o", str(out), "--compression", "brotli"]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'brotli'" in err and "lz4" in err and "Traceback" not in err
    assert not out.exists()
    assert main(["record", "--sim", "--fast", "-o", str(out), "--compression", "gzip"]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'gzip'" in err
    assert not out.exists()


def test_record_writes_the_compression_asked_for(tmp_path, capsys):
    out = tmp_path / "r.mcap"
    argv = ["record", "--sim", "--fast", "--protocol", "+z", "--hold", "1", "--no-mag", "-o", str(out)]
    assert main([*argv, "--compression", "lz4"]) == 0, capsys.readouterr().err
    assert _chunk_compressions(out) == {"lz4"}
    assert read_session(out).n > 900


def test_simulate_and_apply_write_the_compression_asked_for(tmp_path, capsys):
    sim, out, cal = tmp_path / "sim.mcap", tmp_path / "applied.mcap", tmp_path / "cal.json"
    assert main(["simulate", "--protocol", "six", "--hold", "2", "-o", str(sim), "--compression", "lz4"]) == 0
    assert _chunk_compressions(sim) == {"lz4"}
    run_fit(sim).cal.save(cal)
    assert main(["apply", str(sim), "--cal", str(cal), "-o", str(out), "--compression", "none"]) == 0
    assert _chunk_compressions(out) == {""}
    assert np.array_equal(read_session(out).accel_g, read_session(sim).accel_g)
    capsys.readouterr()
    bad = tmp_path / "bad.mcap"
    for argv in (
        ["apply", str(sim), "--cal", str(cal), "-o", str(bad), "--compression", "zip"],
        ["simulate", "--protocol", "six", "-o", str(bad), "--compression", "zip"],
    ):
        assert main(argv) != 0
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "'zip'" in err, err
        assert not bad.exists()


def _chunks(path) -> list[tuple[bytes, int]]:
    """(compressed bytes, uncompressed size) of every chunk of an MCAP file."""
    import struct

    out = []
    with open(path, "rb") as f:
        for ci in make_reader(f).get_summary().chunk_indexes:
            f.seek(ci.chunk_start_offset + 1 + 8 + 8 + 8 + 8 + 4)  # opcode, length, times, size, crc
            (n,) = struct.unpack("<I", f.read(4))
            f.seek(n, 1)  # the compression's name
            (size,) = struct.unpack("<Q", f.read(8))
            out.append((f.read(size), ci.uncompressed_size))
    return out


def test_zstd_chunks_are_written_at_the_writer_level_and_other_writers_keep_theirs(tmp_path, capsys):
    """accellog's chunks are zstd level ZSTD_LEVEL (mcap's Writer has no setting: store.writer), and
    an mcap Writer used directly in the same process still compresses at zstd's default level."""
    import zstandard
    from mcap.writer import Writer

    from accellog.store.zstd_level import ZSTD_LEVEL

    src, out = tmp_path / "log.csv", tmp_path / "s.mcap"
    _csv(src, n=20000)
    assert main(["import", "csv", str(src), "-o", str(out)]) == 0, capsys.readouterr().err
    sim, cal, applied = tmp_path / "sim.mcap", tmp_path / "cal.json", tmp_path / "applied.mcap"
    assert main(["simulate", "--protocol", "six", "--hold", "4", "-o", str(sim)]) == 0
    run_fit(sim).cal.save(cal)  # apply registers its derived channels after the first chunks
    assert main(["apply", str(sim), "--cal", str(cal), "-o", str(applied)]) == 0, capsys.readouterr().err
    assert ZSTD_LEVEL != 3
    for path in (out, sim, applied):
        for data, size in _chunks(path):
            raw = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
            assert data == zstandard.compress(raw, ZSTD_LEVEL), path.name

    plain = tmp_path / "plain.mcap"
    with open(plain, "wb") as f:
        w = Writer(f, chunk_size=4096)
        w.start()
        sid = w.register_schema("s", "jsonschema", b"{}")
        cid = w.register_channel("t", "json", sid)
        for i in range(2000):
            w.add_message(
                cid, log_time=i, publish_time=i, data=b'{"x": %d, "y": "%s"}' % (i, b"ab" * (i % 7))
            )
        w.finish()
    chunks = _chunks(plain)
    assert len(chunks) > 2
    for data, size in chunks:
        raw = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        assert data == zstandard.compress(raw)
