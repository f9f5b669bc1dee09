"""Observation files (the segment stage's artifact): ObsTable <-> JSON with a format name and version."""

from __future__ import annotations

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
        kw = {}
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
