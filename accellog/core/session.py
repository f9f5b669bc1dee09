"""In-memory form of a recorded session: what the MCAP reader returns and every stage consumes.

All arrays are numpy, columnar, one row per sample. Times are float64 seconds since the session
start (the *sensor* time: sample clock for the chip, the logger's timestamps for imports; uneven
spacing is allowed and must be honoured by integration). Raw counts are kept next to the values in
units so nothing is lost; ``accel_g`` is derived from counts when counts exist.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from accellog.core.device import DeviceKey
from accellog.core.reprs import names_text, short_repr
from accellog.core.units import STANDARD_GRAVITY_MPS2

POSE_UP_VECTORS: dict[str, tuple[float, float, float]] = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}
"""Up vector in the sensor frame for the six face poses: the pose '+z' has the z axis pointing up,
so a perfect accelerometer at rest reads +1 g on z."""


@dataclass(frozen=True)
class SessionMeta:
    """Facts about how a session was recorded (stored as MCAP metadata record 'session')."""

    source: str
    """'hardware', 'emulator', 'import:capstone', 'import:imucal', 'import:csv'."""
    chip: str = "MPU-9250"
    who_am_i: int | None = None
    accel_range_g: float | None = None
    gyro_range_dps: float | None = None
    accel_lsb_per_g: float | None = None
    """counts per g of accel_counts; None when the source gave values without counts."""
    gyro_lsb_per_dps: float | None = None
    dlpf_cfg: int | None = None
    a_dlpf_cfg: int | None = None
    sample_rate_hz: float = 0.0
    """Nominal output data rate (Hz); real timing is in Session.t_s."""
    local_gravity_mps2: float = STANDARD_GRAVITY_MPS2
    software: str = ""
    host: str = ""
    protocol: str = ""
    start_time_unix_ns: int = 0
    ak8963_wia: int | None = None
    """AK8963 WIA register (0x48) when the magnetometer was read (device identity)."""
    serial: str = ""
    """User-given serial/name of the sensor (device identity; see accellog.core.device)."""
    i2c_bus: str = ""
    """Bus the chip was read on ('/dev/i2c-1', 'emulator'); '' for imports."""
    i2c_address: int | None = None
    """7-bit I2C address of the MPU (0x68/0x69)."""
    extra: dict[str, str] = field(default_factory=dict)
    """Free-form string facts (e.g. 'scenario' JSON of a simulation, importer notes)."""

    def replace(self, **changes) -> SessionMeta:
        return dataclasses.replace(self, **changes)

    @property
    def device(self) -> DeviceKey:
        """The device key (WHO_AM_I, AK8963 WIA, serial, bus, address, host) of this session."""
        return DeviceKey.from_meta(self)


def vec3(v) -> tuple[float, float, float]:
    """A 3-vector (any sequence or array of 3 numbers) as the plain-float tuple PoseLabel keeps."""
    x, y, z = (float(c) for c in v)
    return x, y, z


def quat4(q) -> tuple[float, float, float, float]:
    """A quaternion (w, x, y, z) (any sequence or array of 4 numbers) as a plain-float tuple."""
    w, x, y, z = (float(c) for c in q)
    return w, x, y, z


@dataclass(frozen=True)
class PoseLabel:
    """A labelled static hold.

    up_sensor: unit vector, in the sensor frame, of the reading a perfect accelerometer gives at
    rest in this pose (it points up, against gravity). q_sensor_to_world: nominal orientation
    (w, x, y, z) of the sensor in the world frame, if the protocol knows it (None otherwise).
    """

    name: str
    start_s: float
    end_s: float
    up_sensor: tuple[float, float, float]
    q_sensor_to_world: tuple[float, float, float, float] | None = None
    hold_index: int = 0


@dataclass(frozen=True)
class Event:
    """Something that happened while recording: every lost sample is accounted for here.

    kind: 'gap' (samples missing between sample indices), 'fifo_overflow', 'misaligned',
    'i2c_error', 'retry', 'note', 'recovered' (reader salvaged a truncated file), 'pose_prompt',
    'damaged' (reader skipped a chunk that failed its CRC; lost_samples counts its IMU samples),
    'skipped_row' (an imported CSV row that did not parse, dropped with --bad-rows skip; its line).
    """

    t_s: float
    kind: str
    detail: str = ""
    sample_index: int = -1
    lost_samples: int = 0


@dataclass
class Truth:
    """Ground truth of a simulated session (never used by fitting, only by evaluation)."""

    t_s: np.ndarray  # (K,)
    specific_force_g: np.ndarray  # (K,3) sensor frame, what a perfect accelerometer reads (g)
    omega_dps: np.ndarray  # (K,3) sensor frame angular rate (deg/s)
    position_m: np.ndarray  # (K,3) world frame (z up)
    velocity_mps: np.ndarray  # (K,3) world frame
    q_sensor_to_world: np.ndarray  # (K,4) w,x,y,z
    temp_degC: np.ndarray  # (K,) die temperature


@dataclass
class Session:
    """One recording, columnar. N samples of accel/gyro/temp, M magnetometer samples."""

    meta: SessionMeta
    t_s: np.ndarray
    """(N,) float64 sensor time since session start (s)."""
    sample_index: np.ndarray
    """(N,) int64 index in the device's sample stream; a jump > 1 is a gap (see events)."""
    accel_g: np.ndarray
    """(N,3) float64 accelerometer reading in g (counts / accel_lsb_per_g when counts exist)."""
    accel_counts: np.ndarray | None = None  # (N,3) int32
    gyro_dps: np.ndarray | None = None  # (N,3) float64
    gyro_counts: np.ndarray | None = None  # (N,3) int32
    temp_degC: np.ndarray | None = None  # (N,) float64
    temp_counts: np.ndarray | None = None  # (N,) int32
    host_time_s: np.ndarray | None = None
    """(N,) host clock (s since session start) when the batch holding each sample was read."""
    mag_t_s: np.ndarray | None = None  # (M,)
    mag_uT: np.ndarray | None = None  # (M,3) after ASA adjustment
    mag_counts: np.ndarray | None = None  # (M,3) int32 raw
    mag_st2: np.ndarray | None = None  # (M,) uint8 status byte
    poses: list[PoseLabel] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)
    truth: Truth | None = None
    path: str | None = None

    @property
    def n(self) -> int:
        return int(self.t_s.shape[0])

    def __repr__(self) -> str:
        span = float(self.t_s[-1] - self.t_s[0]) if self.n else 0.0
        channels = ["accel"] + [
            c
            for c, x in (("gyro", self.gyro_dps), ("temp", self.temp_degC), ("mag", self.mag_uT))
            if x is not None
        ]
        return short_repr(
            "Session",
            [
                self.meta.source,
                f"{self.n} samples over {span:.4g} s at {self.meta.sample_rate_hz:g} Hz",
                "+".join(channels),
                f"{len(self.poses)} poses",
                f"{len(self.events)} events",
                self.path,
            ],
        )

    @property
    def accel_mps2(self) -> np.ndarray:
        """(N,3) reading in m/s^2 (g0 = 9.80665)."""
        return self.accel_g * STANDARD_GRAVITY_MPS2

    def lost_samples(self) -> int:
        """Samples the events say were lost (gaps, overflows, I2C errors)."""
        return int(sum(e.lost_samples for e in self.events))

    def slice_time(self, start_s: float, end_s: float) -> slice:
        """Index slice of the samples with start_s <= t < end_s (t_s is sorted)."""
        i0, i1 = np.searchsorted(self.t_s, [start_s, end_s], side="left")
        return slice(int(i0), int(i1))


