"""Pose protocols for a guided recording: which static poses, in which order, with what labels.

A pose is named by the sensor axis that points up ('+z' = z axis up, the sensor lying flat) and,
for the 24-pose protocol, a rotation about the vertical ('+z@90' = z up, turned 90 deg about the
world vertical). The nominal orientation is q_sensor_to_world = q_yaw(deg) * q_face, where q_face
turns the face's up axis onto world +z.

Off-axis poses (cube edges and corners, for nonlin3 and g_cross) join two or three distinct signed
axes: '+x+y' has up = (1, 1, 0)/sqrt(2) (a 45 deg tilt between x and y), '+x-y+z' has up =
(1, -1, 1)/sqrt(3); q_face is then the shortest rotation of that up vector onto world +z, and
'@<deg>' adds the same yaw about the vertical.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from accellog.core.errors import InputError
from accellog.core.rotations import quat_between, quat_from_axis_angle, quat_multiply
from accellog.core.session import POSE_UP_VECTORS, quat4, vec3

SIX_POSITION_ORDER = ("+z", "-z", "+y", "-y", "+x", "-x")
"""The seed's order (z+, z-, y+, y-, x+, x-)."""

_POSE_RE = re.compile(r"^((?:[+-][xyz]){1,3})(?:@(-?\d+(?:\.\d+)?))?$")


@dataclass(frozen=True)
class PoseSpec:
    """One pose of a protocol: name, up vector (sensor frame), nominal orientation, hold time."""

    name: str
    up_sensor: tuple[float, float, float]
    q_sensor_to_world: tuple[float, float, float, float]
    hold_s: float


def pose_spec(name: str, hold_s: float) -> PoseSpec:
    """Parse a pose name '+x' .. '-z' (or an edge/corner '+x+y', '+x-y+z'), optionally '@<yaw deg>'
    about the vertical. up = normalised sum of the named axes' unit vectors."""
    m = _POSE_RE.match(name.strip())
    faces = [] if not m else [m.group(1)[i : i + 2] for i in range(0, len(m.group(1)), 2)]
    if not m or len({f[1] for f in faces}) != len(faces):
        raise InputError(
            f"unknown pose name {name!r}: use +x,-x,+y,-y,+z,-z (or an edge/corner of distinct axes such "
            "as '+x+y', '+x-y+z'), optionally with @<deg> (e.g. '+z@90')"
        )
    yaw = float(m.group(2) or 0.0)
    if len(faces) == 1:
        up = POSE_UP_VECTORS[faces[0]]
    else:
        v = np.sum([POSE_UP_VECTORS[f] for f in faces], axis=0)
        up = vec3(v / np.linalg.norm(v))
    q_face = quat_between(np.array(up), np.array([0.0, 0.0, 1.0]))
    q = quat_multiply(quat_from_axis_angle([0.0, 0.0, 1.0], np.deg2rad(yaw)), q_face)
    return PoseSpec(name.strip(), up, quat4(q), float(hold_s))


def six_position(hold_s: float = 30.0) -> list[PoseSpec]:
    """The seed's six positions: each axis up and down once."""
    return [pose_spec(n, hold_s) for n in SIX_POSITION_ORDER]


def twenty_four_position(hold_s: float = 30.0) -> list[PoseSpec]:
    """Six faces x four rotations (0, 90, 180, 270 deg) about the vertical: reveals fixture tilt."""
    return [pose_spec(f"{face}@{yaw}", hold_s) for face in SIX_POSITION_ORDER for yaw in (0, 90, 180, 270)]


def parse_protocol(spec: str, hold_s: float = 30.0) -> list[PoseSpec]:
    """'six' | '24' | a comma-separated list of pose names (e.g. '+z,-z,+x@45')."""
    key = spec.strip().lower()
    if key in ("six", "6", "six_position"):
        return six_position(hold_s)
    if key in ("24", "twenty_four", "24_position"):
        return twenty_four_position(hold_s)
    names = [s for s in spec.split(",") if s.strip()]
    if not names:
        raise InputError("empty pose protocol: give 'six', '24' or a list such as '+z,-z,+x'")
    return [pose_spec(n, hold_s) for n in names]
