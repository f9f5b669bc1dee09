"""Physical error model of the MPU-9250: true motion -> raw counts, with every effect switchable.

Accelerometer (the measurement equation of docs/architecture.md), true specific force f (g, sensor
frame), die temperature T (degC, dT = T - t_ref_degC), time since session start t (s):

    u_i   = f_i + k2_i f_i^2 + k3_i f_i^3 + sum_{j<k} G_i,jk f_j f_k
    S     = diag(1 + s + s_T dT + s_T2 dT^2) + C
    b     = b0 + b_T dT + b_T2 dT^2 + d_t t + w (1 - exp(-t / tau))
    a'    = S u + b + n                                         (g)
    counts = clip(round(a' LSB_per_g), -32768, 32767)

Gyro: w' = (I diag(1 + s) + C) omega + b0 + b_T dT + n (deg/s), counts = clip(round(w' LSB_per_dps)).
Temperature: TEMP_OUT = round((T - 21) 333.87 + n_T).
Magnetometer (AK8963 axes: x_m = y_s, y_m = x_s, z_m = -z_s): H = W R^T B_world (mapped) + hard iron +
n (uT), W the soft-iron matrix (identity: none; B_world the local field); raw counts = H / (0.15 uT/LSB * ASA factor), ASA factor = (ASA - 128) 0.5 / 128 + 1.

Slow bias noise (bias instability B, random walk K; emulator.slow_noise) adds to b for accel and gyro.

Noise n: white Gaussian with the given density, keyed by the sample index (reproducible per seed,
independent of how the stream is cut into reads) and low-pass filtered like the DLPF: a first-order
filter with the DLPF's -3 dB bandwidth f_c at the output period T_o, h[k] ∝ a^k, a = exp(-2 pi f_c
T_o), scaled so the per-sample standard deviation is density * sqrt(pi/2 f_c) (noise-equivalent
bandwidth of a first-order filter). Consecutive samples then correlate with coefficient a.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from accellog.acquire.emulator.temperature import TemperaturePath
from accellog.core.errors import InputError
from accellog.core.kinematics import Kinematics, Motion
from accellog.core.rotations import rotate_inverse
from accellog.core.session import Truth

if TYPE_CHECKING:
    from accellog.acquire.emulator.slow_noise import MarkovBank
from accellog.core.units import (
    MAG_UT_PER_LSB_14BIT,
    MAG_UT_PER_LSB_16BIT,
    STANDARD_GRAVITY_MPS2,
    TEMP_LSB_PER_DEGC,
    TEMP_OFFSET_DEGC,
)


def _zeros3() -> np.ndarray:
    return np.zeros(3)


def _zeros33() -> np.ndarray:
    return np.zeros((3, 3))


def _as3(name: str, v) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.ndim == 0:
        a = np.full(3, float(a))
    if a.shape != (3,):
        raise InputError(f"{name} must be 3 numbers (x, y, z), got shape {a.shape}")
    return a


def _as33(name: str, v, zero_diagonal: bool = False) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.shape != (3, 3):
        raise InputError(f"{name} must be a 3x3 matrix, got shape {a.shape}")
    if zero_diagonal and np.any(np.diag(a) != 0):
        raise InputError(f"{name} must have a zero diagonal (the diagonal is the scale error)")
    return a


@dataclass
class AccelErrors:
    """Accelerometer error parameters (zero = effect off). Vectors are per sensor axis (x, y, z)."""

    bias_g: np.ndarray = field(default_factory=_zeros3)
    """b0 (g)."""
    scale: np.ndarray = field(default_factory=_zeros3)
    """s: scale-factor deviation from 1 (dimensionless, 0.03 = +3 %)."""
    cross_axis: np.ndarray = field(default_factory=_zeros33)
    """C: off-diagonal cross-axis sensitivity (dimensionless, zero diagonal); C[i, j] couples f_j into axis i."""
    temp_bias_g_per_degC: np.ndarray = field(default_factory=_zeros3)
    temp_bias2_g_per_degC2: np.ndarray = field(default_factory=_zeros3)
    temp_scale_per_degC: np.ndarray = field(default_factory=_zeros3)
    temp_scale2_per_degC2: np.ndarray = field(default_factory=_zeros3)
    nonlin2_per_g: np.ndarray = field(default_factory=_zeros3)
    """k2 (1/g): u_i += k2_i f_i^2."""
    nonlin3_per_g2: np.ndarray = field(default_factory=_zeros3)
    """k3 (1/g^2): u_i += k3_i f_i^3."""
    g_cross_per_g: np.ndarray = field(default_factory=_zeros33)
    """G (1/g): u_i += G[i,0] f_x f_y + G[i,1] f_x f_z + G[i,2] f_y f_z."""
    time_drift_g_per_s: np.ndarray = field(default_factory=_zeros3)
    warmup_g: np.ndarray = field(default_factory=_zeros3)
    """w (g): bias change after power-on, b += w (1 - exp(-t / warmup_tau_s))."""
    warmup_tau_s: float = 60.0
    temp_rate_bias_g_per_degC_per_s: np.ndarray = field(default_factory=_zeros3)
    """r (g/(degC/s)): bias following the rate of the die temperature, b += r dT/dt (not in the library)."""
    temp_hysteresis_g: np.ndarray = field(default_factory=_zeros3)
    """h (g): thermal hysteresis, b += h s(t), s = (P(T) - T) / (w / 2) in [-1, 1], P the play
    (backlash) operator of width w = temp_hysteresis_width_degC: -1 while heating, +1 while
    cooling (not in the library)."""
    temp_hysteresis_width_degC: float = 2.0
    noise_density_g_per_rtHz: np.ndarray = field(default_factory=_zeros3)
    bias_instability_g: np.ndarray = field(default_factory=_zeros3)
    """B (g): flicker bias noise, Allan deviation floor 0.664 B (emulator.slow_noise)."""
    random_walk_g_per_s_rtHz: np.ndarray = field(default_factory=_zeros3)
    """K (g/s/sqrt(Hz)): bias random walk, AVAR = K^2 tau / 3."""
    clock_error: float = 0.0
    """eps: the chip's real sample period is (1 + eps) / ODR (fraction; 0.01 = 1 % slow)."""
    t_ref_degC: float = 25.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name in ("cross_axis", "g_cross_per_g"):
                setattr(self, f.name, _as33(f.name, v, zero_diagonal=f.name == "cross_axis"))
            elif f.name in ("warmup_tau_s", "clock_error", "t_ref_degC", "temp_hysteresis_width_degC"):
                setattr(self, f.name, float(v))
            else:
                setattr(self, f.name, _as3(f.name, v))
        if self.warmup_tau_s <= 0:
            raise InputError(f"warmup_tau_s={self.warmup_tau_s:g} must be > 0 s")
        if not self.temp_hysteresis_width_degC > 0:
            raise InputError(
                f"temp_hysteresis_width_degC={self.temp_hysteresis_width_degC:g} must be > 0 degC"
            )
        if not -0.5 < self.clock_error < 0.5:
            raise InputError(f"clock_error={self.clock_error:g} is not a plausible fraction")

    @classmethod
    def perfect(cls) -> AccelErrors:
        """No errors, no noise."""
        return cls()

    @classmethod
    def datasheet(cls, seed: int = 0) -> AccelErrors:
        """Uniform draws within the PS-MPU-9250A figures: +-3 % scale, +-2 % cross-axis, zero-g
        +-60 mg (x, y) / +-80 mg (z), +-1.5 mg/degC, +-0.026 %/degC; 300 ug/rtHz noise."""
        rng = np.random.default_rng([int(seed), 0xACCE1])
        cross = rng.uniform(-0.02, 0.02, (3, 3))
        np.fill_diagonal(cross, 0.0)
        return cls(
            bias_g=rng.uniform(-1, 1, 3) * np.array([0.060, 0.060, 0.080]),
            scale=rng.uniform(-0.03, 0.03, 3),
            cross_axis=cross,
            temp_bias_g_per_degC=rng.uniform(-1.5e-3, 1.5e-3, 3),
            temp_scale_per_degC=rng.uniform(-2.6e-4, 2.6e-4, 3),
            noise_density_g_per_rtHz=np.full(3, 300e-6),
        )

    def bias_at(self, temp_degC: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """b(T, t) (n,3) in g."""
        dT = (np.asarray(temp_degC, float) - self.t_ref_degC)[:, None]
        t = np.asarray(t_s, float)[:, None]
        b = self.bias_g + self.temp_bias_g_per_degC * dT + self.temp_bias2_g_per_degC2 * dT**2
        b = b + self.time_drift_g_per_s * t
        if np.any(self.warmup_g):
            b = b + self.warmup_g * (1.0 - np.exp(-np.maximum(t, 0.0) / self.warmup_tau_s))
        return b

    def apply(self, f_g: np.ndarray, temp_degC: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """Noise-free reading a' = S u + b (n,3, g) for true specific force f_g (n,3, g)."""
        f = np.asarray(f_g, float)
        u = f
        if np.any(self.nonlin2_per_g) or np.any(self.nonlin3_per_g2):
            u = f + self.nonlin2_per_g * f**2 + self.nonlin3_per_g2 * f**3
        if np.any(self.g_cross_per_g):
            prods = np.stack([f[:, 0] * f[:, 1], f[:, 0] * f[:, 2], f[:, 1] * f[:, 2]], axis=1)
            u = u + prods @ self.g_cross_per_g.T
        dT = (np.asarray(temp_degC, float) - self.t_ref_degC)[:, None]
        diag = 1.0 + self.scale + self.temp_scale_per_degC * dT + self.temp_scale2_per_degC2 * dT**2
        a = diag * u
        if np.any(self.cross_axis):
            a = a + u @ self.cross_axis.T
        return a + self.bias_at(temp_degC, t_s)


@dataclass
class GyroErrors:
    """Gyro error parameters (zero = off): w' = (diag(1 + s) + C) w + b0 + b_T dT + b_T2 dT^2 + n (deg/s)."""

    bias_dps: np.ndarray = field(default_factory=_zeros3)
    scale: np.ndarray = field(default_factory=_zeros3)
    cross_axis: np.ndarray = field(default_factory=_zeros33)
    temp_bias_dps_per_degC: np.ndarray = field(default_factory=_zeros3)
    temp_bias2_dps_per_degC2: np.ndarray = field(default_factory=_zeros3)
    noise_density_dps_per_rtHz: np.ndarray = field(default_factory=_zeros3)
    bias_instability_dps: np.ndarray = field(default_factory=_zeros3)
    """B (deg/s): flicker bias noise, Allan deviation floor 0.664 B."""
    random_walk_dps_per_s_rtHz: np.ndarray = field(default_factory=_zeros3)
    """K (deg/s/s/sqrt(Hz)): rate random walk, AVAR = K^2 tau / 3."""
    t_ref_degC: float = 25.0

    def __post_init__(self) -> None:
        self.bias_instability_dps = _as3("bias_instability_dps", self.bias_instability_dps)
        self.random_walk_dps_per_s_rtHz = _as3("random_walk_dps_per_s_rtHz", self.random_walk_dps_per_s_rtHz)
        self.bias_dps = _as3("bias_dps", self.bias_dps)
        self.scale = _as3("scale", self.scale)
        self.cross_axis = _as33("cross_axis", self.cross_axis, zero_diagonal=True)
        self.temp_bias_dps_per_degC = _as3("temp_bias_dps_per_degC", self.temp_bias_dps_per_degC)
        self.temp_bias2_dps_per_degC2 = _as3("temp_bias2_dps_per_degC2", self.temp_bias2_dps_per_degC2)
        self.noise_density_dps_per_rtHz = _as3("noise_density_dps_per_rtHz", self.noise_density_dps_per_rtHz)
        self.t_ref_degC = float(self.t_ref_degC)

    @classmethod
    def perfect(cls) -> GyroErrors:
        return cls()

    @classmethod
    def datasheet(cls, seed: int = 0) -> GyroErrors:
        """Uniform draws within PS-MPU-9250A Table 1: +-5 dps offset, +-3 % scale, +-2 % cross-axis,
        +-0.24 dps/degC (30 dps over -40..85 degC); 0.01 dps/rtHz noise."""
        rng = np.random.default_rng([int(seed), 0x6E0])
        cross = rng.uniform(-0.02, 0.02, (3, 3))
        np.fill_diagonal(cross, 0.0)
        return cls(
            bias_dps=rng.uniform(-5.0, 5.0, 3),
            scale=rng.uniform(-0.03, 0.03, 3),
            cross_axis=cross,
            temp_bias_dps_per_degC=rng.uniform(-0.24, 0.24, 3),
            noise_density_dps_per_rtHz=np.full(3, 0.01),
        )

    def apply(self, omega_dps: np.ndarray, temp_degC: np.ndarray) -> np.ndarray:
        """Noise-free gyro reading (n,3, deg/s)."""
        w = np.asarray(omega_dps, float)
        dT = (np.asarray(temp_degC, float) - self.t_ref_degC)[:, None]
        out = w * (1.0 + self.scale) + self.bias_dps + self.temp_bias_dps_per_degC * dT
        if np.any(self.temp_bias2_dps_per_degC2):
            out = out + self.temp_bias2_dps_per_degC2 * dT**2
        if np.any(self.cross_axis):
            out = out + w @ self.cross_axis.T
        return out


@dataclass(frozen=True)
class SampleBlock:
    """Raw counts of n consecutive samples, as the chip puts them in its data registers / FIFO."""

    accel_counts: np.ndarray  # (n,3) int16
    temp_counts: np.ndarray  # (n,) int16
    gyro_counts: np.ndarray  # (n,3) int16


# -- index-keyed, DLPF-shaped noise -----------------------------------------------------------------
_NOISE_BLOCK = 4096
_INDEX_OFFSET = 4096  # white-noise index = sample index + offset, so FIR history never goes negative
_STREAM_ACCEL, _STREAM_GYRO, _STREAM_TEMP, _STREAM_MAG = 1, 2, 3, 4


@lru_cache(maxsize=64)
def _dlpf_taps(bandwidth_hz: float, odr_hz: float) -> np.ndarray:
    """Unit-energy FIR taps h[k] ∝ a^k, a = exp(-2 pi f_c / ODR), truncated at a^k < 1e-4."""
    a = float(np.exp(-2.0 * np.pi * bandwidth_hz / odr_hz))
    n = 1 if a < 1e-4 else min(2048, int(np.ceil(np.log(1e-4) / np.log(a))) + 1)
    h = a ** np.arange(n)
    return h / np.sqrt(np.sum(h * h))


class _WhiteNoise:
    """Standard normal white noise w[j, axis] keyed by (seed, stream, j): random access, cached blocks."""

    def __init__(self, seed: int, stream: int, axes: int) -> None:
        self.seed, self.stream, self.axes = int(seed), int(stream), axes
        self._cache: dict[int, np.ndarray] = {}

    def _block(self, b: int) -> np.ndarray:
        blk = self._cache.get(b)
        if blk is None:
            rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([self.seed, self.stream, b])))
            blk = rng.standard_normal((_NOISE_BLOCK, self.axes))
            if len(self._cache) >= 8:
                self._cache.pop(next(iter(self._cache)))
            self._cache[b] = blk
        return blk

    def range(self, j0: int, j1: int) -> np.ndarray:
        """w[j0:j1] (j1 - j0, axes) for white-noise indices j >= 0."""
        b0, b1 = j0 // _NOISE_BLOCK, (j1 - 1) // _NOISE_BLOCK
        if b0 == b1:
            o = j0 - b0 * _NOISE_BLOCK
            return self._block(b0)[o : o + (j1 - j0)]
        parts = np.concatenate([self._block(b) for b in range(b0, b1 + 1)])
        o = j0 - b0 * _NOISE_BLOCK
        return parts[o : o + (j1 - j0)]

    def filtered(self, index: np.ndarray, taps: np.ndarray) -> np.ndarray:
        """Unit-variance low-pass noise at sample indices (n,) >= 0 (any order, gaps allowed)."""
        idx = np.asarray(index, np.int64) + _INDEX_OFFSET
        if idx.size == 0:
            return np.zeros((0, self.axes))
        lo, hi = int(idx.min()), int(idx.max()) + 1
        L = taps.size
        if L == 1:
            w = self.range(lo, hi)
            return w[idx - lo] * taps[0]
        w = self.range(lo - L + 1, hi)
        out = np.empty((hi - lo, self.axes))
        for ax in range(self.axes):  # 3 axes: one vectorised convolution each
            out[:, ax] = np.convolve(w[:, ax], taps, mode="valid")
        return out[idx - lo]


