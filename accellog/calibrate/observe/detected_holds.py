"""Pose labels for sessions that carry none (ROS 2 bags, other loggers): the still intervals found by
``accellog.calibrate.observe.detect.detect_static``. A hold whose mean reading is within ``max_angle_deg`` of a
face (+x..-z) gets that face's name and exact up vector (a six-position protocol on a table); other
holds stay unlabelled (their orientation is unknown: the orientation-free fit uses them).

Labels are given only when all six faces are found that close (a table protocol): the fit's label
check refuses holds more than ``label_check.MAX_LABEL_ANGLE_DEG`` (10 deg) from their label, so the
default 8 deg leaves a margin; an uncalibrated MPU-9250 on a table reads 3.5-5.5 deg off the faces
(imucal's Ferraris recording). A hand-held session (holds near, not on, the faces) gets no labels,
and ``accellog fit`` then fits it orientation-free.

The hand-held path (``detect_holds``) cuts the detected intervals into observation windows without
labels, the detector's threshold factor swept 2..10 and chosen by the orientation-free fit's RMS
residual (the gravity norm, ``norm_cost``); ``norm_obs`` gives another session's windows for the
norm's held-out judgement. ``fit_observations`` is the fit stage's observation step for a session
read whole (relabelled, orientation-free or unlabelled): its holds, or its detected intervals;
``field_observations`` and ``fit_stops`` are the field fit's (unlabelled sessions of one device,
their stops fitted orientation-free with a prior or on what the stops identify).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from accellog.calibrate.model.compose import Model, build_model
from accellog.calibrate.model.effects import HANDHELD_START
from accellog.calibrate.model.fit import fit_orientation_free
from accellog.calibrate.observe.detect import TooFewOrientations, detect_static, with_labels
from accellog.calibrate.observe.label_check import relabel_holds
from accellog.calibrate.observe.segment import observations
from accellog.core.errors import InputError, ModelError
from accellog.core.notices import note
from accellog.core.protocol import pose_spec
from accellog.core.session import POSE_UP_VECTORS, ObsTable, PoseLabel, Session
from accellog.store.source import Source, open_source


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


@dataclass
class Detection:
    """Static intervals found by the detector and the settings that found them."""

    intervals: list[dict]
    window_s: float
    threshold: float | None
    """Fixed threshold factor k (statistic < k * reference), or None: swept 2..10, best by the
    orientation-free residual."""

    def to_dict(self) -> dict:
        return {"window_s": self.window_s, "threshold": self.threshold, "intervals": self.intervals}


def norm_cost(session: Session, m: Model, *, window_s: float, gravity_g: float = 1.0):
    """detect_static's cost of candidate labels: the RMS gravity-norm residual (g) of the unweighted
    orientation-free fit of m on their windows of about window_s (untrimmed; inf when it fails)."""

    def cost(labels: list[PoseLabel]) -> float:
        o = observations(with_labels(session, labels), window_s=window_s, trim_s=0.0, check_units=False)
        try:
            return fit_orientation_free(o, m, weighted=False, gravity_g=gravity_g).rms_g
        except ModelError:
            return np.inf

    return cost


def detect_holds(
    session: Session,
    *,
    window_s: float = 1.0,
    threshold: float | None = None,
    obs_window_s: float = 2.0,
    model: str = HANDHELD_START,
) -> tuple[ObsTable, Detection]:
    """Detect the static intervals of an unlabelled session (variance window `window_s` s,
    threshold factor `threshold` or a sweep scored by the orientation-free fit) and cut them into
    observation windows."""
    if not window_s > 0:
        raise InputError(f"detector window must be > 0 s, got {window_s}")
    rate = (session.n - 1) / max(float(session.t_s[-1] - session.t_s[0]), 1e-12)
    w = max(3, round(window_s * rate) | 1)
    m = build_model(model)
    ks = (float(threshold),) if threshold is not None else tuple(range(2, 11))
    cost = norm_cost(session, m, window_s=obs_window_s)
    labels = detect_static(session, window_samples=w, k_values=ks, cost=cost)
    obs = observations(with_labels(session, labels), window_s=obs_window_s, trim_s=0.0)
    iv = [
        {
            "start_s": p.start_s,
            "end_s": p.end_s,
            "n": int(np.sum((session.t_s >= p.start_s) & (session.t_s < p.end_s))),
            "up_sensor": [float(x) for x in p.up_sensor],
        }
        for p in labels
    ]
    return obs, Detection(iv, float(window_s), threshold)


def norm_obs(session: Session, *, window_s: float = 2.0, detect_window_s: float = 1.0) -> ObsTable:
    """Observation windows of another session for the gravity-norm judgement: its labelled holds
    (the norm ignores their orientations), or its detected static intervals when it has none."""
    if session.poses:
        return observations(session, window_s=window_s)
    return detect_holds(session, window_s=detect_window_s, obs_window_s=window_s)[0]


def fit_observations(
    src: Source, m: Model, *, gravity_g: float, relabel: bool, window_s: float, trim_s: float
) -> tuple[ObsTable, list[PoseLabel] | None, Source]:
    """(observations, the detected static intervals or None, the Source the fit's gyro and
    provenance read) of a session read whole for a relabelled or orientation-free fit: labels that
    contradict gravity replaced when relabel (label_check.relabel_holds, a note each); the windows
    of its holds (trim_s s trimmed), or, unlabelled, of the static intervals detect_static finds
    scored by the orientation-free fit of m (norm_cost; too few distinct orientations: refused,
    with the option that updates a lab calibration instead)."""
    session = src.whole()
    if relabel:
        session, changes = relabel_holds(session, trim_s=trim_s)
        for c in changes:
            note(f"{session.path or 'session'}: relabelled {c.pose!r} as {c.likely!r}: {c.line()}")
    if session.poses:
        return observations(session, window_s=window_s, trim_s=trim_s), None, open_source(session)
    try:
        detected = detect_static(session, cost=norm_cost(session, m, window_s=window_s, gravity_g=gravity_g))
    except TooFewOrientations as exc:
        raise TooFewOrientations(
            f"{exc}; or give --prior LAB.json to update a lab calibration from these stops"
        ) from None
    held = with_labels(session, detected)
    return observations(held, window_s=window_s, trim_s=0.0), detected, open_source(held)


def fit_stops(obs: ObsTable, m: Model, gravity_g: float, prior=None, *, weighted: bool = True,
              uncertainty: str = "noise", note_what: bool = False):  # fmt: skip
    """The orientation-free fit of the stops: with the prior (calibrate.model.prior.Prior), or of
    the terms they identify (model.stops.identify_stops; the rest held at nominal, said
    in a note when note_what)."""
    from accellog.calibrate.model.stops import identify_stops
    from accellog.calibrate.model.variance import with_uncertainty

    ident = identify_stops(obs, m, None if prior is None else prior.theta)
    fixed = ident.unfitted if prior is None else ()
    fit = fit_orientation_free(obs, m, weighted=weighted or prior is not None, gravity_g=gravity_g, prior=prior,
                               fixed=fixed)  # fmt: skip
    fit = with_uncertainty(fit, obs, uncertainty)
    if prior is not None:
        fit.prior_sources = prior.sources(fit.theta, fit.cov)
    fit.identification = ident
    if note_what:
        for line in ident.lines(prior is not None):
            note(f"{obs.session or 'stops'}: {line}")
    if ident.weak and prior is None:
        fit.warnings.append(ident.weak_line())
    return fit


def judge_stops(fit, obs: ObsTable) -> None:
    """What the detected stops of a full orientation-free fit determine (identify_stops at the
    fitted values) in fit.identification; weakly determined parameters said in a note and in the
    fit's warnings."""
    from accellog.calibrate.model.stops import identify_stops

    ident = identify_stops(obs, fit.model, fit.theta)
    fit.identification = ident
    if ident.weak:
        note(f"{obs.session or 'stops'}: {ident.weak_line()}")
        fit.warnings.append(ident.weak_line())


def field_observations(
    srcs: list[Source], m: Model, gravity_g: float, prior=None, *, window_s: float, trim_s: float = 0.5
) -> tuple[list[ObsTable], list[tuple[Source, list[PoseLabel] | None]]]:
    """(each session's stop windows, [(the Source its gyro and provenance read, its detected
    intervals or None)]): a labelled session's holds are its stops (trim_s s trimmed); an unlabelled
    one's are the still intervals detect_static finds (one at least), scored by the fit of the stops
    (fit_stops, unweighted, with the prior)."""
    parts: list[ObsTable] = []
    found: list[tuple[Source, list[PoseLabel] | None]] = []
    for src in srcs:
        session = src.whole()
        if session.poses:
            parts.append(observations(session, window_s=window_s, trim_s=trim_s))
            found.append((src, None))
            continue

        def cost(labels, s=session) -> float:
            o = observations(with_labels(s, labels), window_s=window_s, trim_s=0.0, check_units=False)
            return fit_stops(o, m, gravity_g, prior, weighted=False).rms_g

        detected = detect_static(session, min_poses=1, cost=cost)
        held = with_labels(session, detected)
        parts.append(observations(held, window_s=window_s, trim_s=0.0))
        found.append((open_source(held), detected))
    return parts, found
