"""Typed sections of the calibration file: `temperature`, `fit`, `sensor`, `device`, the entries of
`sources` (and the round trip of `gyro` and `magnetometer`).

Each section is a frozen dataclass with units in its field names. The JSON form is an interface
(accellog.calibrate.calfile.calibration), so a section read from a file and written again is the same
text, byte for byte:

- ``from_dict`` reads what every accellog version wrote; a key an older version did not write
  is None and stays absent when the section is written back;
- keys are written in the order they were read; a section built by this version (``source_keys``
  None) writes its keys in field order, optional ones (``optional`` in the field metadata) only
  when set;
- keys this version does not know are kept in ``extra`` and written back unchanged;
- values keep their JSON type (an int stays an int), lists become tuples in the typed form.

The gyro section is accellog.calibrate.gyro.calibrate.GyroCalibration, the magnetometer section
accellog.calibrate.mag.magnetometer.MagCalibration; ``object_section`` gives them the same round trip
(the section as read is written back while the object is unchanged; unknown keys are kept otherwise).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

import numpy as np

from accellog.calibrate.gyro.model import GyroCalibration
from accellog.calibrate.mag.magnetometer import MagCalibration
from accellog.core.device import DeviceKey
from accellog.core.errors import InputError
from accellog.core.jsonio import dumps


def json_field(kind: Any, *, optional: bool = False) -> Any:
    """A typed section field of JSON `kind`: 'num', 'int', 'bool', 'str', 'nums', 'strs' (lists),
    'nummap', 'strmap' (objects of numbers / strings), 'obj' (any object, kept as read), a Section class (a nested object), or
    ('list', Section class) / ('map', Section class) (a list / an object of them)."""
    return field(default=None, metadata={"kind": kind, "optional": optional})


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


_CHECKS = {
    "num": ("a number", _is_num),
    "int": ("an integer", lambda x: _is_num(x) and float(x).is_integer()),
    "bool": ("true or false", lambda x: isinstance(x, bool)),
    "str": ("a string", lambda x: isinstance(x, str)),
    "nums": ("a list of numbers", lambda x: isinstance(x, list) and all(e is None or _is_num(e) for e in x)),
    "strs": ("a list of strings", lambda x: isinstance(x, list) and all(isinstance(e, str) for e in x)),
    "nummap": (
        "an object of numbers",
        lambda x: isinstance(x, dict) and all(e is None or _is_num(e) for e in x.values()),
    ),
    "obj": ("an object", lambda x: isinstance(x, dict)),
    "strmap": (
        "an object of strings",
        lambda x: isinstance(x, dict) and all(isinstance(e, str) for e in x.values()),
    ),
}


def _read(kind: Any, v: Any, name: str, where: str | None) -> Any:
    """The typed value of JSON value `v` (None stays None); InputError naming `name` when malformed."""
    if v is None:
        return None
    if isinstance(kind, type) and issubclass(kind, Section):  # a nested section
        return kind.from_dict(v, where, name=name)
    if isinstance(kind, tuple):
        form, cls = kind
        if form == "list":
            if not isinstance(v, list):
                raise InputError(f"calibration field {name} is not a list", where=where)
            return tuple(cls.from_dict(e, where, name=f"{name}[{i}]") for i, e in enumerate(v))
        if not isinstance(v, dict):
            raise InputError(f"calibration field {name} is not an object", where=where)
        return {k: cls.from_dict(e, where, name=f"{name}.{k}") for k, e in v.items()}
    what, ok = _CHECKS[kind]
    if not ok(v):
        raise InputError(f"calibration field {name} = {str(v)[:40]!r} is not {what}", where=where)
    if isinstance(v, list):
        return tuple(v)
    return copy.deepcopy(v) if isinstance(v, dict) else v


def _write(v: Any) -> Any:
    """JSON form of a typed value (sections -> objects, tuples -> lists)."""
    if isinstance(v, Section):
        return v.to_dict()
    if isinstance(v, tuple):
        return [_write(e) for e in v]
    if isinstance(v, Mapping):
        return {k: _write(e) for k, e in v.items()}
    return v


@dataclass(frozen=True)
class Section:
    """Base of a typed section: fields declared with `json_field`, unknown keys and key order kept."""

    NAME: ClassVar[str] = "section"

    extra: Mapping[str, Any] = field(default_factory=dict, kw_only=True)
    """Keys this version does not know, as read (written back unchanged)."""
    source_keys: tuple[str, ...] | None = field(default=None, kw_only=True, repr=False, compare=False)
    """Keys of the section as read, in file order (None: built by this version)."""

    @classmethod
    def empty(cls):
        """A section with no keys (written as {}: unknown, as in files of pose tables)."""
        return cls(source_keys=())

    @classmethod
    def _typed(cls) -> list:
        return [f for f in fields(cls) if "kind" in f.metadata]

    @classmethod
    def from_dict(cls, d: Any, where: str | None = None, *, name: str | None = None):
        """The section of JSON object `d` (None or absent = empty); InputError on a malformed value."""
        name = name or cls.NAME
        if d is None:
            d = {}
        if not isinstance(d, Mapping):
            raise InputError(f"calibration section {name!r} is not an object", where=where)
        typed = cls._typed()
        kw = {
            f.name: _read(f.metadata["kind"], d[f.name], f"{name}.{f.name}", where)
            for f in typed
            if f.name in d
        }
        known = {f.name for f in typed}
        extra = {k: copy.deepcopy(v) for k, v in d.items() if k not in known}
        return cls(**kw, extra=extra, source_keys=tuple(d))

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: the keys as read (or all non-optional ones when built here), then new
        keys set since, then unknown keys added since."""
        src = self.source_keys
        vals = {}
        for f in self._typed():
            v = getattr(self, f.name)
            if v is not None or (f.name in src if src is not None else not f.metadata["optional"]):
                vals[f.name] = _write(v)
        out: dict[str, Any] = {}
        for k in src or ():
            if k in vals:
                out[k] = vals.pop(k)
            elif k in self.extra:
                out[k] = copy.deepcopy(self.extra[k])
        out.update(vals)
        for k, v in self.extra.items():
            out.setdefault(k, copy.deepcopy(v))
        return out


