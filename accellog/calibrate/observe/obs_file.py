"""Observation tables read from files: the segment stage's artifact (ObsTable <-> JSON with a format
name and version) and the capstone pose tables (six_position_data: one row of means per pose).

``read_obs_table`` is the one reader of both; a session file (samples) is store.source's.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import ObsTable

# ---------------------------------------------------------------- observation files (stage artifact)

OBS_FORMAT = "accellog.observations"
_OBS_ARRAYS = (
    "meas_g",
    "sigma_g",
    "up_sensor",
    "pose_id",
    "t_s",
    "t_in_pose_s",
    "n_samples",
    "std_g",
    "temp_degC",
    "dtemp_degC_per_s",
    "q_sensor_to_world",
)


def obs_to_dict(obs: ObsTable) -> dict:
    """JSON-able ObsTable (format 'accellog.observations' v1; arrays as lists; g, s, degC)."""
    d: dict = {
        "format": OBS_FORMAT,
        "format_version": 1,
        "pose_names": list(obs.pose_names),
        "session": obs.session,
    }
    for k in _OBS_ARRAYS:
        v = getattr(obs, k)
        d[k] = None if v is None else np.asarray(v).tolist()
    return d


def obs_from_dict(d: dict, where: str | None = None) -> ObsTable:
    """Inverse of obs_to_dict; InputError naming the field on malformed input."""
    if not isinstance(d, dict) or d.get("format") != OBS_FORMAT:
        raise InputError(f"not an accellog observations file (format '{OBS_FORMAT}')", where=where)
    try:
        kw: dict[str, Any] = {}  # ObsTable's array fields (None: absent from the file)
        for k in _OBS_ARRAYS:
            v = d.get(k)
            kw[k] = (
                None if v is None else np.asarray(v, dtype=int if k in ("pose_id", "n_samples") else float)
            )
        obs = ObsTable(pose_names=list(d["pose_names"]), session=str(d.get("session", "")), **kw)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"malformed observations file: {exc}", where=where) from None
    n = obs.meas_g.shape[0] if obs.meas_g is not None else -1
    for k in _OBS_ARRAYS:
        v = getattr(obs, k)
        if k in ("temp_degC", "dtemp_degC_per_s", "q_sensor_to_world") and v is None:
            continue
        if v is None or v.shape[0] != n:
            raise InputError(f"observations field {k!r} missing or not {n} rows", where=where)
    return obs


CAPSTONE_SAMPLES_PER_POSE = 5400
"""30 s at ~180 Hz: the capstone protocol (its pose tables carry no sample count)."""


def read_obs_table(path: str | os.PathLike, *, n_per_pose: int | None = None) -> ObsTable | None:
    """The ObsTable of an observations JSON or a capstone pose table (n_per_pose samples behind each
    mean, default CAPSTONE_SAMPLES_PER_POSE); None for any other file (a session: store.source)."""
    from accellog.calibrate.observe.segment import obs_from_pose_means
    from accellog.core.textin import json_kind, read_json
    from accellog.store.importers import load_capstone_pose_table
    from accellog.store.source import text_kind

    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".json" and p.exists():
        d = read_json(p)
        if isinstance(d, dict) and d.get("format") == OBS_FORMAT:
            return obs_from_dict(d, where=str(p))
        other = json_kind(d)
        if other is not None:
            raise InputError(
                f"this is {other}, not a session or observation table: are the arguments swapped?",
                where=str(p),
            )
        raise InputError(
            f"JSON input must be an observations file ('{OBS_FORMAT}', written by `accellog segment -o`)",
            where=str(p),
        )
    if suffix in (".csv", ".txt") and p.exists() and text_kind(p) == "pose_table":
        pt = load_capstone_pose_table(p)
        n = CAPSTONE_SAMPLES_PER_POSE if n_per_pose is None else n_per_pose
        return obs_from_pose_means(pt.truth_g, pt.mean_g, pt.std_g, n, names=pt.names, session=str(p))
    return None
