"""A gap in an imported stream is counted in the file, as the recorder counts its own: a CSV with
a time column and a ROS 2 bag (streamed and in memory) with 0.5 s missing at 100 Hz get one
Event('gap') at the sample after it, ~49 samples lost; a stream without gaps gets none."""

from __future__ import annotations

import dataclasses

import numpy as np
from support.ros2_bags import session_to_bag
from support.sessions import synth_session

from accellog.store.importers.csv import CsvOptions, import_csv, import_csv_to_mcap
from accellog.store.importers.ros2 import import_ros2
from accellog.store.importers.ros2_stream import import_ros2_to_mcap
from accellog.store.reader import read_session

RATE_HZ = 100.0


def _stamps(gap_after: int | None, n: int = 400) -> np.ndarray:
    t = np.arange(n) / RATE_HZ
    if gap_after is not None:
        t[gap_after + 1 :] += 0.5 - 1 / RATE_HZ  # 0.5 s from sample gap_after to the next
    return t


def _gaps(events) -> list:
    return [e for e in events if e.kind == "gap"]


def _check(events, gap_after: int | None) -> None:
    gaps = _gaps(events)
    if gap_after is None:
        assert gaps == []
        return
    (g,) = gaps
    assert g.sample_index == gap_after + 1 and g.lost_samples == 49, g
    assert abs(g.t_s - _stamps(gap_after)[gap_after + 1]) < 1e-6 and "0.5 s without samples" in g.detail


def test_csv_gap_is_an_event_in_the_session_and_the_file(tmp_path):
    for gap_after in (None, 150):
        t = _stamps(gap_after)
        rows = "\n".join(f"{x:.6f},0.01,0.02,1.0" for x in t)
        csv = tmp_path / f"log{gap_after}.csv"
        csv.write_text("t,ax,ay,az\n" + rows + "\n")
        opts = CsvOptions(check_units=False)
        _check(import_csv(csv, opts).events, gap_after)
        out = tmp_path / f"log{gap_after}.mcap"
        import_csv_to_mcap(csv, out, opts)
        _check(read_session(out).events, gap_after)


def test_ros2_gap_is_an_event_streamed_and_in_memory(tmp_path):
    base = synth_session(seed=1, hold_s=1.0, move_s=0.5, rate_hz=RATE_HZ)
    n = min(base.n, 400)
    for gap_after in (None, 150):
        s = dataclasses.replace(
            base,
            t_s=_stamps(gap_after, n),
            sample_index=np.arange(n),
            accel_g=base.accel_g[:n],
            gyro_dps=None if base.gyro_dps is None else base.gyro_dps[:n],
            temp_degC=None,
            poses=[],
            events=[],
        )
        bag = session_to_bag(s, tmp_path / f"bag{gap_after}")
        _check(import_ros2(bag).events, gap_after)
        out = tmp_path / f"streamed{gap_after}.mcap"
        facts = import_ros2_to_mcap(bag, out)
        assert facts is not None and facts["events"] == (0 if gap_after is None else 1)
        _check(read_session(out).events, gap_after)
