"""Scenario -> session: record a whole session from the emulated chip on a simulated clock.

The samples go through exactly the path real hardware uses: emulated registers -> ``Mpu9250``
driver (FIFO bursts) -> ``Recorder`` -> ``SessionWriter``; only the clock is simulated, so an hour
of 1 kHz data takes seconds. The scenario's pose labels are the holds the motion really has (the
simulated operator labels each hold from its start to its end, minus a small margin).

A scenario is a TOML file or the equivalent keyword arguments:

```toml
protocol = "six"            # 'six', '24' or a list like '+z,-z,+x@90'
hold_s = 30.0
move_s = 3.0
sample_rate_hz = 1000.0     # 1000 / (1 + SMPLRT_DIV)
accel_range_g = 2
chip_seed = 7               # draws the chip's error parameters (same chip across sessions)
seed = 1                    # noise of this session
errors = "datasheet"        # 'datasheet' | 'perfect'
local_gravity_mps2 = 9.80665
fixture_tilt_deg = [0.0, 0.0]
[set]                       # overrides of AccelErrors fields, e.g.
temp_bias_g_per_degC = [0.001, -0.0005, 0.0008]
[gyro_set]                  # overrides of GyroErrors fields, e.g.
temp_bias2_dps_per_degC2 = [0.002, -0.001, 0.0015]
[faults]                    # all off by default (accellog.acquire.emulator.faults.FaultPlan):
i2c_error_rate = 0.0        #   probability per transaction / per FIFO read (0..1)
fifo_glitch_rate = 0.0
host_stall_s = 0.0          #   host pauses this long (s) ...
host_stall_every_s = 0.0    #   ... every this many seconds
disconnect_at_s = 0.0       #   bus cut at this time (s) ...
disconnect_s = 0.0          #   ... for this long (s)
[magnetometer]              # optional: record the AK8963 (100 Hz mode) with this local field and iron
field_uT = [20.0, 0.0, -45.0]          # world frame (x, y horizontal, z up)
hard_iron_uT = [30.0, -12.0, 8.0]      # AK8963 axes
soft_iron = [[1.05, 0.02, 0.0], [0.02, 0.97, 0.01], [0.0, 0.01, 0.98]]
[temperature]               # 'constant' (T), 'warmup' (T_start, T_end, tau_s) or 'ramp' (T0, rate)
kind = "warmup"
T_start = 25.0
T_end = 40.0
tau_s = 300.0
```

The fault keys at the top level (``i2c_error_rate = 0.01``, and ``Scenario(i2c_error_rate=0.01)``)
are the form before the [faults] table: still read, with a DeprecationWarning (and a note on the
command line).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomllib

from accellog.acquire.device import configure_device
from accellog.acquire.emulator import robot
from accellog.acquire.emulator.chip import EmulatedMpu9250
from accellog.acquire.emulator.clock import SimClock
from accellog.acquire.emulator.faults import FaultPlan, FaultyBus, stalling_sleep
from accellog.acquire.emulator.poses import PoseSequenceMotion
from accellog.acquire.emulator.sensor_model import AccelErrors, GyroErrors, SensorModel
from accellog.acquire.emulator.temperature import TemperaturePath
from accellog.acquire.recorder import Recorder, session_meta
from accellog.core.errors import InputError, did_you_mean
from accellog.core.kinematics import Motion
from accellog.core.notices import note
from accellog.core.protocol import parse_protocol
from accellog.core.session import PoseLabel
from accellog.core.textin import read_text, toml_loads
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.flows.scenario_checks import (
    ERROR_LIMITS,
    GYRO_ERROR_LIMITS,
    MAX_SESSION_S,
    check_error_values,
    check_errors,
    check_numbers,
    check_session_runs,
    check_type,
    overridden_errors,
)
from accellog.store.atomic import AtomicOutput, check_output
from accellog.store.writer import DEFAULT_COMPRESSION, SessionWriter, check_compression

_SMPLRT_DIV_BASE_HZ = 1000.0
FREEZER = {"kind": "warmup", "T_start": 5.0, "T_end": 45.0, "tau_s": 300.0}
"""--temperature freezer: the die warms from 5 to 45 degC (time constant 300 s): a thermal calibration's span."""


