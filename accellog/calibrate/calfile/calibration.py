"""Calibration: a fitted error model in a JSON file, and its application to readings.

A calibration inverts the measurement equation of its model (accellog.calibrate.model.compose):

    reading a' (g) = predict(theta, f, drivers)   ->   f = correct(theta, a', drivers)   (g)

and states the gravity convention of the fit: the true specific force of a static pose was
truth_g * up (truth_g = 1 for the seed's convention, i.e. the output unit is one *local* g;
truth_g = g_local / g0 for standard g). Integration then uses

    a (m/s^2) = f * mps2_per_unit,   mps2_per_unit = local_gravity_mps2 / truth_g.

File format ('accellog.calibration', format_version 1): units, model spec (terms), parameters with
values, 1-sigma and units, covariance, S and b at reference conditions, gravity convention,
temperature at calibration, fit statistics, source files with SHA-256, the device key of the sensor
(accellog.core.device; absent in older files = unknown), software version, an optional
displacement-drift model (accellog.navigate.drift), and optional versioned sections `noise`
(accellog.calibrate.noise.noise_model) and `magnetometer` (accellog.calibrate.mag.magnetometer).

Every section is typed: `temperature`, `fit`, `sensor`, `device` and the `sources` entries are
accellog.calibrate.calfile.sections types (TemperatureInfo, FitInfo, SensorInfo, DeviceInfo, SourceFile),
`noise` an accellog.calibrate.calfile.noise_section.NoiseSection, `gyro` a GyroCalibration, `magnetometer` a
MagCalibration. A file read and saved again is the same text (keys a section lacked stay absent, keys
this version does not know are kept).
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import functools
import hashlib
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from accellog.calibrate.calfile.drift_model import DriftModel
from accellog.calibrate.calfile.noise_section import NoiseSection
from accellog.calibrate.calfile.schema import check_document, check_S, check_values
from accellog.calibrate.calfile.sections import (
    DetectedInterval,
    DeviceInfo,
    FitInfo,
    SensorInfo,
    SourceFile,
    TemperatureInfo,
    gyro_from_dict,
    mag_from_dict,
    object_section,
)
from accellog.calibrate.gyro.model import GyroCalibration
from accellog.calibrate.mag.magnetometer import MagCalibration
from accellog.calibrate.model.compose import model_from_spec
from accellog.calibrate.model.effects import LIBRARY
from accellog.calibrate.model.session_drivers import session_drivers
from accellog.core import textin
from accellog.core.device import DeviceKey
from accellog.core.errors import InputError, ModelError
from accellog.core.jsonio import JsonResult, dumps
from accellog.core.reprs import fit_text, param_table_html, short_repr
from accellog.core.session import ObsTable, Session
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.core.version import __version__
from accellog.store.atomic import write_text_atomic

if TYPE_CHECKING:
    from accellog.store.source import Source

FORMAT = "accellog.calibration"
FORMAT_VERSION = 1
UNITS = {"accel_in": "g", "accel_out": "g (see gravity.truth_g)", "time": "s", "temperature": "degC"}


def sha256_file(path: str | os.PathLike) -> str | None:
    """Hex SHA-256 of a file, or None if it cannot be read."""
    try:
        h = hashlib.sha256()
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        return h.hexdigest()
    except OSError:
        return None


def source_entry(path: str | None, kind: str = "") -> SourceFile:
    """Path, SHA-256 (None when unreadable) and kind of an input file."""
    return SourceFile(path=path, sha256=sha256_file(path) if path else None, kind=kind)


GRAVITY_CONVENTIONS = ("seed", "local")
"""'seed': truth = +-1 per pose (unit = one local g; the capstone study); 'local': truth =
g_local / g0 in standard g (the physical convention)."""


def convention_truth_g(gravity: str, local_gravity_mps2: float) -> float:
    """The fit's truth |f| (g) under a gravity convention (GRAVITY_CONVENTIONS)."""
    if gravity not in GRAVITY_CONVENTIONS:
        raise InputError(f"unknown gravity convention {gravity!r}: use 'seed' or 'local'")
    return 1.0 if gravity == "seed" else local_gravity_mps2 / STANDARD_GRAVITY_MPS2