@dataclass(frozen=True)
class TemperatureInfo(Section):
    """Die temperature of the calibration: the model's reference and, when the observations had
    temperatures, their mean and range (degC)."""

    NAME: ClassVar[str] = "temperature"

    t_ref_degC: float | None = json_field("num")
    """Reference temperature T_ref of the model's temperature terms (degC)."""
    mean_degC: float | None = json_field("num", optional=True)
    """Mean temperature of the fitted observations (degC)."""
    min_degC: float | None = json_field("num", optional=True)
    max_degC: float | None = json_field("num", optional=True)

    @property
    def range_degC(self) -> tuple[float, float] | None:
        """(min, max) temperature of the observations (degC), None when not recorded."""
        if self.min_degC is None or self.max_degC is None:
            return None
        return (self.min_degC, self.max_degC)


@dataclass(frozen=True)
class DetectedInterval(Section):
    """A static interval found in an unlabelled (hand-held) session and used by the fit."""

    NAME: ClassVar[str] = "interval"

    start_s: float | None = json_field("num")
    end_s: float | None = json_field("num")
    n: int | None = json_field("int")
    """Number of samples in [start_s, end_s)."""
    up_sensor: tuple[float, ...] | None = json_field("nums")
    """Unit vector of gravity 'up' in the sensor frame during the interval."""

    @classmethod
    def of_labels(cls, labels: Sequence[Any], t_s: np.ndarray) -> tuple[DetectedInterval, ...]:
        """The intervals of detected PoseLabels, n counted in the session's sample times t_s (s)."""
        return tuple(
            cls(
                start_s=p.start_s,
                end_s=p.end_s,
                n=int(np.sum((t_s >= p.start_s) & (t_s < p.end_s))),
                up_sensor=tuple(float(x) for x in p.up_sensor),
            )
            for p in labels
        )