@dataclass
class Scenario:
    """Everything that defines a simulated session (see module docstring for the TOML form)."""

    protocol: str = "six"
    hold_s: float = 30.0
    move_s: float = 3.0
    sample_rate_hz: float = 1000.0
    accel_range_g: int = 2
    gyro_range_dps: int = 250
    chip_seed: int = 7
    seed: int = 1
    errors: str = "datasheet"
    set: dict[str, Any] = field(default_factory=dict)
    gyro_errors: str = "datasheet"
    gyro_set: dict[str, Any] = field(default_factory=dict)
    """Overrides of GyroErrors fields (TOML: the [gyro_set] table), e.g. temp_bias2_dps_per_degC2."""
    temperature: dict[str, Any] = field(default_factory=lambda: {"kind": "constant", "T": 25.0})
    local_gravity_mps2: float = STANDARD_GRAVITY_MPS2
    fixture_tilt_deg: tuple[float, float] = (0.0, 0.0)
    label_margin_s: float = 0.25
    motion: str = "poses"
    """'poses' (guided static holds) or 'robot' (the default robot path; see emulator.robot)."""
    robot_path: str = "demo"
    """'demo' (a 64 s closed loop with ramps, a banked turn and 9 stops), 'long' (10 min) or 'parked'
    (30 stops of hold_s on slopes tilted <= 15 deg, drawn from seed: emulator.robot.parked_run)."""
    magnetometer: dict[str, Any] = field(default_factory=dict)
    """Empty: no magnetometer readout. Else keys field_uT, hard_iron_uT, soft_iron, noise_uT (emulator)."""
    faults: FaultPlan = field(default_factory=FaultPlan)
    """What goes wrong during the recording (accellog.acquire.emulator.faults), all off by default:
    a FaultPlan, or a mapping {key: number} that becomes one (checked); TOML: the [faults] table."""

    def __post_init__(self) -> None:
        if isinstance(self.faults, Mapping):
            self.faults = FaultPlan.from_mapping(dict(self.faults))

    @classmethod
    def from_toml(cls, path: str | Path) -> Scenario:
        p = Path(path)
        if not p.exists():
            raise InputError("scenario file not found", where=str(p))
        try:
            data = toml_loads(read_text(p, "scenario file", kind="TOML"), str(p))
        except tomllib.TOMLDecodeError as exc:
            raise InputError(f"not valid TOML ({exc})", where=str(p)) from None
        if not data:  # an empty file (or only comments) is a mistake, not a request for the defaults
            raise InputError("scenario file sets nothing (no keys or tables)", where=str(p))
        return cls.from_dict(data, where=str(p))

    @classmethod
    def from_dict(cls, data: dict[str, Any], where: str = "scenario") -> Scenario:
        names = {f.name for f in dataclasses.fields(cls)}
        flat = [k for k in FaultPlan.names() if k in data]  # the form before [faults] (module doc)
        unknown = sorted(set(data) - names - set(flat))
        if unknown:
            hint = did_you_mean(unknown, names)
            raise InputError(f"unknown scenario key(s) {unknown}{hint}; known: {sorted(names)}", where=where)
        for key, value in data.items():
            check_type(key, value, where)
        data = dict(data)
        if flat:
            if "faults" in data:
                raise InputError(f"fault keys {flat} both at the top level and in [faults]", where=where)
            _deprecated(
                f"fault keys at the top level of a scenario ({', '.join(flat)})", _IN_TABLE, stacklevel=2
            )
            note(f"{where}: fault keys at the top level ({', '.join(flat)}) are deprecated: {_IN_TABLE}")
            data["faults"] = FaultPlan.from_mapping({k: data.pop(k) for k in flat}, where=where)
        elif "faults" in data:
            data["faults"] = FaultPlan.from_mapping(data["faults"], where=f"{where} [faults]")
        sc = cls(**data)
        sc.validate(where)
        return sc

    def validate(self, where: str = "scenario") -> None:
        """InputError naming the first field that is not finite or outside its physical range (the
        one check of a scenario, from a TOML file or from options); see _check_numbers."""
        check_numbers(self, where)
        rate = self.sample_rate_hz
        div = _SMPLRT_DIV_BASE_HZ / rate - 1.0 if rate > 0 and np.isfinite(rate) else -1.0
        if rate <= 0 or abs(div - round(div)) > 1e-9 or not 0 <= round(div) <= 255:
            raise InputError(
                f"sample_rate_hz={self.sample_rate_hz:g} is not 1000/(1+N) for N in 0..255", where=where
            )
        if self.errors not in ("datasheet", "perfect"):
            raise InputError(f"errors={self.errors!r}: use 'datasheet' or 'perfect'", where=where)
        if self.motion not in ("poses", "robot"):
            raise InputError(f"motion={self.motion!r}: use 'poses' or 'robot'", where=where)
        if not 0 < self.hold_s <= MAX_SESSION_S or not 0 <= self.move_s <= MAX_SESSION_S:
            raise InputError(
                f"hold_s={self.hold_s:g} must be > 0 and move_s={self.move_s:g} >= 0 (s), "
                f"both at most {MAX_SESSION_S:g} s",
                where=where,
            )
        if not 0 <= self.label_margin_s < self.hold_s / 2:
            raise InputError(
                f"label_margin_s={self.label_margin_s:g} must be >= 0 and shorter than half the hold "
                f"(hold_s={self.hold_s:g} s): the labels would end before they start",
                where=where,
            )
        if self.accel_range_g not in (2, 4, 8, 16):
            raise InputError(f"accel_range_g={self.accel_range_g}: use 2, 4, 8 or 16", where=where)
        check_error_values(self.set, ERROR_LIMITS, f"{where} [set]" if where != "scenario" else where)
        check_error_values(
            self.gyro_set, GYRO_ERROR_LIMITS, f"{where} [gyro_set]" if where != "scenario" else where
        )
        self.fault_plan(where)
        try:
            parse_protocol(self.protocol, self.hold_s)
            temperature_path(self.temperature)
        except InputError as exc:
            if exc.where is None:
                raise InputError(str(exc), where=where) from None
            raise

    def fault_plan(self, where: str = "scenario") -> FaultPlan:
        """The scenario's faults, checked (rates 0..1, times >= 0, stalls shorter than their period)."""
        faults = self.faults.to_dict() if isinstance(self.faults, FaultPlan) else dict(self.faults)
        return FaultPlan.from_mapping(faults, where=where)

    @property
    def sample_rate_div(self) -> int:
        return round(_SMPLRT_DIV_BASE_HZ / self.sample_rate_hz - 1.0)

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)