class SensorModel:
    """Turns a Motion into raw MPU-9250 / AK8963 counts with the error parameters above.

    local_gravity_mps2: gravity at the (simulated) site; the motion's own gravity term is replaced
    by it (f += R^T (0, 0, (g_local - g_motion) / g0)). mag_field_uT: Earth field in the world frame
    (x, y horizontal, z up). mag_hard_iron_uT: offset in AK8963 axes. mag_asa: fuse-ROM sensitivity
    adjustment bytes. Times are seconds since the session (motion) start; the motion is held at its
    ends outside [0, duration_s].
    """

    def __init__(
        self,
        motion: Motion,
        accel: AccelErrors | None = None,
        gyro: GyroErrors | None = None,
        temperature=None,
        seed: int = 0,
        local_gravity_mps2: float = STANDARD_GRAVITY_MPS2,
        mag_field_uT: tuple[float, float, float] = (20.0, 0.0, -45.0),
        mag_hard_iron_uT: tuple[float, float, float] = (0.0, 0.0, 0.0),
        mag_soft_iron=None,
        mag_asa: tuple[int, int, int] = (176, 178, 167),
        mag_noise_uT: float = 0.3,
        temp_noise_degC: float = 0.01,
    ) -> None:

        self.motion = motion
        self.accel = accel if accel is not None else AccelErrors.perfect()
        self.gyro = gyro if gyro is not None else GyroErrors.perfect()
        self.temperature = temperature if temperature is not None else TemperaturePath.constant(25.0)
        self.seed = int(seed)
        self.local_gravity_mps2 = float(local_gravity_mps2)
        self._gravity_fix_g = (
            self.local_gravity_mps2 - float(getattr(motion, "local_gravity_mps2", STANDARD_GRAVITY_MPS2))
        ) / STANDARD_GRAVITY_MPS2
        self.mag_field_uT = _as3("mag_field_uT", mag_field_uT)
        self.mag_hard_iron_uT = _as3("mag_hard_iron_uT", mag_hard_iron_uT)
        self.mag_soft_iron = np.eye(3) if mag_soft_iron is None else _as33("mag_soft_iron", mag_soft_iron)
        asa = np.asarray(mag_asa, int)
        if asa.shape != (3,) or np.any((asa < 0) | (asa > 255)):
            raise InputError("mag_asa must be 3 bytes (0..255)")
        self.mag_asa = tuple(int(v) for v in asa)
        self.mag_noise_uT = float(mag_noise_uT)
        self.temp_noise_degC = float(temp_noise_degC)
        self._noise = {
            s: _WhiteNoise(self.seed, s, 1 if s == _STREAM_TEMP else 3)
            for s in (_STREAM_ACCEL, _STREAM_GYRO, _STREAM_TEMP, _STREAM_MAG)
        }
        self._slow: dict[tuple[int, float], MarkovBank | None] = {}

    def _slow_bias(self, stream: int, odr_hz: float, index: np.ndarray) -> np.ndarray | None:
        """Bias instability + random walk of the accel or gyro at sample indices (None if both off)."""
        from accellog.acquire.emulator.slow_noise import slow_bias

        key = (stream, float(odr_hz))
        if key not in self._slow:
            if stream == _STREAM_ACCEL:
                B, K = self.accel.bias_instability_g, self.accel.random_walk_g_per_s_rtHz
            else:
                B, K = self.gyro.bias_instability_dps, self.gyro.random_walk_dps_per_s_rtHz
            self._slow[key] = slow_bias(self.seed, stream, odr_hz, B, K)
        bank = self._slow[key]
        return None if bank is None else bank.at(np.maximum(index, 0))

    @property
    def clock_error(self) -> float:
        """eps of the chip's sample clock (period (1 + eps) / ODR)."""
        return self.accel.clock_error

    @property
    def mag_asa_factor(self) -> np.ndarray:
        """(ASA - 128) * 0.5 / 128 + 1 per AK8963 axis."""
        return (np.asarray(self.mag_asa, float) - 128.0) * 0.5 / 128.0 + 1.0

    # -- truth --------------------------------------------------------------------------------------
    def _kin(self, t_s: np.ndarray) -> Kinematics:
        t = np.clip(np.asarray(t_s, float).reshape(-1), 0.0, self.motion.duration_s)
        k = self.motion.kinematics(t)
        if self._gravity_fix_g != 0.0:
            k.specific_force_g = k.specific_force_g + rotate_inverse(
                k.q_sensor_to_world, np.array([0.0, 0.0, self._gravity_fix_g])
            )
        return k

    def truth(self, t_s: np.ndarray) -> Truth:
        """Exact specific force, rate, pose and die temperature at times t_s (s)."""
        t = np.asarray(t_s, float).reshape(-1)
        k = self._kin(t)
        return Truth(
            t_s=t,
            specific_force_g=k.specific_force_g,
            omega_dps=k.omega_dps,
            position_m=k.position_m,
            velocity_mps=k.velocity_mps,
            q_sensor_to_world=k.q_sensor_to_world,
            temp_degC=self.temperature.degC(t),
        )

    # -- readings -----------------------------------------------------------------------------------
    def sample(
        self,
        t_s: np.ndarray,
        *,
        accel_lsb_per_g: float,
        gyro_lsb_per_dps: float,
        odr_hz: float,
        accel_bandwidth_hz: float,
        gyro_bandwidth_hz: float,
        index: np.ndarray | None = None,
    ) -> SampleBlock:
        """Raw counts at true times t_s (s) for sample indices ``index`` (default round(t ODR / (1+eps))).

        The noise of sample j depends only on (seed, j, bandwidth, ODR), so any split of a stream
        into calls gives identical counts.
        """
        t = np.asarray(t_s, float).reshape(-1)
        if index is None:
            index = np.round(t * odr_hz / (1.0 + self.clock_error)).astype(np.int64)
        idx = np.asarray(index, np.int64).reshape(-1)
        k = self._kin(t)
        T = self.temperature.degC(t)
        a = self.accel.apply(k.specific_force_g, T, t)
        if np.any(self.accel.temp_rate_bias_g_per_degC_per_s) or np.any(self.accel.temp_hysteresis_g):
            a = a + self._path_bias(t)
        dens_a = self.accel.noise_density_g_per_rtHz
        if np.any(dens_a):
            sigma = dens_a * np.sqrt(0.5 * np.pi * accel_bandwidth_hz)
            a = a + sigma * self._noise[_STREAM_ACCEL].filtered(idx, _dlpf_taps(accel_bandwidth_hz, odr_hz))
        slow = self._slow_bias(_STREAM_ACCEL, odr_hz, idx)
        if slow is not None:
            a = a + slow
        w = self.gyro.apply(k.omega_dps, T)
        dens_g = self.gyro.noise_density_dps_per_rtHz
        if np.any(dens_g):
            sigma = dens_g * np.sqrt(0.5 * np.pi * gyro_bandwidth_hz)
            w = w + sigma * self._noise[_STREAM_GYRO].filtered(idx, _dlpf_taps(gyro_bandwidth_hz, odr_hz))
        slow = self._slow_bias(_STREAM_GYRO, odr_hz, idx)
        if slow is not None:
            w = w + slow
        temp = (T - TEMP_OFFSET_DEGC) * TEMP_LSB_PER_DEGC
        if self.temp_noise_degC > 0:
            temp = (
                temp
                + (self.temp_noise_degC * TEMP_LSB_PER_DEGC)
                * self._noise[_STREAM_TEMP].filtered(idx, np.ones(1))[:, 0]
            )
        return SampleBlock(
            accel_counts=_to_int16(a * accel_lsb_per_g),
            temp_counts=_to_int16(temp),
            gyro_counts=_to_int16(w * gyro_lsb_per_dps),
        )

    def _path_bias(self, t: np.ndarray) -> np.ndarray:
        """Bias terms that need the temperature's history (n,3) g: r dT/dt + h s(t) (AccelErrors)."""
        e, path = self.accel, self.temperature
        rate = path.rate_degC_per_s(t)[:, None]
        play = path.play_degC(t, e.temp_hysteresis_width_degC, self.motion.duration_s)
        s = (play - path.degC(t)) / (0.5 * e.temp_hysteresis_width_degC)
        return e.temp_rate_bias_g_per_degC_per_s * rate + e.temp_hysteresis_g * s[:, None]

    def mag_field_sensor_uT(self, t_s: np.ndarray) -> np.ndarray:
        """Noise-free field (n,3, uT) in AK8963 axes (x_m = y_s, y_m = x_s, z_m = -z_s), soft and hard iron."""
        k = self._kin(t_s)
        b = rotate_inverse(k.q_sensor_to_world, np.broadcast_to(self.mag_field_uT, (k.t_s.size, 3)))
        return np.stack([b[:, 1], b[:, 0], -b[:, 2]], axis=1) @ self.mag_soft_iron.T + self.mag_hard_iron_uT

    def mag_sample(
        self, t_s: np.ndarray, index: np.ndarray, *, bits16: bool = True
    ) -> tuple[np.ndarray, np.ndarray]:
        """AK8963 raw counts (n,3, int16, before ASA) and HOFL flags (n,) at times t_s for measurement
        indices ``index``: counts = round(H / (ut_per_lsb * asa_factor))."""
        h = self.mag_field_sensor_uT(t_s)
        if self.mag_noise_uT > 0:
            h = h + self.mag_noise_uT * self._noise[_STREAM_MAG].filtered(np.asarray(index), np.ones(1))
        hofl = np.sum(np.abs(h), axis=1) >= 4912.0
        lsb = MAG_UT_PER_LSB_16BIT if bits16 else MAG_UT_PER_LSB_14BIT
        limit = 32760 if bits16 else 8190
        counts = np.clip(np.round(h / (lsb * self.mag_asa_factor)), -limit, limit).astype(np.int16)
        return counts, hofl


def _to_int16(x: np.ndarray) -> np.ndarray:
    """clip(round(x), -32768, 32767) as int16 (saturation like the chip's ADC output)."""
    return np.clip(np.rint(x), -32768, 32767).astype(np.int16)
