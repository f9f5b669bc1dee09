"""The static intervals a detector found in an unlabelled session, drawn on the sensor timeline.

- ``/detect/still``   1 inside a detected interval, 0 outside (step series over the session, s),
  drawn over every sample-stream plot (role 'detected')
- ``/detect/log``     TextLog at each interval start: start, end (s), samples n, threshold factor
- ``/docs/detected``  the intervals as a table, with the detector window and threshold
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from accellog.calibrate.observe.detected_holds import Detection


def _threshold(det: Detection) -> str:
    return "swept 2..10" if det.threshold is None else f"{det.threshold:g}"


def still_steps(det: Detection) -> tuple[np.ndarray, np.ndarray]:
    """(t_s, 0/1) of the 'still' step signal: 1 from each interval's start, 0 from its end."""
    t, v = [], []
    for iv in det.intervals:
        t += [iv["start_s"], iv["end_s"]]
        v += [1.0, 0.0]
    return np.asarray(t, dtype=np.float64), np.asarray(v, dtype=np.float64)


def log_detection(rec, det: Detection) -> None:
    """The detected intervals in a RunRecording: a still/moving step series on the timeline, one log
    line per interval and a table document."""
    if not det.intervals:
        return
    t, v = still_steps(det)
    rec.log_series(
        "detect/still",
        t,
        v[:, None],
        [f"detected still (threshold {_threshold(det)})"],
        step=True,
        role="detected",
    )
    md = [
        f"### Detected static intervals (window {det.window_s:g} s, threshold {_threshold(det)})\n",
        "| # | start (s) | end (s) | n | up (sensor) |",
        "|---|---|---|---|---|",
    ]
    for k, iv in enumerate(det.intervals):
        up = ", ".join(f"{x:+.2f}" for x in iv["up_sensor"])
        rec.log_text(
            "detect/log",
            iv["start_s"],
            f"interval {k}: {iv['start_s']:.2f}-{iv['end_s']:.2f} s, n {iv['n']}, threshold {_threshold(det)}",
        )
        md.append(f"| {k} | {iv['start_s']:.2f} | {iv['end_s']:.2f} | {iv['n']} | {up} |")
    rec.log_document("detected", "\n".join(md) + "\n")
