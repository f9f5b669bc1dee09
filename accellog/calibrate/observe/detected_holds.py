"""Pose labels for sessions that carry none (ROS 2 bags, other loggers): the still intervals found by
``accellog.calibrate.observe.detect.detect_static``. A hold whose mean reading is within ``max_angle_deg`` of a
face (+x..-z) gets that face's name and exact up vector (a six-position protocol on a table); other
holds stay unlabelled (their orientation is unknown: the orientation-free fit uses them).

Labels are given only when all six faces are found that close (a table protocol): the fit's label
check refuses holds more than ``label_check.MAX_LABEL_ANGLE_DEG`` (10 deg) from their label, so the
default 8 deg leaves a margin; an uncalibrated MPU-9250 on a table reads 3.5-5.5 deg off the faces
(imucal's Ferraris recording). A hand-held session (holds near, not on, the faces) gets no labels,
and ``accellog fit`` then fits it orientation-free.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from accellog.calibrate.observe.detect import detect_static
from accellog.core.protocol import pose_spec
from accellog.core.session import POSE_UP_VECTORS, PoseLabel, Session


def label_detected_holds(session: Session, *, min_poses: int = 6, max_angle_deg: float = 8.0) -> Session:
    """A copy of session labelled with its detected face holds (all six faces within max_angle_deg,
    else none); meta.extra['poses'] says which."""
    found = detect_static(session, min_poses=min_poses)
    faces = list(POSE_UP_VECTORS)
    up = np.array([POSE_UP_VECTORS[f] for f in faces])
    labels: list[PoseLabel] = []
    for p in found:
        d = np.asarray(p.up_sensor, float)
        cos = up @ (d / np.linalg.norm(d))
        k = int(np.argmax(cos))
        if cos[k] >= np.cos(np.deg2rad(max_angle_deg)):
            spec = pose_spec(faces[k], p.end_s - p.start_s)
            labels.append(
                PoseLabel(faces[k], p.start_s, p.end_s, spec.up_sensor, spec.q_sensor_to_world, len(labels))
            )
    faces_found = {p.name for p in labels}
    if len(faces_found) < len(faces):
        note = (
            f"{len(found)} still intervals (detect_static), {len(faces_found)} of the 6 faces within "
            f"{max_angle_deg:g} deg: not a table protocol, left unlabelled (fit fits orientation-free)"
        )
        labels = []
    else:
        note = (
            f"{len(labels)} of {len(found)} still intervals (detect_static) labelled as the face within "
            f"{max_angle_deg:g} deg; labels detected, not in the source"
        )
    extra = {**session.meta.extra, "poses": note}
    meta = session.meta.replace(protocol=",".join(p.name for p in labels), extra=extra)
    return dataclasses.replace(session, poses=labels, meta=meta)