@dataclass
class ObsTable:
    """Static observations for model fitting: one row per averaging window of a static hold.

    Built by accellog.calibrate.observe.segment from a Session (several windows per hold, so that slow effects such
    as temperature or warm-up are visible), or from pose means (one row per pose, the seed's CSVs).
    All accelerations in g.
    """

    meas_g: np.ndarray  # (n,3) window mean of the reading
    sigma_g: np.ndarray  # (n,3) standard error of that mean (autocorrelation-aware)
    up_sensor: np.ndarray  # (n,3) nominal up vector of the pose (unit)
    pose_id: np.ndarray  # (n,) int, index into pose_names
    pose_names: list[str]
    t_s: np.ndarray  # (n,) window mid time since session start
    t_in_pose_s: np.ndarray  # (n,) window mid time since the hold began
    n_samples: np.ndarray  # (n,) samples in the window
    std_g: np.ndarray  # (n,3) sample standard deviation in the window
    temp_degC: np.ndarray | None = None  # (n,)
    dtemp_degC_per_s: np.ndarray | None = None  # (n,)
    q_sensor_to_world: np.ndarray | None = None  # (n,4) nominal orientation, NaN where unknown
    session: str = ""

    @property
    def n(self) -> int:
        return int(self.meas_g.shape[0])

    def __repr__(self) -> str:
        temp = None
        if self.temp_degC is not None and np.isfinite(self.temp_degC).any():
            temp = f"{np.nanmin(self.temp_degC):.1f}..{np.nanmax(self.temp_degC):.1f} degC"
        poses = f"{len(self.pose_names)} poses ({names_text(self.pose_names)})"
        return short_repr("ObsTable", [f"{self.n} windows", poses, temp, self.session])