_IN_TABLE = "put them in a 'faults' table ([faults] in TOML)"


def _deprecated(what: str, instead: str, stacklevel: int) -> None:
    warnings.warn(f"{what}: deprecated, {instead}", DeprecationWarning, stacklevel=stacklevel + 1)


def _flat_fault_keywords(init):
    """Scenario(i2c_error_rate=...): the keywords before Scenario.faults, deprecated (module doc)."""

    @functools.wraps(init)
    def __init__(self, *args, **kw) -> None:
        flat = {k: kw.pop(k) for k in FaultPlan.names() if k in kw}
        if flat:
            if "faults" in kw:
                raise TypeError(f"Scenario(): fault keys {list(flat)} both as keywords and in faults=")
            given = ", ".join(f"{k}={v!r}" for k, v in flat.items())
            _deprecated(f"Scenario({given})", f"use Scenario(faults={flat!r})", stacklevel=2)
            kw["faults"] = flat
        init(self, *args, **kw)

    return __init__


def _flat_fault_attribute(name: str) -> property:
    """sc.<fault key>, read or set: the attribute before Scenario.faults, deprecated."""

    def get(self):
        _deprecated(f"Scenario.{name}", f"read Scenario.faults.{name}", stacklevel=2)
        return getattr(self.faults, name)

    def set_(self, value) -> None:
        _deprecated(f"Scenario.{name}", "set Scenario.faults (a FaultPlan or a mapping)", stacklevel=2)
        self.faults = FaultPlan.from_mapping({**self.fault_plan().to_dict(), name: value})

    return property(get, set_, doc=f"Deprecated: Scenario.faults.{name}.")