@dataclass(frozen=True)
class FitInfo(Section):
    """Statistics of the fit that made the calibration (accellog.calibrate.model.fit.FitResult).

    chi2 = sum of squared normalised residuals, dof = 3 n_obs - n_params, chi2_dof = chi2 / dof,
    p_value = P(chi2' > chi2); rms_g = residual RMS (g). sigma_scaled: 1-sigma of the parameters
    scaled by sqrt(chi2_dof) (units of the parameters), None when not computed.
    """

    NAME: ClassVar[str] = "fit"

    method: str | None = json_field("str")
    """'labelled' (known poses) or 'orientation_free' (|f| = truth_g)."""
    weighted: bool | None = json_field("bool")
    chi2: float | None = json_field("num")
    dof: int | None = json_field("int")
    chi2_dof: float | None = json_field("num")
    p_value: float | None = json_field("num")
    rms_g: float | None = json_field("num")
    n_obs: int | None = json_field("int")
    uncertainty: str | None = json_field("str")
    """Uncertainty method: 'noise', 'between_hold' or 'jackknife' (accellog.calibrate.model.variance)."""
    between_hold_g: tuple[float, ...] | None = json_field("nums")
    """Between-hold scatter [tau_along, tau_across] (g) of the 'between_hold' method ([tau_along]
    for an orientation-free fit: the gravity norm sees only the along-gravity part)."""
    warnings: tuple[str, ...] | None = json_field("strs")
    sigma_scaled: tuple[float | None, ...] | None = json_field("nums")
    detected_intervals: tuple[DetectedInterval, ...] | None = json_field(
        ("list", DetectedInterval), optional=True
    )
    """Static intervals detected in an unlabelled session (hand-held fits), None otherwise."""

    @classmethod
    def from_result(cls, fit: Any) -> FitInfo:
        """From an accellog.calibrate.model.fit.FitResult (or its orientation-free variant)."""
        fd = fit.to_dict()
        return cls(
            method=fd.get("method"),
            weighted=fd.get("weighted"),
            chi2=fd.get("chi2"),
            dof=fd.get("dof"),
            chi2_dof=fd.get("chi2_dof"),
            p_value=fd.get("p_value"),
            rms_g=fd.get("rms_g"),
            n_obs=fd.get("n_obs"),
            uncertainty=fd.get("uncertainty"),
            between_hold_g=None if fd.get("between_hold_g") is None else tuple(fd["between_hold_g"]),
            warnings=tuple(fit.warnings),
            sigma_scaled=tuple(float(x) for x in fit.sigma_scaled) if len(fit.sigma_scaled) else None,
        )


@dataclass(frozen=True)
class SensorInfo(Section):
    """Accelerometer set-up of the calibrated session (``SensorInfo.empty()`` for pose tables and
    observation files)."""

    NAME: ClassVar[str] = "sensor"

    chip: str | None = json_field("str")
    """Chip name from the session metadata (e.g. 'MPU-9250')."""
    accel_range_g: float | None = json_field("num")
    """Full-scale range (+- g); None when the source did not say."""
    accel_lsb_per_g: float | None = json_field("num")
    """Sensitivity (LSB per g); None when the source gave values without counts."""

    @classmethod
    def from_meta(cls, meta: Any) -> SensorInfo:
        """From a session's SessionMeta (chip, accel_range_g, accel_lsb_per_g)."""
        return cls(chip=meta.chip, accel_range_g=meta.accel_range_g, accel_lsb_per_g=meta.accel_lsb_per_g)


@dataclass(frozen=True)
class SourceFile(Section):
    """One input of the calibration (an entry of `sources`): its path and the SHA-256 of its bytes."""

    NAME: ClassVar[str] = "source"

    path: str | None = json_field("str")
    sha256: str | None = json_field("str")
    """Hex SHA-256 of the file, None when it could not be read."""
    kind: str | None = json_field("str")
    """What the file is ('emulator', 'hardware', 'import:...', 'drift', ...)."""
    recovered: Mapping[str, Any] | None = json_field("obj", optional=True)
    """What was salvaged from a truncated input (accellog.store.source.RecoveryInfo.to_dict())."""

    @classmethod
    def list_from_json(cls, v: Any, where: str | None = None) -> list[SourceFile]:
        """The `sources` list (absent = none); InputError when it or an entry is malformed."""
        if v is None:
            return []
        if not isinstance(v, list):
            raise InputError("calibration field sources is not a list", where=where)
        return [cls.from_dict(x, where, name=f"sources[{i}]") for i, x in enumerate(v)]


