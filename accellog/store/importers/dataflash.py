"""ArduPilot DataFlash log (.bin) -> Session, with pymavlink's DFReader: the ``IMU`` messages of one
instance (field ``I``; logs before it name the instances IMU, IMU2, IMU3), ``TimeUS`` (microseconds
since boot), ``AccX..Z`` (m/s^2), ``GyrX..Z`` (rad/s), ``T`` (degC), in the axes after the board's
IMU orientation, where ArduPilot applies INS_ACCOFFS/INS_TCAL. The device ids are the log's
``INS_ACC_ID`` / ``INS_GYR_ID`` parameters (``INS_ACC2_ID``... for the later instances).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import Session
from accellog.store.importers.autopilot_log import log_session

MAGIC = bytes([0xA3, 0x95])
"""First two bytes of every DataFlash message (HEAD_BYTE1, HEAD_BYTE2)."""
_FIELDS = ("TimeUS", "AccX", "AccY", "AccZ", "GyrX", "GyrY", "GyrZ", "T")


def _reader(path: Path):
    try:
        from pymavlink import DFReader
    except ImportError:  # pragma: no cover - a declared dependency
        raise InputError("importing DataFlash logs needs pymavlink (pip install pymavlink)") from None
    if not path.is_file():
        raise InputError("no such file", where=str(path))
    with open(path, "rb") as f:
        head = f.read(2)
    if head != MAGIC:  # DFReader prints every byte it skips: refuse foreign files before it reads
        raise InputError(f"not a DataFlash log (starts {head.hex() or 'empty'}, not a395)", where=str(path))
    try:
        return DFReader.DFReader_binary(str(path))
    except Exception as exc:  # DFReader raises bare exceptions on foreign or damaged files
        raise InputError(
            f"not a readable DataFlash log ({type(exc).__name__}: {exc})", where=str(path)
        ) from None


def _instance_id(params: dict, kind: str, imu: int) -> int | None:
    """INS_ACC_ID / INS_ACC2_ID / ... (kind 'ACC' or 'GYR') as an int; None when not logged or 0."""
    v = params.get(f"INS_{kind}{'' if imu == 0 else imu + 1}_ID")
    return int(v) if v else None


def import_dataflash(path: str | Path, *, imu: int = 0) -> Session:
    """IMU instance ``imu`` (0-based, as the log's field I) of a DataFlash log -> Session."""
    path = Path(path)
    r = _reader(path)
    legacy = {"IMU": 0, "IMU2": 1, "IMU3": 2}
    rows: list[tuple] = []
    seen: set[int] = set()
    has_temp = True
    while (m := r.recv_match(type=list(legacy))) is not None:
        d = m.to_dict()
        k = int(d["I"]) if "I" in d else legacy[m.get_type()]
        seen.add(k)
        if k == imu:
            has_temp = has_temp and "T" in d
            rows.append(tuple(float(d.get(f, np.nan)) for f in _FIELDS))
    if not rows:
        have = f"IMU instances {sorted(seen)}" if seen else "no IMU messages"
        raise InputError(f"--imu {imu}: the log has {have}", where=str(path))
    a = np.array(rows)
    extra = {"imu": f"IMU {imu}", "dataflash_message": "IMU"}
    return log_session(path, "dataflash", a[:, 0].astype(np.int64), a[:, 1:4], a[:, 4:7],
                       a[:, 7] if has_temp else None, accel_id=_instance_id(r.params, "ACC", imu),
                       gyro_id=_instance_id(r.params, "GYR", imu), extra=extra)  # fmt: skip