Scenario.__init__ = _flat_fault_keywords(Scenario.__init__)  # type: ignore[method-assign]
for _name in FaultPlan.names():
    setattr(Scenario, _name, _flat_fault_attribute(_name))


def build_sensor_model(sc: Scenario):
    """The emulator's physical model for a scenario: motion, error parameters, temperature path."""

    motion: Motion
    if sc.motion == "robot":
        paths: dict[str, Callable[..., Motion]] = {"demo": robot.demo_loop, "long": robot.long_run,
                 "parked": functools.partial(robot.parked_run, seed=sc.seed, hold_s=sc.hold_s)}  # fmt: skip
        if sc.robot_path not in paths:
            raise InputError(f"robot_path={sc.robot_path!r}: use one of {sorted(paths)}")
        motion = paths[sc.robot_path](local_gravity_mps2=sc.local_gravity_mps2)
    else:
        motion = PoseSequenceMotion(
            parse_protocol(sc.protocol, sc.hold_s),
            move_s=sc.move_s,
            fixture_tilt_deg=sc.fixture_tilt_deg,
        )
    accel = AccelErrors.datasheet(sc.chip_seed) if sc.errors == "datasheet" else AccelErrors.perfect()
    if sc.set:
        accel = overridden_errors(accel, sc.set, "accelerometer")
        check_errors(accel, ERROR_LIMITS)
    gyro = GyroErrors.datasheet(sc.chip_seed) if sc.gyro_errors == "datasheet" else GyroErrors.perfect()
    if sc.gyro_set:
        gyro = overridden_errors(gyro, sc.gyro_set, "gyro")
        check_errors(gyro, GYRO_ERROR_LIMITS)
    temperature = temperature_path(sc.temperature)
    known_mag = {"field_uT", "hard_iron_uT", "soft_iron", "noise_uT"}
    if set(sc.magnetometer) - known_mag:
        raise InputError(
            f"unknown magnetometer key(s) {sorted(set(sc.magnetometer) - known_mag)}; known: {sorted(known_mag)}"
        )
    mag: dict[str, Any] = {}  # SensorModel's mag_* arguments: arrays, noise a float
    for k, v in sc.magnetometer.items():
        try:
            mag[f"mag_{k}"] = np.asarray(v, float) if k != "noise_uT" else float(v)
        except (TypeError, ValueError):
            raise InputError(f"magnetometer {k} = {v!r} is not a number or a list of numbers") from None
    if mag.get("mag_noise_uT", 0.0) < 0:
        raise InputError(f"magnetometer noise_uT = {mag['mag_noise_uT']:g} must be >= 0 (uT)")
    model = SensorModel(
        motion,
        accel=accel,
        gyro=gyro,
        temperature=temperature,
        seed=sc.seed,
        local_gravity_mps2=sc.local_gravity_mps2,
        **mag,
    )
    return model, motion