def source_provenance(src: Source | None, table: ObsTable | None) -> SourceFile:
    """The provenance entry of a fit's input: its session file (hashed), or the observation
    table's session file when no session was read; a recovered (truncated) session says what was
    kept (store.source.recovery_info)."""
    from accellog.store.source import recovery_info

    if src is None:
        p = table.session if table is not None else None
        return source_entry(p if p and Path(p).is_file() else None, "")
    path = str(src.path) if src.path is not None else src.session.path if src.session is not None else None
    entry = source_entry(path if path and Path(path).is_file() else None, src.meta.source)
    info = recovery_info(src.session) if src.session is not None else None
    if info is not None:
        entry = dataclasses.replace(entry, recovered=info.to_dict())
    return entry


@dataclass
class Calibration(JsonResult):
    """A fitted accelerometer calibration (see module docstring for the conventions)."""

    model_spec: dict
    param_names: list[str]
    param_units: list[str]
    theta: np.ndarray
    cov: np.ndarray
    truth_g: float = 1.0
    gravity_convention: str = "seed"
    local_gravity_mps2: float = STANDARD_GRAVITY_MPS2
    temperature: TemperatureInfo = field(default_factory=TemperatureInfo.empty)
    """Reference and observed temperatures (degC)."""
    fit: FitInfo = field(default_factory=FitInfo.empty)
    """Statistics of the fit (chi2/dof, residual RMS, warnings, detected intervals)."""
    sources: list[SourceFile] = field(default_factory=list)
    """The input files (path, SHA-256, kind)."""
    sensor: SensorInfo = field(default_factory=SensorInfo.empty)
    """Accelerometer set-up of the calibrated session (chip, range, sensitivity)."""
    software: str = f"accellog {__version__}"
    created_utc: str = ""
    drift: DriftModel | None = None
    device: DeviceInfo = field(default_factory=DeviceInfo.empty)
    """Device key of the calibrated sensor (DeviceInfo.key); empty = unknown."""
    gyro: GyroCalibration | None = None
    """Gyro calibration, when the session allowed it."""
    noise: NoiseSection | None = None
    """Noise terms (accellog.calibrate.calfile.noise_section), when `accellog noise --cal` added them."""
    magnetometer: MagCalibration | None = None
    """Magnetometer hard/soft iron, when `accellog magcal --cal` added them."""
    path: str | None = None
    gyro_source: dict | None = field(default=None, repr=False, compare=False)
    """The `gyro` section as read from the file (written back unchanged while `gyro` equals it)."""
    magnetometer_source: dict | None = field(default=None, repr=False, compare=False)
    """The `magnetometer` section as read (as gyro_source)."""
    effects_file: Any = field(default=None, repr=False, compare=False)
    """The user's effects (an EffectsFile, or the path the user named with --effects-file) for a
    model with user effects; never taken from the file itself (a data file carries no code)."""
    stored_S_b: tuple | None = field(default=None, repr=False, compare=False)
    """S and b_g as read from the file (written back when the model needs code not given)."""

    def __post_init__(self) -> None:
        # sections given as their JSON dicts (older callers) become the typed sections
        for name, cls in (
            ("temperature", TemperatureInfo),
            ("fit", FitInfo),
            ("sensor", SensorInfo),
            ("device", DeviceInfo),
        ):
            if isinstance(getattr(self, name), Mapping):
                setattr(self, name, cls.from_dict(getattr(self, name)))
        self.sources = [SourceFile.from_dict(x) if isinstance(x, Mapping) else x for x in self.sources]
        if isinstance(self.gyro, Mapping):
            self.gyro, self.gyro_source = gyro_from_dict(self.gyro), dict(self.gyro)
        if isinstance(self.noise, Mapping):
            self.noise = NoiseSection.from_dict(self.noise)
        if isinstance(self.magnetometer, Mapping):
            self.magnetometer_source = dict(self.magnetometer)
            self.magnetometer = mag_from_dict(self.magnetometer)

    # ------------------------------------------------------------------ derived
    @property
    def sigma(self) -> np.ndarray:
        """1-sigma of each parameter (sqrt of the covariance diagonal)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    @property
    def mps2_per_unit(self) -> float:
        """m/s^2 per unit of the calibrated output: local_gravity_mps2 / truth_g."""
        return self.local_gravity_mps2 / self.truth_g

    @functools.cached_property
    def model(self):
        """The accellog.calibrate.model.compose.Model of this calibration, built from the spec once (a user effects
        file is imported and its SHA-256 checked on first use, not on every correct())."""

        try:
            return model_from_spec(self.model_spec, self.effects_file)
        except ModelError as exc:
            if self.path is None or exc.where is not None:
                raise
            raise ModelError(str(exc), where=self.path) from None

    @property
    def terms(self) -> list[str]:
        return list(self.model_spec.get("terms", []))

    def __repr__(self) -> str:
        name, f = self.model_spec.get("name", "+".join(self.terms)), self.fit
        sections = "+".join(
            n for n, x in (("gyro", self.gyro), ("noise", self.noise), ("mag", self.magnetometer)) if x
        )
        return short_repr(
            "Calibration",
            [
                fit_text(name, len(self.param_names), f.chi2_dof, f.rms_g),
                sections and f"with {sections}",
                f"device {self.device.key.id}" if self.device.key.known else None,
                self.path,
            ],
        )

    def _repr_html_(self) -> str:
        stats = fit_text(self.model_spec.get("name", "+".join(self.terms)), len(self.param_names), None, None)
        return param_table_html(
            f"calibration {stats}", self.param_names, self.param_units, self.theta, self.sigma
        )

    def device_conflicts(self, key: DeviceKey) -> list[str]:
        """How `key` (a session's device) differs from the calibrated device; [] when they match
        or either is unknown (see DeviceKey.conflicts)."""
        return self.device.key.conflicts(key)

    def S_b(self) -> tuple[np.ndarray, np.ndarray]:
        """Linear part at reference conditions: S (3,3), b (3,) g (as stored in the file when its
        model needs a user effects file that was not given)."""
        if self.stored_S_b is not None and self.needs_user_code:
            return self.stored_S_b
        return self.model.S_b(self.theta)

    def with_effects(self, add: Sequence[str]) -> Calibration:
        """This calibration with more effects, as the prior of a fit that adds them (`fit RUN --prior
        LAB.json --add temp_bias`: a lab calibration at one temperature updated by a warm-up's
        stops): the added parameters at their initial values (0; S_ii 1) with 1-sigma = the effect's
        typical size (temp_bias: 1.5 mg/degC, the datasheet tempco), uncorrelated; the rest as here."""
        m = self.model.with_terms(add)
        if m.term_names == self.model.term_names:
            return self
        theta, cov = m.initial_theta(), np.diag(m.param_typical**2)
        old = [m.index[n] for n in self.param_names]
        theta[old] = self.theta
        cov[np.ix_(old, old)] = self.cov
        return replace(self, model_spec=m.to_spec(), param_names=list(m.param_names),
                       param_units=list(m.param_units), theta=theta, cov=cov, stored_S_b=None)  # fmt: skip

    @property
    def needs_user_code(self) -> bool:
        """True when the model has user effects and no effects file was given to run them."""
        return self.effects_file is None and any(t not in LIBRARY for t in self.terms)

    # ------------------------------------------------------------------ apply
    def correct(
        self, data: Session | np.ndarray, drivers: Mapping[str, np.ndarray] | None = None
    ) -> np.ndarray:
        """Calibrated specific force f (n,3) in calibrated units (see truth_g) from a Session or a
        reading array (n,3) g; arrays need `drivers` for models with temperature/time terms."""
        model = self.model
        if isinstance(data, Session):
            meas = data.accel_g
            drv = dict(session_drivers(data, model.required_drivers))
            if drivers:
                drv.update(drivers)
        else:
            meas = np.atleast_2d(np.asarray(data, float))
            drv = dict(drivers or {})
        if meas.ndim != 2 or meas.shape[1] != 3:
            raise InputError(f"readings must be (n,3) g, got shape {meas.shape}")
        return model.correct(self.theta, meas, drv)

    def correct_mps2(
        self, data: Session | np.ndarray, drivers: Mapping[str, np.ndarray] | None = None
    ) -> np.ndarray:
        """Calibrated specific force in m/s^2 (correct() * mps2_per_unit)."""
        return self.correct(data, drivers) * self.mps2_per_unit

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_fit(
        cls,
        fit: Any,
        *,
        obs: ObsTable | None = None,
        gravity_convention: str = "seed",
        local_gravity_mps2: float = STANDARD_GRAVITY_MPS2,
        sources: list[SourceFile] | None = None,
        sensor: SensorInfo | Mapping | None = None,
    ) -> Calibration:
        """From an accellog.calibrate.model.fit.FitResult (truth_g = fit.gravity_g)."""
        temp = TemperatureInfo(t_ref_degC=fit.model.t_ref_degC)
        if obs is not None and obs.temp_degC is not None and np.isfinite(obs.temp_degC).all():
            temp = TemperatureInfo(
                t_ref_degC=fit.model.t_ref_degC,
                mean_degC=float(np.mean(obs.temp_degC)),
                min_degC=float(np.min(obs.temp_degC)),
                max_degC=float(np.max(obs.temp_degC)),
            )
        return cls(
            effects_file=fit.model.effects_file,
            model_spec=fit.model.to_spec(),
            param_names=list(fit.param_names),
            param_units=list(fit.param_units),
            theta=np.asarray(fit.theta, float).copy(),
            cov=np.asarray(fit.cov, float).copy(),
            truth_g=float(fit.gravity_g),
            gravity_convention=gravity_convention,
            local_gravity_mps2=float(local_gravity_mps2),
            temperature=temp,
            fit=FitInfo.from_result(fit),
            sources=list(sources or []),
            sensor=sensor if isinstance(sensor, SensorInfo) else SensorInfo.from_dict(sensor or {}),
            created_utc=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        )

    @classmethod
    def from_session_fit(
        cls,
        fit: Any,
        obs: ObsTable,
        src: Source | None,
        *,
        gravity_convention: str,
        local_gravity_mps2: float,
        detected: list | None = None,
    ) -> Calibration:
        """from_fit with the session's sensor, device and provenance (source_provenance), and the
        static intervals the fit used when they were detected (hand-held: PoseLabels of src)."""
        cal = cls.from_fit(
            fit,
            obs=obs,
            gravity_convention=gravity_convention,
            local_gravity_mps2=local_gravity_mps2,
            sources=[source_provenance(src, obs)],
            sensor=SensorInfo.empty() if src is None else SensorInfo.from_meta(src.meta),
        )
        if src is not None:
            cal.device = DeviceInfo.from_key(src.meta.device)
        if detected and src is not None and src.session is not None:
            intervals = DetectedInterval.of_labels(detected, src.session.t_s)
            cal.fit = dataclasses.replace(cal.fit, detected_intervals=intervals)
        return cal

    # ------------------------------------------------------------------ file
    def to_dict(self) -> dict:
        mag = object_section(self.magnetometer, self.magnetometer_source, MagCalibration.from_dict)
        S, b = self.S_b()
        sig = self.sigma
        return {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "software": self.software,
            "created_utc": self.created_utc,
            "units": dict(UNITS),
            "equation": "a' = S u + b (+ model terms); calibrated f = model.correct(theta, a')",
            "model": dict(self.model_spec),
            "params": [
                {"name": n, "value": float(v), "sigma": float(s), "unit": u}
                for n, v, s, u in zip(self.param_names, self.theta, sig, self.param_units, strict=True)
            ],
            "covariance": np.asarray(self.cov, float).tolist(),
            "S": S.tolist(),
            "b_g": b.tolist(),
            "gravity": {
                "convention": self.gravity_convention,
                "truth_g": self.truth_g,
                "local_gravity_mps2": self.local_gravity_mps2,
                "mps2_per_unit": self.mps2_per_unit,
            },
            "temperature": self.temperature.to_dict(),
            "fit": self.fit.to_dict(),
            "sensor": self.sensor.to_dict(),
            "device": self.device.to_dict(),
            "sources": [x.to_dict() for x in self.sources],
            "drift": self.drift.to_dict() if self.drift is not None else None,
            "gyro": object_section(self.gyro, self.gyro_source, GyroCalibration.from_dict),
            **({"noise": self.noise.to_dict()} if self.noise is not None else {}),
            **({"magnetometer": mag} if mag is not None else {}),
        }

    def save(self, path: str | os.PathLike, *, inputs: tuple = ()) -> None:
        """Write the JSON file atomically (accellog.store.atomic); refused when `path` is one of the
        source files, this calibration's own file or `inputs`. What would be written is first
        checked by the reader's own validation (calibration_from_dict): no file no loader reads."""
        srcs = [x.path for x in self.sources]
        d = self.to_dict()
        calibration_from_dict(textin.parse_json(dumps(d), str(path)), str(path), self.effects_file)
        write_json_atomic(path, d, inputs=(*srcs, self.path, *inputs))
        self.path = str(path)


def write_json_atomic(path: str | os.PathLike, data: Any, *, inputs: tuple = ()) -> None:
    """Write JSON atomically (accellog.store.atomic: lock, temp file, fsync, rename); the folder
    is created when missing; an output that is one of `inputs` is refused."""
    write_text_atomic(path, dumps(data) + "\n", inputs=inputs, mkdir=True)


def read_text(path: str | os.PathLike, what: str = "file", kind: str | None = None) -> str:
    """The text of a file, or InputError naming it when it is missing, not text or (with `kind`,
    'JSON' or 'TOML') over its size limit (accellog.core.textin)."""
    return textin.read_text(path, what, kind)


def read_json(path: str | os.PathLike, what: str = "file") -> Any:
    """Parsed strict JSON of at most 32 MiB, nested <= 64 levels, or InputError naming the file
    (and line) when missing, too large or malformed (accellog.core.textin)."""
    return textin.read_json(path, what)


def calibration_from_dict(d: Any, where: str | None = None, effects_file: Any = None) -> Calibration:
    """Validate and build a Calibration from its JSON dict (InputError on a bad or foreign file).
    User effects run only from `effects_file` (see load_calibration)."""
    if not isinstance(d, dict):
        raise InputError("not an accellog calibration file (top level is not an object)", where=where)
    if d.get("format") != FORMAT:
        if "cal_type" in d and "K_a" in d:
            raise InputError(
                f"this is an imucal calibration (cal_type {d.get('cal_type')!r}), not an accellog calibration: "
                "fit one with `accellog fit`",
                where=where,
            )
        other = textin.json_kind(d)
        if other is not None:
            raise InputError(f"this is {other}, not a calibration: are the arguments swapped?", where=where)
        keys = ", ".join(sorted(d)[:6])
        raise InputError(
            f"not an accellog calibration file (no format '{FORMAT}'; keys: {keys})", where=where
        )
    ver = d.get("format_version")
    if not isinstance(ver, int) or ver > FORMAT_VERSION or ver < 1:
        raise InputError(
            f"calibration format_version {ver!r} is not supported (this accellog reads <= {FORMAT_VERSION})",
            where=where,
        )
    check_document(d, where)
    try:
        params = d["params"]
        names = [str(p["name"]) for p in params]
        units = [str(p["unit"]) for p in params]
        theta = np.array([float(p["value"]) for p in params])
        cov = np.asarray(d["covariance"], float)
        grav = d["gravity"]
        spec = d["model"]
        truth_g = float(grav["truth_g"])
        lg = float(grav["local_gravity_mps2"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(
            f"calibration file is missing or has a malformed field: {exc}", where=where
        ) from None
    if not (truth_g > 0 and lg > 0):
        raise InputError(f"gravity truth_g {truth_g} and local_gravity_mps2 {lg} must be > 0", where=where)
    check_values(names, theta, cov, truth_g=truth_g, local_gravity_mps2=lg, where=where)
    cal = Calibration(
        model_spec=dict(spec),
        param_names=names,
        param_units=units,
        theta=theta,
        cov=cov,
        truth_g=truth_g,
        gravity_convention=str(grav.get("convention", "")),
        local_gravity_mps2=lg,
        temperature=TemperatureInfo.from_dict(d.get("temperature"), where),
        fit=FitInfo.from_dict(d.get("fit"), where),
        sources=SourceFile.list_from_json(d.get("sources"), where),
        sensor=SensorInfo.from_dict(d.get("sensor"), where),
        device=DeviceInfo.from_dict(d.get("device"), where),
        software=str(d.get("software", "")),
        created_utc=str(d.get("created_utc", "")),
        drift=DriftModel.from_dict(d["drift"], where=where) if d.get("drift") else None,
        gyro=gyro_from_dict(d.get("gyro"), where),
        gyro_source=d.get("gyro") or None,
        noise=None if d.get("noise") is None else NoiseSection.from_dict(d["noise"], where),
        magnetometer=mag_from_dict(d.get("magnetometer"), where),
        magnetometer_source=d.get("magnetometer"),
        effects_file=effects_file,
    )
    if cal.needs_user_code:
        cal.stored_S_b = _stored_S_b(d, where)
        check_S(cal.stored_S_b[0], where)
        return cal
    try:
        model = cal.model
    except ModelError as exc:
        raise InputError(f"calibration model cannot be rebuilt: {exc}", where=where) from None
    if model.param_names != names:
        raise InputError(
            f"parameter names {names} do not match model {model.name!r} ({model.param_names})", where=where
        )
    check_S(model.S_b(theta)[0], where)
    return cal


def _stored_S_b(d: dict, where: str | None) -> tuple[np.ndarray, np.ndarray]:
    """S and b_g as stored, for a model with user effects whose code was not given (the schema
    checked that the model records their file and its hash)."""
    try:
        S, b = np.asarray(d["S"], float), np.asarray(d["b_g"], float)
    except (KeyError, TypeError, ValueError):
        raise InputError("calibration file has no valid 'S' / 'b_g'", where=where) from None
    if S.shape != (3, 3) or b.shape != (3,) or not (np.isfinite(S).all() and np.isfinite(b).all()):
        raise InputError("calibration 'S' must be 3x3 and 'b_g' 3 finite numbers", where=where)
    return S, b


def load_calibration(path: str | os.PathLike, effects_file: Any = None) -> Calibration:
    """Read a calibration JSON file; one-line InputError on missing, malformed or foreign files.

    A model with user effects is rebuilt only from `effects_file`, the Python file the user named
    (--effects-file), hash-checked before it runs; nothing named inside the calibration is ever
    imported. Without it the calibration still loads and keeps its stored S and b_g, and
    `cal.model` (anything that applies it) raises one ModelError saying what to pass."""
    cal = calibration_from_dict(
        read_json(path, "calibration file"), where=str(path), effects_file=effects_file
    )
    cal.path = str(path)
    return cal


def as_calibration(x: Calibration | str | os.PathLike, effects_file: Any = None) -> Calibration:
    """A Calibration as given, or loaded from its file (with the user's effects file, if any)."""
    return x if isinstance(x, Calibration) else load_calibration(x, effects_file)
