"""What was recovered from a truncated or unfinished recording, stated so that users see it.

``read_session`` salvages the complete chunks of an unfinished MCAP file and appends an
Event('recovered'); ``recovery_info`` turns that into numbers (seconds and samples kept, complete
holds) that commands print on stderr, put in ``--json`` and store in every artifact's provenance.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from accellog.core.notices import note
from accellog.core.session import Session


@dataclass(frozen=True)
class RecoveryInfo:
    """A recovered session: duration_s and samples kept, holds (complete labelled poses), detail."""

    path: str
    duration_s: float
    samples: int
    holds: int
    detail: str

    def to_dict(self) -> dict:
        return asdict(self)

    def line(self) -> str:
        return (
            f"{self.path}: truncated file recovered: {self.duration_s:.1f} s, {self.samples} samples, "
            f"{self.holds} holds kept ({self.detail})"
        )


def recovery_info(session: Session) -> RecoveryInfo | None:
    """RecoveryInfo of a session read from an unfinished file, None for a finished one."""
    notes = [e.detail for e in session.events if e.kind == "recovered"]
    if not notes:
        return None
    dur = float(session.t_s[-1] - session.t_s[0]) if session.n else 0.0
    return RecoveryInfo(str(session.path or ""), dur, int(session.n), len(session.poses), "; ".join(notes))


def announce(session: Session) -> RecoveryInfo | None:
    """recovery_info, also queued as a user note (accellog.core.notices; the CLI prints it on
    stderr when the command succeeds)."""
    info = recovery_info(session)
    if info is not None:
        note(info.line())
    return info
