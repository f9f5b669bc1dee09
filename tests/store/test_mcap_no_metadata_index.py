"""A session written by the official mcap Writer without a metadata index (``index_types`` without
METADATA, or no indexes at all) reads, streams, lists its labels and fits exactly like the same
session written with the index, in the fast and in the generic reader: the session record is found
by walking the records between the chunks (store.mcap.records)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import IndexType, Writer

from accellog.cli import main
from accellog.flows.simulate import Scenario, simulate
from accellog.store import reader
from accellog.store.mcap.records import metadata_between_chunks, scanned_metadata
from accellog.store.stream import iter_imu, read_labels

NO_METADATA_INDEX = IndexType.ALL & ~IndexType.METADATA


def rewrite(src, dst, *, late: bool = False, **writer_options) -> None:
    """Every record of src written again by mcap's Writer(**writer_options); late: the session
    metadata record after the messages (between the last chunks) instead of before them."""
    with open(src, "rb") as f, open(dst, "wb") as g:
        r = make_reader(f)
        metas = list(r.iter_metadata())
        w = Writer(g, chunk_size=4096, **writer_options)  # small chunks: many records between them
        w.start(profile="", library="rewritten by mcap")
        if not late:
            for m in metas:
                w.add_metadata(m.name, dict(m.metadata))
        w.add_metadata("other", {"accel_lsb_per_g": "1"})  # another record name: ignored
        sids, cids = {}, {}
        for sch, ch, msg in r.iter_messages(log_time_order=False):
            if sch.id not in sids:
                sids[sch.id] = w.register_schema(sch.name, sch.encoding, sch.data)
            if ch.id not in cids:
                cids[ch.id] = w.register_channel(
                    ch.topic, ch.message_encoding, sids[sch.id], dict(ch.metadata)
                )
            w.add_message(cids[ch.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)
        if late:
            for m in metas:
                w.add_metadata(m.name, dict(m.metadata))
        w.finish()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("nomi")
    src = d / "sim.mcap"
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0, seed=4), src)
    out = {}
    for name, kw in {
        "indexed": {},
        "no_metadata_index": {"index_types": NO_METADATA_INDEX},
        "late_no_metadata_index": {"index_types": NO_METADATA_INDEX, "late": True},
        "no_indexes": {"index_types": IndexType.NONE, "use_summary_offsets": False},
    }.items():
        out[name] = d / f"{name}.mcap"
        rewrite(src, out[name], **kw)
    return out


def test_the_files_have_no_metadata_index(files):
    for name in ("no_metadata_index", "late_no_metadata_index", "no_indexes"):
        with open(files[name], "rb") as f:
            r = make_reader(f)
            assert r.get_summary().metadata_indexes == []
            assert list(r.iter_metadata()) == []  # mcap's reader alone does not find the record
    names = [m.name for m in scanned_metadata(files["late_no_metadata_index"])]
    assert names == ["other", "session"]  # file order


def _same_session(a, b):
    assert a.meta == b.meta
    for key in ("t_s", "sample_index", "accel_g", "accel_counts", "gyro_dps", "temp_degC"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)
    assert a.poses == b.poses and a.events == b.events


@pytest.mark.parametrize("fast", [True, False])
@pytest.mark.parametrize("name", ["no_metadata_index", "late_no_metadata_index", "no_indexes"])
def test_reads_like_the_indexed_file(files, name, fast, monkeypatch):
    monkeypatch.setattr(reader, "FAST_READ", fast)
    want = reader.read_session(files["indexed"])
    assert want.meta.accel_lsb_per_g
    _same_session(reader.read_session(files[name]), want)
    assert read_labels(files[name]) == read_labels(files["indexed"])
    assert (
        reader.session_summary(files[name])["metadata"]
        == reader.session_summary(files["indexed"])["metadata"]
    )


@pytest.mark.parametrize("name", ["no_metadata_index", "no_indexes"])
def test_streams_like_the_indexed_file(files, name):
    def blocks(path):
        got = list(iter_imu(path))
        return (
            got[0].meta,
            np.concatenate([b.accel_g for b in got]),
            np.concatenate([b.gyro_dps for b in got]),
        )

    (m1, a1, g1), (m2, a2, g2) = blocks(files[name]), blocks(files["indexed"])
    assert m1 == m2
    np.testing.assert_array_equal(a1, a2)
    np.testing.assert_array_equal(g1, g2)


def test_fits_like_the_indexed_file(files, tmp_path):
    def fitted(name):
        out = tmp_path / f"{name}.json"
        assert main(["fit", str(files[name]), "-o", str(out)]) in (0, None)
        cal = json.loads(out.read_text())
        cal.pop("created_utc", None)
        cal.pop("sources", None)
        return cal

    want = fitted("indexed")
    assert fitted("no_metadata_index") == want


def test_walk_refuses_a_broken_chain(files):
    data = bytearray(files["no_metadata_index"].read_bytes())
    start = int.from_bytes(data[-8 - 29 + 9 : -8 - 29 + 17], "little")
    assert len(metadata_between_chunks(data, start)) == 2
    first = metadata_between_chunks(data, start)[0]
    data[first] = 0x7F  # not a data-section opcode
    with pytest.raises(ValueError, match="record 0x7f"):
        metadata_between_chunks(data, start)