def temperature_path(spec: dict[str, Any]):
    """TemperaturePath from {'kind': 'constant'|'warmup'|'ramp'|'points', ...} (degC, s)."""

    kind = spec.get("kind", "constant")
    try:
        if kind == "constant":
            return TemperaturePath.constant(float(spec.get("T", 25.0)))
        if kind == "warmup":
            return TemperaturePath.warmup(float(spec["T_start"]), float(spec["T_end"]), float(spec["tau_s"]))
        if kind == "ramp":
            return TemperaturePath.ramp(float(spec["T0"]), float(spec["rate_degC_per_s"]))
        if kind == "points":
            return TemperaturePath.points(spec["t_s"], spec["T"])
    except KeyError as exc:
        raise InputError(f"temperature kind {kind!r} needs key {exc}") from None
    except (TypeError, ValueError):
        raise InputError(
            f"temperature {spec!r}: values must be numbers (lists of numbers for points)"
        ) from None
    raise InputError(f"unknown temperature kind {kind!r}: use constant, warmup, ramp or points")


def simulate(
    sc: Scenario,
    out: str | Path,
    *,
    duration_s: float | None = None,
    poll_s: float = 0.025,
    truth_step_s: float = 0.01,
    serial: str = "",
    start_time_unix_ns: int | None = None,
    force: bool = False,
    compression: str = DEFAULT_COMPRESSION,
    progress=None,
):
    """Write the scenario's session to ``out`` (MCAP) on a simulated clock; return RecordSummary.
    progress(done_s, total_s): called after every FIFO batch with the simulated time so far.

    truth_step_s: spacing of the stored ground truth (s); it is for evaluation only. serial: the
    device's user serial (identity; default EMU-<chip_seed>: the chip seed draws the chip, so two
    seeds are two devices and fitting them together is refused); start_time_unix_ns: the session's wall-clock start (a
    simulated date; default: the writer's clock). An existing ``out`` is refused unless
    force=True; the file appears (atomically) only when complete. Faults of the scenario
    (accellog.acquire.emulator.faults) act on the bus and the host's sleep. compression: of the
    MCAP chunks ('zstd', 'lz4' or 'none').
    """

    check_compression(compression)
    check_output(out, overwrite=force)
    model, motion = build_sensor_model(sc)
    total_s = motion.duration_s if duration_s is None else duration_s
    check_session_runs(sc, model.temperature, total_s)
    plan = sc.fault_plan()
    clock = SimClock()
    chip = EmulatedMpu9250(model, clock, seed=sc.seed, i2c_error_rate=plan.i2c_error_rate)
    bus = FaultyBus(chip, plan, clock.now_ns, seed=sc.seed) if plan.bus_faults else chip
    sleep = stalling_sleep(clock.sleep, clock.now_ns, plan)
    dev = configure_device(
        bus,
        clock_ns=clock.now_ns,
        sleep=clock.sleep,
        accel_range_g=sc.accel_range_g,
        gyro_range_dps=sc.gyro_range_dps,
        sample_rate_div=sc.sample_rate_div,
        mag=bool(sc.magnetometer),  # the AK8963 in its 100 Hz mode
    )
    driver = dev.driver
    meta = session_meta(
        dev.info,
        dev.config,
        source="emulator",
        protocol=sc.protocol if sc.motion == "poses" else f"robot:{sc.robot_path}",
        local_gravity_mps2=sc.local_gravity_mps2,
        extra={"scenario": sc.to_json()},
        serial=serial or f"EMU-{sc.chip_seed}",
        i2c_bus="emulator",
        i2c_address=chip.address,
    )
    if start_time_unix_ns is not None:
        meta = meta.replace(start_time_unix_ns=int(start_time_unix_ns))
    ao = AtomicOutput(out, overwrite=force)
    tmp = ao.begin()
    try:
        with SessionWriter(tmp, meta, compression=compression) as writer:
            driver.start()
            rec = Recorder(driver, writer, sleep=sleep, poll_s=poll_s, read_mag=dev.read_mag)
            if progress is not None:
                rec.on_batch = lambda _batch, _accel: progress(min(rec.t_s, total_s), total_s)
            rec.run_for(total_s)
            for label in _session_labels(motion, chip, rec.t_s, sc.label_margin_s):
                writer.write_pose(label)
                rec.summary.poses.append(label)
            writer.write_truth(chip.truth_for_session(np.arange(0.0, rec.t_s, truth_step_s)))
    except BaseException:  # never leave a half-written session behind (Ctrl-C, errors)
        ao.abort()
        raise
    ao.commit()
    rec.summary.duration_s = rec.t_s
    return rec.summary


