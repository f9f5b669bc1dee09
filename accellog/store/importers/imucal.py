"""imucal (mad-lab-fau/imucal): a Ferraris session CSV + section list JSON (102.4 Hz, m/s^2, deg/s) or the
pre-cut annotated_session.csv (raw counts, 204.8 Hz).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import Event, PoseLabel, Session, SessionMeta
from accellog.core.textin import read_json
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.store.importers.text import (
    check_time,
    face_label,
    hold_end,
    line_of_row,
    read_lines,
    read_table,
)

IMUCAL_FERRARIS_RATE_HZ = 102.4
IMUCAL_ANNOTATED_RATE_HZ = 204.8
IMUCAL_ACCEL_LSB_PER_G = 2048.0
"""annotated_session.csv counts: 16-bit at +-16 g (inferred from imucal's K_a = 2048/9.81 per m/s^2)."""
IMUCAL_GYRO_LSB_PER_DPS = 16.384
"""annotated_session.csv gyro counts: 16-bit at +-2000 deg/s (inferred)."""
IMUCAL_POSES = {"x_p": "+x", "x_a": "-x", "y_p": "+y", "y_a": "-y", "z_p": "+z", "z_a": "-z"}
IMUCAL_ROTATIONS = ("x_rot", "y_rot", "z_rot")


# ---------------------------------------------------------------------------------------------
# imucal


def _imucal_sections(path: Path, sections: Path | None, n: int) -> dict[str, tuple[int, int]]:
    sections = sections or path.with_name(path.stem + "_list.json")
    if not sections.is_file():
        raise InputError(
            f"an imucal Ferraris session needs its section list (start/end rows per label): {sections} not found",
            where=str(path),
        )
    raw = read_json(sections, "section list")
    if not isinstance(raw, dict):
        raise InputError("section list must be an object {label: {start, end}}", where=str(sections))
    out = {}
    for label, se in raw.items():
        if label not in IMUCAL_POSES and label not in IMUCAL_ROTATIONS:
            known = ", ".join([*IMUCAL_POSES, *IMUCAL_ROTATIONS])
            raise InputError(f"unknown section label {label!r} (known: {known})", where=str(sections))
        try:
            start, end = int(se["start"]), int(se["end"])
        except (TypeError, KeyError, ValueError):
            raise InputError(
                f"section {label!r} needs integer 'start' and 'end' rows", where=str(sections)
            ) from None
        if not 0 <= start < end <= n:
            raise InputError(
                f"section {label!r} rows [{start}, {end}) outside the {n} data rows", where=str(sections)
            )
        out[label] = (start, end)
    return out


def _imucal_labels(t: np.ndarray, parts: dict[str, tuple[int, int]], sample_index: np.ndarray):
    poses: list[PoseLabel] = []
    events: list[Event] = []
    for label, (s, e) in sorted(parts.items(), key=lambda kv: kv[1][0]):
        end_s = hold_end(t, e)
        if label in IMUCAL_POSES:
            poses.append(face_label(IMUCAL_POSES[label], float(t[s]), end_s, len(poses)))
        else:
            detail = json.dumps({"label": label, "axis": label[0], "start_s": float(t[s]), "end_s": end_s})
            events.append(Event(float(t[s]), "motion_segment", detail, int(sample_index[s])))
    return poses, events


def import_imucal(
    path: str | Path, sections: str | Path | None = None, *, sample_rate_hz: float | None = None
) -> Session:
    """imucal recordings -> Session.

    - example_ferraris_session.csv (n_samples,gyr_*,acc_* in deg/s, m/s^2; 102.4 Hz) with its section
      list JSON ({label: {start, end}} rows, default <stem>_list.json): static labels x_p, x_a, ...
      become poses +x, -x, ...; x_rot/y_rot/z_rot become 'motion_segment' events.
    - annotated_session.csv (part,samples,acc_*,gyr_* raw counts; 204.8 Hz): parts as above.
    """
    path = Path(path)
    lines = read_lines(path)
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    base_extra = {"source_file": path.name, "imucal_labels": json.dumps(IMUCAL_POSES)}
    if header[:1] == ["n_samples"] and set(header[1:]) == {
        "gyr_x",
        "gyr_y",
        "gyr_z",
        "acc_x",
        "acc_y",
        "acc_z",
    }:
        return _ferraris_session(
            path, lines, header, sections, sample_rate_hz or IMUCAL_FERRARIS_RATE_HZ, base_extra
        )
    if header == ["part", "samples", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"]:
        return _annotated_session(path, lines, header, sample_rate_hz or IMUCAL_ANNOTATED_RATE_HZ, base_extra)
    raise InputError(
        "not an imucal file: expected header 'n_samples,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z' "
        "or 'part,samples,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z'",
        where=f"{path}:1",
    )


def _ferraris_session(path: Path, lines, header, sections, fs: float, base_extra: dict) -> Session:
    """example_ferraris_session.csv layout: n_samples, gyro (deg/s), accel (m/s^2), sections from JSON."""
    cols = read_table(path, lines, 2, header)
    idx = cols["n_samples"]
    if np.any(idx != np.round(idx)):
        row = int(np.flatnonzero(idx != np.round(idx))[0])
        raise InputError("n_samples must be an integer", where=f"{path}:{line_of_row(lines, 2, row)}")
    idx = idx.astype(np.int64)
    t = idx / fs
    check_time(path, lines, 2, t)
    parts = _imucal_sections(path, Path(sections) if sections else None, t.shape[0])
    acc_mps2 = np.stack([cols["acc_x"], cols["acc_y"], cols["acc_z"]], 1)
    gyro = np.stack([cols["gyr_x"], cols["gyr_y"], cols["gyr_z"]], 1)
    poses, events = _imucal_labels(t, parts, idx)
    extra = base_extra | {
        "source_unit": "m/s^2",
        "conversion": "accel_g = acc_mps2 / 9.80665 (original: acc_mps2 = accel_g * 9.80665)",
        "imucal_gravity_mps2": "9.81 (imucal's g for its Ferraris fit)",
        "gyro_unit": "deg/s",
        "sections": json.dumps({k: list(v) for k, v in parts.items()}),
    }
    meta = SessionMeta(
        source="import:imucal",
        chip="unknown (imucal example)",
        sample_rate_hz=fs,
        protocol="ferraris",
        extra=extra,
    )
    return Session(
        meta=meta,
        t_s=t,
        sample_index=idx,
        accel_g=acc_mps2 / STANDARD_GRAVITY_MPS2,
        gyro_dps=gyro,
        poses=poses,
        events=events,
        path=str(path),
    )


def _annotated_session(path: Path, lines, header, fs: float, base_extra: dict) -> Session:
    """annotated_session.csv layout: part label, sample index, raw accel and gyro counts per row."""
    cols = read_table(path, lines, 2, header, strings=("part",))
    num = np.stack([cols[c] for c in header[1:]], 1)
    if np.any(num != np.round(num)):
        row = int(np.flatnonzero(np.any(num != np.round(num), axis=1))[0])
        raise InputError(
            "annotated session values must be integer counts",
            where=f"{path}:{line_of_row(lines, 2, row)}",
        )
    order = np.argsort(cols["samples"], kind="stable")  # file rows are grouped by part
    num, part = num[order].astype(np.int64), cols["part"][order]
    idx = num[:, 0]
    if np.any(np.diff(idx) == 0):
        raise InputError(
            f"duplicate sample {int(idx[np.flatnonzero(np.diff(idx) == 0)[0]])}", where=str(path)
        )
    unknown = sorted(set(part.tolist()) - set(IMUCAL_POSES) - set(IMUCAL_ROTATIONS))
    if unknown:
        raise InputError(f"unknown part label(s) {unknown}", where=str(path))
    starts = np.concatenate([[0], np.flatnonzero(part[1:] != part[:-1]) + 1])
    ends = np.concatenate([starts[1:], [part.shape[0]]])
    t = idx / fs
    parts_rows = {}
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        if part[s] in parts_rows:
            raise InputError(f"part {part[s]!r} is not one contiguous block of samples", where=str(path))
        parts_rows[part[s]] = (s, e)
    poses, events = _imucal_labels(t, parts_rows, idx)
    jumps = np.flatnonzero(np.diff(idx) > 1)
    events += [
        Event(
            float(t[j + 1]),
            "gap",
            "samples not in the pre-cut file",
            int(idx[j + 1]),
            int(idx[j + 1] - idx[j] - 1),
        )
        for j in jumps.tolist()
    ]
    events.sort(key=lambda e: e.t_s)
    acc_c, gyr_c = num[:, 1:4].astype(np.int32), num[:, 4:7].astype(np.int32)
    extra = base_extra | {
        "source_unit": "counts (a.u.)",
        "scale": "inferred: 2048 counts/g (+-16 g), 16.384 counts/(deg/s) (+-2000 deg/s)",
    }
    meta = SessionMeta(
        source="import:imucal",
        chip="unknown (imucal example, 16-bit)",
        accel_range_g=16.0,
        gyro_range_dps=2000.0,
        accel_lsb_per_g=IMUCAL_ACCEL_LSB_PER_G,
        gyro_lsb_per_dps=IMUCAL_GYRO_LSB_PER_DPS,
        sample_rate_hz=fs,
        protocol="ferraris",
        extra=extra,
    )
    return Session(
        meta=meta,
        t_s=t,
        sample_index=idx,
        accel_g=acc_c / IMUCAL_ACCEL_LSB_PER_G,
        accel_counts=acc_c,
        gyro_dps=gyr_c / IMUCAL_GYRO_LSB_PER_DPS,
        gyro_counts=gyr_c,
        poses=poses,
        events=events,
        path=str(path),
    )
