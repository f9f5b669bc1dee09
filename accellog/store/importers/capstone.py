"""capstone (willward20/UCA-Honors-Capstone): the static test files (``t`` in s, uneven; x,y,z in g with
quantum 1/16384 g -> stored as counts with accel_lsb_per_g = 16384 when exact) and the six_position_data
pose tables (pose *statistics*: ``load_capstone_pose_table``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import POSE_UP_VECTORS, Session, SessionMeta, vec3
from accellog.core.units import SEED_LOCAL_GRAVITY_MPS2
from accellog.store.importers.text import (
    check_time,
    face_label,
    hold_end,
    rate_hz,
    read_lines,
    read_table,
)

CAPSTONE_LSB_PER_G = 16384.0
"""The capstone data are in g with quantum 1/16384 g (MPU-9250 at +-2 g)."""


# ---------------------------------------------------------------------------------------------
# capstone


@dataclass
class PoseTable:
    """Per-pose statistics (one row per pose, in g): truth, mean and standard deviation of the reading."""

    names: list[str]
    truth_g: np.ndarray  # (P,3) nominal reading (+-1 g on one axis)
    mean_g: np.ndarray  # (P,3) mean reading over the hold
    std_g: np.ndarray  # (P,3) sample standard deviation over the hold
    path: str = ""


_CAPSTONE_TABLE_COLS = ["x_true", "x_mean", "x_std", "y_true", "y_mean", "y_std", "z_true", "z_mean", "z_std"]


def load_capstone_pose_table(path: str | Path) -> PoseTable:
    """six_position_data*.csv: columns x_true (g),x_mean (g),x_std,y_true (g),... -> PoseTable (g)."""
    path = Path(path)
    lines = read_lines(path)
    header = [h.split("(")[0].strip() for h in (lines[0].split(",") if lines else [])]
    if header != _CAPSTONE_TABLE_COLS:
        raise InputError(
            "not a capstone pose table: expected header x_true (g),x_mean (g),x_std,y_true (g),...,z_std",
            where=f"{path}:1",
        )
    cols = read_table(path, lines, 2, _CAPSTONE_TABLE_COLS)
    truth = np.stack([cols["x_true"], cols["y_true"], cols["z_true"]], 1)
    mean = np.stack([cols["x_mean"], cols["y_mean"], cols["z_mean"]], 1)
    std = np.stack([cols["x_std"], cols["y_std"], cols["z_std"]], 1)
    by_vec = {v: k for k, v in POSE_UP_VECTORS.items()}
    names = [by_vec.get(vec3(row), f"pose{i}") for i, row in enumerate(truth)]
    return PoseTable(names, truth, mean, std, str(path))


def import_capstone(path: str | Path) -> Session:
    """A capstone static test file (60 s or 300 s, z up) -> Session with one '+z' hold over the file.

    Lines 1-2 are a title and a malformed header ('time (s)x (g),y (g),z (g)'); rows are t (s), x, y,
    z (g). Values that are exact multiples of 1/16384 g are stored as counts (lossless), otherwise as
    accel_g doubles.
    """
    path = Path(path)
    lines = read_lines(path)
    if lines and lines[0].replace(" ", "").startswith("x_true"):
        raise InputError(
            "this is a capstone pose table (per-pose means, not samples): "
            "load it with accellog.store.importers.load_capstone_pose_table",
            where=f"{path}:1",
        )
    if len(lines) < 3 or "time" not in lines[1].lower() or "x" not in lines[1].lower():
        raise InputError(
            "not a capstone test file: expected a title on line 1 and 'time (s)x (g),y (g),z (g)' on line 2",
            where=f"{path}:2",
        )
    cols = read_table(path, lines, 3, ["t", "x", "y", "z"])
    t = cols["t"]
    check_time(path, lines, 3, t)
    acc = np.stack([cols["x"], cols["y"], cols["z"]], 1)
    scaled = acc * CAPSTONE_LSB_PER_G
    exact = bool(np.all(scaled == np.round(scaled)) and np.all(np.abs(scaled) <= 32768))
    counts = scaled.astype(np.int32) if exact else None
    n = t.shape[0]
    extra = {
        "source_file": path.name,
        "title": lines[0].strip(),
        "source_unit": "g",
        "time": "t column, s since logging start (time.time() based, uneven)",
        "storage": "counts = g * 16384 (exact)"
        if exact
        else "accel_g doubles (values not multiples of 1/16384 g)",
    }
    meta = SessionMeta(
        source="import:capstone",
        accel_range_g=2.0,
        accel_lsb_per_g=CAPSTONE_LSB_PER_G if exact else None,
        sample_rate_hz=rate_hz(t),
        local_gravity_mps2=SEED_LOCAL_GRAVITY_MPS2,
        protocol="static +z",
        extra=extra,
    )
    return Session(
        meta=meta,
        t_s=t,
        sample_index=np.arange(n, dtype=np.int64),
        accel_g=counts / CAPSTONE_LSB_PER_G if counts is not None else acc,
        accel_counts=counts,
        poses=[face_label("+z", float(t[0]), hold_end(t, n), 0)],
        path=str(path),
    )
