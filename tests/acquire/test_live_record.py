"""`accellog record --rerun save FILE`: the live view gets raw data, prompts, stillness and the
running calibration, and the MCAP recording is complete."""

from __future__ import annotations

from rerun.chunk import RrdReader

from accellog.cli import main
from accellog.store.reader import read_session


def _texts(rrd, entity: str) -> list[str]:
    out = []
    for c in RrdReader(str(rrd)).stream().filter(content=entity).to_chunks():
        b = c.to_record_batch()
        for name in b.schema.names:
            if name.endswith(":text"):
                out += [v[0] for v in b.column(name).to_pylist() if v]
    return out


def test_live_view_shows_prompts_and_running_calibration(tmp_path):
    mcap, rrd = tmp_path / "s.mcap", tmp_path / "live.rrd"
    rc = main(["record", "--sim", "--fast", "--hold", "2", "-o", str(mcap), "--rerun", f"save {rrd}"])
    assert rc == 0
    s = read_session(mcap)
    assert [p.name for p in s.poses] == ["+z", "-z", "+y", "-y", "+x", "-x"]
    assert s.lost_samples() == 0
    prompts = _texts(rrd, "/live/prompt")
    assert len(prompts) == 6 and "-x" in prompts[-1]
    cal = _texts(rrd, "/live/calibration")
    assert len(cal) == 6
    assert "running model1" in cal[0] and "model3: not yet determined" in cal[0]
    assert "running model3" in cal[-1] and "S_zy" in cal[-1]