@dataclass(frozen=True)
class DeviceInfo(Section):
    """Device key of the calibrated sensor as stored (accellog.core.device.DeviceKey.to_dict());
    ``DeviceInfo.empty()`` = unknown (files written before device keys existed)."""

    NAME: ClassVar[str] = "device"

    id: str | None = json_field("str")
    """Fleet grouping name (DeviceKey.id: the serial, else 'host/bus/0xADDR')."""
    who_am_i: int | None = json_field("int")
    ak8963_wia: int | None = json_field("int")
    serial: str | None = json_field("str")
    i2c_bus: str | None = json_field("str")
    i2c_address: int | None = json_field("int")
    host: str | None = json_field("str")

    @classmethod
    def from_key(cls, key: DeviceKey) -> DeviceInfo:
        """The section of a DeviceKey (its to_dict(): id, then the key's fields)."""
        return cls.from_dict(key.to_dict())

    @property
    def key(self) -> DeviceKey:
        """The DeviceKey (unknown facts empty; the stored id is derived, not read)."""
        return DeviceKey.from_dict(self.to_dict())


# ------------------------------------------------------------------------------ gyro and magnetometer


def gyro_from_dict(d: Any, where: str | None = None) -> GyroCalibration | None:
    """The `gyro` section as a GyroCalibration (None when absent or empty); InputError naming the file."""
    if not d:
        return None
    if not isinstance(d, Mapping):
        raise InputError("calibration section 'gyro' is not an object", where=where)
    try:
        g = GyroCalibration.from_dict(dict(d))
    except InputError as exc:
        raise InputError(str(exc), where=where) from None
    for key in ("bias_dps", "temp_bias_dps_per_degC", "t_ref_degC", "matrix"):  # sigmas may be unknown
        if not np.isfinite(np.asarray(getattr(g, key), float)).all():
            raise InputError(
                f"gyro calibration {key!r} must be finite numbers (no NaN, null or inf)", where=where
            )
    if abs(np.linalg.det(g.matrix)) < 1e-6:
        raise InputError("gyro calibration 'matrix' is singular", where=where)
    return g


def mag_from_dict(d: Any, where: str | None = None) -> MagCalibration | None:
    """The `magnetometer` section as a MagCalibration (None when absent); InputError naming the file."""
    return None if d is None else MagCalibration.from_dict(d, where)


def object_section(obj: Any, source: Mapping[str, Any] | None, reread: Callable[[dict], Any]) -> dict | None:
    """JSON form of a section held as an object with to_dict() (GyroCalibration, MagCalibration).

    `source` is the section as read and `reread` its parser: while `obj` still equals what was read
    (same strict JSON), the source is written back as it was (key order, ints, keys this version
    does not know); else obj.to_dict() followed by the source's keys it does not know."""
    if obj is None:
        return None
    d = obj.to_dict()
    if not source:
        return d
    if dumps(reread(dict(source)).to_dict()) == dumps(d):
        return copy.deepcopy(dict(source))
    return {**d, **{k: copy.deepcopy(v) for k, v in source.items() if k not in d}}


def check_one_device(srcs: Sequence[Any], prior: Any = None) -> None:
    """Refuse (InputError, one line) session Sources of different devices, or of another device
    than the prior calibration's."""
    first = DeviceInfo.from_key(srcs[0].meta.device).key
    for src in srcs[1:]:
        diff = first.conflicts(DeviceInfo.from_key(src.meta.device).key)
        if diff:
            raise InputError(f"{src.where} is another device than {srcs[0].where}: {'; '.join(diff)}")
    diff = [] if prior is None else prior.device_conflicts(first)
    if diff:
        raise InputError(
            f"{srcs[0].where} is another device than the prior's ({prior.path}): {'; '.join(diff)}"
        )
