"""A simulated fleet: N emulated chips, several short sessions each over simulated months.

Each device k gets its own datasheet draw of accelerometer errors (``AccelErrors.datasheet`` with
chip_seed = 1000 * seed + k: +-60/80 mg zero-g offset, +-3 % scale, +-2 % cross-axis, see
accellog.acquire.emulator.sensor_model) and a serial ``IMU-0001`` ... Session j is recorded
``j * months_between`` months after the first; between sessions the parameters age slowly:

    b(t) = b0 + r_b * t_months,     s(t) = s0 + r_s * t_months

with per-device, per-axis rates r_b ~ N(0, ageing_bias_g_per_month), r_s ~ N(0,
ageing_scale_per_month) (defaults 20 ug/month and 10 ppm/month: far below what a 6-pose x 3 s
session resolves, so a healthy device must not be flagged). One device (``damaged``) is dropped
after its first session: its x bias jumps by ``damage_bias_g`` and its y scale by
``damage_scale``. The room is at 25 degC in every session (the datasheet temperature
coefficients then do not act; a fleet at varying temperature needs a temperature model).

Field runs (field_runs > 0): after its lab sessions each device records that many robot runs
(robot_path 'parked': 30 stops of FIELD_STOP_S on slopes tilted <= 15 deg, pose labels removed, as a robot's log
has none: DIR/<serial>/<serial>_f<j>.mcap), months_between apart; the devices in aged_devices have
had their biases move by aged_bias_g (magnitude uniform in that range, random sign, per axis)
since the last lab session, the others only by their slow ageing (accellog.flows.fleet_field).

Files: DIR/<serial>/<serial>_s<j>.mcap, plus DIR/fleet_truth.json (the drawn parameters, ageing
rates and the damaged device: ground truth for tests, never read by ``fleet run``).
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from accellog.core.errors import InputError
from accellog.store.atomic import folder_output

NS_PER_S = 1_000_000_000
FIELD_STOP_S = 8.0
"""How long a field run's robot stands at each of its stops (s)."""
SECONDS_PER_MONTH = 30.4375 * 86400.0


@dataclass
class FleetSpec:
    """What to simulate (see module docstring)."""

    n_devices: int = 40
    sessions_per_device: int = 3
    months_between: float = 3.0
    hold_s: float = 3.0
    move_s: float = 1.0
    sample_rate_hz: float = 200.0
    seed: int = 0
    damaged: int | None = -1
    """Index of the damaged device (-1: the middle one, n_devices // 2; None: none)."""
    damage_bias_g: float = 0.020
    damage_scale: float = 0.005
    ageing_bias_g_per_month: float = 20e-6
    ageing_scale_per_month: float = 10e-6
    start_utc: str = "2026-01-05T09:00:00Z"
    temperature_degC: float = 25.0
    field_runs: int = 0
    aged_devices: tuple[int, ...] = ()
    aged_bias_g: tuple[float, float] = (0.005, 0.008)

    def damaged_index(self) -> int | None:
        if self.damaged is None or self.n_devices == 0:
            return None
        return self.n_devices // 2 if self.damaged < 0 else int(self.damaged)

    MAX_SESSIONS: ClassVar[int] = 100_000
    """Most sessions one fleet simulation writes (more would run for days and fill the disk)."""

    def validate(self) -> None:
        if self.n_devices < 1 or self.sessions_per_device < 1:
            raise InputError(
                f"fleet of {self.n_devices} devices x {self.sessions_per_device} sessions: need >= 1"
            )
        if self.field_runs < 0 or any(not 0 <= k < self.n_devices for k in self.aged_devices):
            raise InputError(
                f"field_runs={self.field_runs} must be >= 0 and aged_devices in 0..{self.n_devices - 1}"
            )
        if self.n_devices * self.sessions_per_device > self.MAX_SESSIONS:
            raise InputError(
                f"fleet of {self.n_devices} devices x {self.sessions_per_device} sessions: at most "
                f"{self.MAX_SESSIONS:,} sessions"
            )
        d = self.damaged_index()
        if d is not None and not 0 <= d < self.n_devices:
            raise InputError(f"damaged device index {d} is not in 0..{self.n_devices - 1}")


@dataclass
class SimulatedSession:
    """One planned session: device, index, file, wall-clock start, and the error overrides."""

    serial: str
    index: int
    path: str
    start_time_unix_ns: int
    months: float
    chip_seed: int
    noise_seed: int
    overrides: dict[str, list[float]]
    field: bool = False
    """A robot's run without pose labels (module doc), not a lab session."""


@dataclass
class FleetSimResult:
    """What simulate_fleet wrote."""

    out_dir: str
    sessions: list[SimulatedSession] = field(default_factory=list)
    damaged_serial: str | None = None
    truth_file: str = ""

    @property
    def serials(self) -> list[str]:
        return sorted({s.serial for s in self.sessions})

    def to_dict(self) -> dict[str, Any]:
        return {
            "out_dir": self.out_dir,
            "n_devices": len(self.serials),
            "n_sessions": len(self.sessions),
            "damaged_serial": self.damaged_serial,
            "truth_file": self.truth_file,
        }


