"""`track`: strapdown tracks of a moving session, one per calibration next to 'raw', with their errors."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from accellog.calibrate.calfile.calibration import as_calibration
from accellog.core.errors import InputError
from accellog.core.jsonio import JsonResult
from accellog.core.session import Session
from accellog.navigate.track_eval import TrackRun, run_session_tracks
from accellog.present.rrd.offload import open_recording
from accellog.present.views import log_session, log_track_runs
from accellog.store.reader import read_session


@dataclass
class TrackReport(JsonResult):
    """Tracks of one session: ``runs[0]`` is 'raw'; reference 'truth' or 'loop closure'."""

    session_path: str
    session: Session
    runs: list[TrackRun]
    zupt: bool

    @property
    def reference(self) -> str:
        return self.runs[0].error.reference

    def to_dict(self) -> dict:
        return {
            "session": self.session_path,
            "reference": self.reference,
            "zupt": self.zupt,
            "tracks": [
                {
                    **r.error.to_dict(),
                    "without_zupt": None if r.error_without_zupt is None else r.error_without_zupt.to_dict(),
                }
                for r in self.runs
            ],
        }

    def write_rrd(self, path: str | Path) -> None:
        """Recording of the session and its tracks vs truth, errors over time, ZUPT stops."""

        with open_recording(f"save:{path}") as rec:
            log_session(rec, self.session)
            log_track_runs(rec, self.runs, self.session.truth, group="track")


def track_session(
    session_path: str | Path, cal_paths: list | None = None, *, zupt: bool = True
) -> TrackReport:
    """Read the session and the calibrations (named by file stem, made unique) and integrate each track."""
    session_path = Path(session_path)
    if not session_path.is_file():
        raise InputError("no such session file", where=str(session_path))
    session = read_session(session_path)
    cals: dict[str, object] = {}
    for p in cal_paths or []:
        c = as_calibration(p)
        name = Path(c.path or "cal").stem
        while name in cals or name == "raw":
            name += "'"
        cals[name] = c
    return TrackReport(str(session_path), session, run_session_tracks(session, cals, use_zupt=zupt), zupt)
