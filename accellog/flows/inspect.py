"""`replay` and `compare` of a session file: load it, open the sink (.rrd file or live viewer), run, close.

Session files are only read. .rrd files are written to a temporary name and renamed when complete.
"""

from __future__ import annotations

from pathlib import Path

from accellog.core.errors import InputError
from accellog.flows.replay import compare as compare_fn
from accellog.flows.replay import replay as replay_fn
from accellog.present.rrd.offload import open_recording
from accellog.store.source import open_source


def sink_option(rrd: Path | None, rerun: str | None) -> str | None:
    if rrd is not None and rerun is not None:
        raise InputError("give either --rrd FILE or --rerun spawn|connect URL, not both")
    if rrd is not None:
        if rrd.suffix.lower() != ".rrd":
            raise InputError("the recording file must end in .rrd", where=str(rrd))
        return f"save:{rrd}"
    if rerun is not None:
        opt = rerun.strip()
        head, _, rest = opt.partition(" ")
        if head == "connect" and rest.strip():
            return f"connect:{rest.strip()}"
        if opt in ("spawn", "connect") or opt.startswith("connect:"):
            return opt
        raise InputError(f"--rerun {rerun!r}: use 'spawn', 'connect' or 'connect URL'")
    return None


def run_replay(
    session: Path,
    cal: list | None,  # calibration files or Calibration objects
    sink: str | None,
    *,
    speed: str | None,
    up: str | None,
    raw: bool,
    label: list[str] | None,
    compare_mode: bool,
    full_rate: bool = False,
):
    """Replay or compare a session file into the sink (None: no recording); full_rate: every sample
    in the recording instead of display envelopes."""
    s = open_source(session, what="replay")  # a bad input is refused before a recording opens
    cals = list(cal or [])
    rec = (
        open_recording(  # a child process's when the command started one (present.rrd.offload)
            sink, recording_id=f"accellog-{'compare' if compare_mode else 'replay'}", full_rate=full_rate
        )
        if sink
        else None
    )
    try:
        if compare_mode:
            res = compare_fn(s, cals, labels=label, recording=rec, up_sensor=up, include_raw=raw)
        else:
            res = replay_fn(
                s, cals=cals, labels=label, speed=speed, recording=rec, up_sensor=up, include_raw=raw
            )
    except BaseException:
        if rec is not None:
            rec.abort()
        raise
    if rec is not None:
        rec.close()
        res.rrd = str(sink)[5:] if str(sink).startswith("save:") else sink
        res.sink_report = rec.report() or ""
    return res