def serial_of(k: int) -> str:
    return f"IMU-{k + 1:04d}"


def plan_fleet(spec: FleetSpec, out_dir: str | Path) -> tuple[list[SimulatedSession], dict[str, Any]]:
    """The sessions to simulate and the ground truth (drawn errors, ageing rates, damage)."""
    from accellog.acquire.emulator.sensor_model import AccelErrors

    spec.validate()
    out = Path(out_dir)
    t0 = _dt.datetime.fromisoformat(spec.start_utc.replace("Z", "+00:00"))
    t0_ns = round(t0.timestamp()) * NS_PER_S
    damaged = spec.damaged_index()
    plan = []
    truth: dict[str, Any] = {"spec": dataclasses.asdict(spec), "devices": {}}
    for k in range(spec.n_devices):
        serial = serial_of(k)
        chip_seed = 1000 * spec.seed + k
        base = AccelErrors.datasheet(chip_seed)
        rng = np.random.default_rng([spec.seed, k, 0xA6E])
        r_b = rng.normal(0.0, spec.ageing_bias_g_per_month, 3)
        r_s = rng.normal(0.0, spec.ageing_scale_per_month, 3)
        truth["devices"][serial] = {
            "chip_seed": chip_seed,
            "bias_g": base.bias_g.tolist(),
            "scale": base.scale.tolist(),
            "ageing_bias_g_per_month": r_b.tolist(),
            "ageing_scale_per_month": r_s.tolist(),
            "damaged": k == damaged,
        }
        aged = (
            rng.uniform(*spec.aged_bias_g, 3) * rng.choice([-1.0, 1.0], 3) if k in spec.aged_devices else 0.0
        )
        truth["devices"][serial]["field_aged_bias_g"] = np.broadcast_to(aged, 3).tolist()
        n_lab = spec.sessions_per_device
        for j in range(n_lab + spec.field_runs):
            months = j * spec.months_between
            bias = base.bias_g + r_b * months + (aged if j >= n_lab else 0.0)
            scale = base.scale + r_s * months
            if k == damaged and j >= 1:
                bias = bias + np.array([spec.damage_bias_g, 0.0, 0.0])
                scale = scale + np.array([0.0, spec.damage_scale, 0.0])
            name = f"{serial}_s{j}" if j < n_lab else f"{serial}_f{j - n_lab}"
            plan.append(
                SimulatedSession(
                    serial=serial,
                    index=j,
                    field=j >= n_lab,
                    path=str(out / serial / f"{name}.mcap"),
                    start_time_unix_ns=t0_ns + round(months * SECONDS_PER_MONTH) * NS_PER_S,
                    months=months,
                    chip_seed=chip_seed,
                    noise_seed=100_000 * spec.seed + 100 * k + j + 1,
                    overrides={"bias_g": bias.tolist(), "scale": scale.tolist()},
                )
            )
    truth["damaged_serial"] = serial_of(damaged) if damaged is not None else None
    return plan, truth


def _simulate_one(spec: FleetSpec, s: SimulatedSession) -> str:
    from accellog.flows.simulate import Scenario, simulate

    sc = Scenario(
        motion="robot" if s.field else "poses",
        robot_path="parked",  # the robot's path (motion 'robot' only)
        protocol="six",
        hold_s=FIELD_STOP_S if s.field else spec.hold_s,
        move_s=spec.move_s,
        sample_rate_hz=spec.sample_rate_hz,
        chip_seed=s.chip_seed,
        seed=s.noise_seed,
        set=dict(s.overrides),
        temperature={"kind": "constant", "T": spec.temperature_degC},
    )
    sc.validate()
    Path(s.path).parent.mkdir(parents=True, exist_ok=True)
    if not s.field:
        simulate(sc, s.path, serial=s.serial, start_time_unix_ns=s.start_time_unix_ns)
        return s.path
    from accellog.store.reader import read_session
    from accellog.store.writer import write_session

    labelled = Path(s.path).with_suffix(".labelled")
    simulate(sc, labelled, serial=s.serial, start_time_unix_ns=s.start_time_unix_ns, force=True)
    write_session(s.path, dataclasses.replace(read_session(labelled), poses=[]))  # a robot's log has none
    labelled.unlink()
    return s.path


def simulate_fleet(spec: FleetSpec, out_dir: str | Path, *, jobs: int = 1) -> FleetSimResult:
    """Write every session of the fleet (jobs > 1: that many processes) and fleet_truth.json."""
    from accellog.calibrate.calfile.calibration import write_json_atomic

    plan, truth = plan_fleet(spec, out_dir)
    with folder_output(out_dir) as out:  # a fleet folder made here goes if it fails (a full disk)
        if jobs > 1:
            with ProcessPoolExecutor(max_workers=jobs) as ex:
                list(ex.map(_simulate_one, [spec] * len(plan), plan, chunksize=8))
        else:
            for s in plan:
                _simulate_one(spec, s)
        truth_file = out / "fleet_truth.json"
        write_json_atomic(truth_file, truth)
    return FleetSimResult(
        out_dir=str(out), sessions=plan, damaged_serial=truth["damaged_serial"], truth_file=str(truth_file)
    )
