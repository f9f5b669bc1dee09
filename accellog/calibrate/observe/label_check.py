"""Physics checks of a session before it is fitted: do the labels agree with what was measured?

At rest an accelerometer reads f = u g (plus errors of a few % and tens of mg), where u is the
unit up vector of the pose in the sensor frame. The measured direction m = mean(f) / |mean(f)| of a
hold therefore lies within a few degrees of its label's u:

    angle = arccos(m . u)   must be <= MAX_LABEL_ANGLE_DEG (default 10 deg)

A hold labelled '+z' that is really '-z' gives 180 deg; the likely true label is the axis pose
(or combined face pose) nearest to m. ``relabel_holds`` applies those likely labels (``--relabel``).
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import POSE_UP_VECTORS, PoseLabel, Session, vec3

MAX_LABEL_ANGLE_DEG = 10.0
"""Largest angle (deg) between a hold's measured gravity direction and its label's up vector."""


def _candidates() -> dict[str, np.ndarray]:
    """Axis poses ('+z') and the 12 edge / 8 corner poses ('+x+y', '+x+y+z') with unit up vectors."""
    out = {k: np.asarray(v, float) for k, v in POSE_UP_VECTORS.items()}
    axes = list(POSE_UP_VECTORS)
    for r in (2, 3):
        for combo in itertools.combinations(axes, r):
            if len({c[1] for c in combo}) < r:
                continue  # the same axis twice ('+x-x')
            v = np.sum([POSE_UP_VECTORS[c] for c in combo], axis=0)
            out["".join(combo)] = v / np.linalg.norm(v)
    return out


_CANDIDATES = _candidates()


def likely_label(direction: np.ndarray) -> tuple[str, np.ndarray]:
    """Name and up vector of the standard pose nearest to a measured direction (unit 3-vector)."""
    names = list(_CANDIDATES)
    ups = np.array([_CANDIDATES[n] for n in names])
    k = int(np.argmax(ups @ direction))
    return names[k], ups[k]


@dataclasses.dataclass(frozen=True)
class LabelMismatch:
    """A hold whose measured gravity direction contradicts its label."""

    pose: str
    hold_index: int
    start_s: float
    end_s: float
    angle_deg: float
    likely: str
    likely_angle_deg: float

    def line(self) -> str:
        return (
            f"pose {self.pose!r} ({self.start_s:.1f}-{self.end_s:.1f} s): measured gravity is "
            f"{self.angle_deg:.0f} deg from the label; it looks like {self.likely!r} "
            f"({self.likely_angle_deg:.1f} deg)"
        )


def label_mismatches(
    session: Session,
    holds: list[tuple[PoseLabel, slice]],
    max_angle_deg: float = MAX_LABEL_ANGLE_DEG,
    means: list[np.ndarray] | None = None,
) -> list[LabelMismatch]:
    """Every hold (label, sample slice) whose mean reading is more than max_angle_deg from its label
    (means: each hold's accel_g[sl].mean(axis=0) when the caller has them)."""
    out = []
    for i, (p, sl) in enumerate(holds):
        a = session.accel_g[sl]
        m = a.mean(axis=0) if means is None else means[i]  # the same sum as nanmean without NaN
        if not np.isfinite(m).all():
            m = np.nanmean(a, axis=0)
        bad = hold_mismatch(p, m, max_angle_deg)
        if bad is not None:
            out.append(bad)
    return out


def hold_mismatch(
    p: PoseLabel, mean: np.ndarray, max_angle_deg: float = MAX_LABEL_ANGLE_DEG
) -> LabelMismatch | None:
    """The mismatch of a hold labelled p whose mean reading is mean (g), if more than max_angle_deg
    from its label; None otherwise (or when the direction is unknown)."""
    norm = float(np.linalg.norm(mean))
    up = np.asarray(p.up_sensor, float)
    if not np.isfinite(norm) or norm == 0 or not np.isfinite(up).all():
        return None
    d = mean / norm
    ang = float(np.degrees(np.arccos(np.clip(d @ up, -1.0, 1.0))))
    if ang <= max_angle_deg:
        return None
    name, u = likely_label(d)
    la = float(np.degrees(np.arccos(np.clip(d @ u, -1.0, 1.0))))
    return LabelMismatch(p.name, p.hold_index, p.start_s, p.end_s, ang, name, la)


def mismatch_error(bad: list[LabelMismatch], where: str | None = None) -> InputError | None:
    """The refusal naming the first mislabelled hold of bad and how many more there are; None if none."""
    if not bad:
        return None
    more = f" (and {len(bad) - 1} more holds)" if len(bad) > 1 else ""
    return InputError(f"{bad[0].line()}{more}; fix the label or fit with --relabel", where=where)


def relabel_holds(
    session: Session, max_angle_deg: float = MAX_LABEL_ANGLE_DEG, trim_s: float = 0.5
) -> tuple[Session, list[LabelMismatch]]:
    """A copy of the session whose mislabelled holds carry their likely true label (orientation
    about the up axis unknown: q_sensor_to_world None), and the changes made."""
    holds = []
    for p in session.poses:
        sl = session.slice_time(p.start_s + trim_s, p.end_s - trim_s)
        if sl.stop > sl.start:
            holds.append((p, sl))
    bad = label_mismatches(session, holds, max_angle_deg)
    if not bad:
        return session, []
    fix = {(b.pose, b.hold_index, b.start_s): b for b in bad}
    poses = []
    for p in session.poses:
        b = fix.get((p.name, p.hold_index, p.start_s))
        if b is None:
            poses.append(p)
            continue
        up = vec3(_CANDIDATES[b.likely])
        poses.append(PoseLabel(b.likely, p.start_s, p.end_s, up, None, 100 + p.hold_index))
    return dataclasses.replace(session, poses=poses), bad