def _session_labels(motion, chip, end_s: float, margin_s: float) -> list[PoseLabel]:
    """The motion's holds on the session's time axis (motion time starts when the chip is created,
    session time at the first FIFO sample), margin_s (s) inside each end; holds not wholly in 0..end_s
    are dropped."""
    out = []
    for lab in motion.labels():
        a, b = (float(v) for v in chip.session_time_s(np.array([lab.start_s, lab.end_s])))
        if a >= 0 and b <= end_s:
            out.append(
                PoseLabel(
                    lab.name, a + margin_s, b - margin_s, lab.up_sensor, lab.q_sensor_to_world, lab.hold_index
                )
            )
    return out


def scenario_from_options(
    path: Path | None,
    *,
    set_items: list[str] | None = None,
    temperature: str | None = None,
    faults: list[str] | None = None,
    **fields: Any,
) -> Scenario:
    """The scenario of `accellog simulate`: the TOML file (or the defaults), then the options given
    (fields: Scenario fields, None = not given), --set FIELD=X[,Y,Z] error overrides, --temperature
    and --fault KEY=NUMBER; validated (InputError naming the option)."""
    sc = Scenario.from_toml(path) if path else Scenario()
    for name, value in fields.items():
        if value is not None:
            setattr(sc, name, value)
    for item in set_items or []:
        key, sep, val = item.partition("=")
        if not sep:
            raise InputError(f"--set {item!r}: use FIELD=VALUE or FIELD=X,Y,Z")
        try:
            nums = [float(v) for v in val.split(",")]
        except ValueError:
            raise InputError(f"--set {item!r}: value is not a number") from None
        sc.set[key.strip()] = nums if len(nums) > 1 else nums[0]
    if temperature:
        sc.temperature = parse_temperature_option(temperature)
    given: dict[str, float] = {}
    for item in faults or []:
        key, sep, val = item.partition("=")
        try:
            value = float(val)
        except ValueError:
            value = None
        if not sep or value is None:
            raise InputError(f"--fault {item!r}: use KEY=NUMBER, e.g. --fault i2c_error_rate=0.01")
        FaultPlan.from_mapping({key.strip(): value}, where="--fault")
        given[key.strip()] = value
    if given:
        sc.faults = FaultPlan.from_mapping({**sc.fault_plan().to_dict(), **given}, where="--fault")
    sc.validate()
    return sc


def parse_temperature_option(text: str) -> dict:
    """'constant:T' | 'warmup:T_start:T_end:tau_s' | 'ramp:T0:rate_degC_per_s' | 'freezer' -> scenario
    dict. 'freezer' is FREEZER: a chip out of the fridge warming to a running board's temperature."""
    if text == "freezer":
        return dict(FREEZER)
    kind, *vals = text.split(":")
    keys = {"constant": ["T"], "warmup": ["T_start", "T_end", "tau_s"], "ramp": ["T0", "rate_degC_per_s"]}
    if kind not in keys or len(vals) != len(keys[kind]):
        raise InputError(
            f"--temperature {text!r}: use constant:T, warmup:T_start:T_end:tau_s, ramp:T0:rate or freezer"
        )
    try:
        return {"kind": kind, **{k: float(v) for k, v in zip(keys[kind], vals, strict=True)}}
    except ValueError:
        raise InputError(f"--temperature {text!r}: values must be numbers") from None
