"""The effect library: every physical error term of the measurement equation, one `Effect` each.

The measurement equation (docs/architecture.md, docs/effects.md), true specific force f (g, sensor
frame), dT = T - T_ref (degC), t = time since session start (s):

    u_i = f_i + k2_i f_i^2 + k3_i f_i^3 + sum_{j<k} G_i,jk f_j f_k        (input nonlinearity)
    S   = diag(S_ii + sT_i dT + sT2_i dT^2) + C                              (C: off-diagonals)
    b   = b_i + bT_i dT + bT2_i dT^2 + dt_i t + w_i (1 - exp(-t / tau))
    a'  = S u + b + sum(user contributions h(p, f, drivers))

Built-in effects are evaluated by `accellog.calibrate.model.compose.Model` (vectorised, exact inverse); a user effect
supplies its additive contribution ``h(p, f_g, drivers) -> (n,3) g`` and is loaded from a Python
file with `load_effects_file` (see docs/effects.md for the ~10-line interface).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import types
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from accellog.core.errors import InputError
from accellog.core.textin import read_bytes

AXES = ("x", "y", "z")

DRIVER_HELP: dict[str, str] = {
    "t_s": "time since session start (s)",
    "temp_degC": "die temperature (degC): record TEMP_OUT with the session",
    "dtemp_degC_per_s": "rate of change of die temperature (degC/s): record TEMP_OUT",
    "t_in_pose_s": "time since the static hold began (s): label the holds",
}
"""Standard driver signals (arrays aligned with observation rows) and how to get them."""


@dataclass(frozen=True)
class Param:
    """One parameter: name, unit, initial value and typical physical magnitude.

    typical sets finite-difference steps and parameter scaling in the fit, and is the size an
    effect must be resolvable to (1-sigma below typical) for diagnose to call it identifiable.
    """

    name: str
    unit: str
    initial: float = 0.0
    typical: float = 1e-3


Contribution = Callable[[Mapping[str, float], np.ndarray, Mapping[str, np.ndarray]], np.ndarray]
"""h(p, f_g (n,3), drivers) -> (n,3) additive contribution to the reading, in g."""


@dataclass(frozen=True)
class Effect:
    """A physical error term.

    name: accepted by ``--add``; params: its parameters; drivers: driver signals it needs (keys of
    the drivers dict, e.g. 'temp_degC'); equation/meaning/reveal: documentation (what it is, what
    protocol reveals it); contribution: for user effects, the additive term h(p, f_g, drivers) (g)
    where p maps parameter names to values; built-in effects leave it None (the model evaluates
    them in the measurement equation). static: False if static pose means cannot show it (clock).
    conflicts: effects that cannot be in the same model (they parametrise the same thing).
    extends: lower-order effects this one continues (temp_bias2 extends temp_bias): between two
    effects the data cannot tell apart, the workbench takes the lower order first.
    """

    name: str
    params: tuple[Param, ...]
    drivers: tuple[str, ...] = ()
    meaning: str = ""
    equation: str = ""
    reveal: str = ""
    contribution: Contribution | None = None
    static: bool = True
    conflicts: tuple[str, ...] = ()
    builtin: bool = False
    source: str | None = None
    extends: tuple[str, ...] = ()

    @property
    def param_names(self) -> list[str]:
        return [p.name for p in self.params]


def per_axis(prefix: str, unit: str, initial: float = 0.0, typical: float = 1e-3) -> tuple[Param, ...]:
    """Three parameters prefix_x, prefix_y, prefix_z with the same unit/initial/typical."""
    return tuple(Param(f"{prefix}_{a}", unit, initial, typical) for a in AXES)


CROSS_NAMES = ("S_xy", "S_xz", "S_yx", "S_yz", "S_zx", "S_zy")
TRI_NAMES = ("S_yx", "S_zx", "S_zy")
PRODUCTS = ("xy", "xz", "yz")

_B = Effect
LIBRARY: dict[str, Effect] = {
    e.name: e
    for e in [
        _B(
            "bias",
            per_axis("b", "g", 0.0, 0.05),
            meaning="zero-g offset: reading at zero specific force (datasheet +-60 mg x,y; +-80 mg z)",
            equation="b_i",
            reveal="any poses (each axis: readings at two orientations)",
            builtin=True,
        ),
        _B(
            "scale",
            tuple(Param(f"S_{a}{a}", "1 (g/g)", 1.0, 0.03) for a in AXES),
            meaning="sensitivity of each axis relative to nominal (datasheet +-3 %)",
            equation="S_ii (diagonal of S)",
            reveal="each axis both up and down (+i and -i poses)",
            builtin=True,
        ),
        _B(
            "cross_axis",
            tuple(Param(n, "1 (g/g)", 0.0, 0.02) for n in CROSS_NAMES),
            meaning="cross-axis sensitivity and misalignment of the sensing axes to the package "
            "frame (all 6 off-diagonals of S; datasheet +-2 %)",
            equation="S_ij, i != j",
            reveal="six-position protocol (each axis up and down)",
            conflicts=("misalignment_tri",),
            builtin=True,
        ),
        _B(
            "misalignment_tri",
            tuple(Param(n, "1 (g/g)", 0.0, 0.02) for n in TRI_NAMES),
            meaning="non-orthogonality of the axes when the body frame is defined by the sensor "
            "axes themselves (x exact, y in the xy plane): lower triangle of S (Kalibr, imu_tk)",
            equation="S_yx, S_zx, S_zy",
            reveal="six-position protocol; orientation-free fits (imu_tk style) need this, not cross_axis",
            conflicts=("cross_axis",),
            builtin=True,
        ),
        _B(
            "temp_bias",
            per_axis("bT", "g/degC", 0.0, 1.5e-3),
            drivers=("temp_degC",),
            meaning="bias temperature coefficient (datasheet zero-g tempco +-1.5 mg/degC)",
            equation="bT_i dT",
            reveal="a temperature path: warm-up or sweep of >= 1 degC, several windows per hold",
            builtin=True,
        ),
        _B(
            "temp_bias2",
            per_axis("bT2", "g/degC^2", 0.0, 5e-5),
            drivers=("temp_degC",),
            meaning="curvature of the bias-temperature curve",
            equation="bT2_i dT^2",
            reveal="a temperature sweep of >= 3 degC (three or more temperature levels)",
            builtin=True,
            extends=("temp_bias",),
        ),
        _B(
            "temp_scale",
            per_axis("sT", "1/degC", 0.0, 2.6e-4),
            drivers=("temp_degC",),
            meaning="sensitivity temperature coefficient (datasheet +-0.026 %/degC)",
            equation="sT_i dT on the diagonal of S",
            reveal="temperature path while each axis is held both up and down",
            builtin=True,
        ),
        _B(
            "temp_scale2",
            per_axis("sT2", "1/degC^2", 0.0, 1e-5),
            drivers=("temp_degC",),
            meaning="curvature of the scale-temperature curve",
            equation="sT2_i dT^2 on the diagonal of S",
            reveal="temperature sweep of >= 3 degC with +i and -i poses at several temperatures",
            builtin=True,
            extends=("temp_scale",),
        ),
        _B(
            "nonlin2",
            per_axis("k2", "1/g", 0.0, 5e-3),
            meaning="even (quadratic) nonlinearity of each axis: shows as +/- asymmetry "
            "(datasheet nonlinearity +-0.5 %)",
            equation="k2_i f_i^2 (inside S u)",
            reveal="each axis at three levels (+1, 0, -1 g): the six-position protocol suffices",
            builtin=True,
        ),
        _B(
            "nonlin3",
            per_axis("k3", "1/g^2", 0.0, 5e-3),
            meaning="odd (cubic) nonlinearity; at +-1 g only it is indistinguishable from scale",
            equation="k3_i f_i^3 (inside S u)",
            reveal="poses off the axes (cube edges/corners, e.g. 45 deg tilts): four levels of f_i",
            builtin=True,
        ),
        _B(
            "g_cross",
            tuple(Param(f"G_{i}_{jk}", "1/g", 0.0, 3e-3) for i in AXES for jk in PRODUCTS),
            meaning="g-dependent cross-coupling: reading of axis i depends on the product f_j f_k",
            equation="sum_{j<k} G_i,jk f_j f_k (inside S u)",
            reveal="poses off the axes (cube edges, 45 deg tilts) so that f_j f_k != 0",
            builtin=True,
        ),
        _B(
            "time_drift",
            per_axis("dt", "g/s", 0.0, 1e-6),
            drivers=("t_s",),
            meaning="slow linear bias drift over the session (bias instability, ageing)",
            equation="dt_i t",
            reveal="a long session; repeat a pose at the start and at the end",
            builtin=True,
        ),
        _B(
            "warmup",
            # starts at a warm-up of typical size (3 mg, 100 s): at w = 0 the time constant has no
            # effect, its Jacobian column is zero and no fit can start there
            (*per_axis("w", "g", 3e-3, 3e-3), Param("tau_warmup_s", "s", 100.0, 100.0)),
            drivers=("t_s",),
            meaning="bias settling after power-up (self-heating, charge settling), one time constant",
            equation="w_i (1 - exp(-t / tau_warmup_s))",
            reveal="start recording at power-up; several windows per hold during the first minutes",
            builtin=True,
        ),
        _B(
            "fixture_tilt",
            (Param("tilt_x_rad", "rad", 0.0, 2e-3), Param("tilt_y_rad", "rad", 0.0, 2e-3)),
            meaning="the fixture (table) is not level: every pose's truth is rotated by one small "
            "world tilt, f = R(q_tilt q_nominal)^T (0, 0, g)",
            equation="q_tilt = rotvec(tilt_x_rad, tilt_y_rad, 0) (world frame)",
            reveal="24-pose protocol: each face at 0/90/180/270 deg about the vertical",
            builtin=True,
        ),
        _B(
            "clock",
            (),
            meaning="sample-clock error: sample period (1 + eps_clock)/ODR (datasheet +-2 %); "
            "invisible in static pose means; shows as sensor time vs host time drift and as a "
            "scale error of integrated velocity/displacement",
            equation="t_true = (1 + eps_clock) index / ODR",
            reveal="host timestamps (Session.host_time_s) over a long recording",
            static=False,
            builtin=True,
        ),
    ]
}
"""Built-in effects by name (the names accepted by --add)."""

PRESETS: dict[str, tuple[str, ...]] = {
    "model1": ("bias",),
    "model2": ("bias", "scale"),
    "model3": ("bias", "scale", "cross_axis"),
}
"""The seed's three models."""
HANDHELD_START = "bias+scale+misalignment_tri"
"""The start model of a hand-held session (orientation-free: a frame rotation is unobservable)."""


NORM_BLIND = {
    "cross_axis": "3 of its 6 terms are a rotation of the sensor frame, invisible in |f|: use "
    "misalignment_tri (the other 3), or record labelled poses",
    "fixture_tilt": "needs pose labels (the tilt of a fixture is a rotation of every truth)",
    "clock": "a sample-clock error does not change static readings: supply host timestamps",
}
"""Effects the gravity norm cannot identify, with what to do instead."""


@dataclass
class EffectsFile:
    """Effects loaded from a user file, with the file's path and SHA-256 (stored in model specs)."""

    path: str
    sha256: str
    effects: dict[str, Effect] = field(default_factory=dict)


def load_effects_file(path: str | os.PathLike, *, expect_sha256: str | None = None) -> EffectsFile:
    """Run a user's Python file and collect its effects: a module-level list ``EFFECTS`` if
    present, else every module-level `Effect` instance. Each must define `contribution`.

    This executes the file with the user's rights: call it only for a file the user named on the
    command line (never for a path read from a calibration, session or pipeline file). The bytes
    are read once; with `expect_sha256` (the hash a calibration recorded) they are hashed and
    compared *before* anything is executed, and the same bytes are what runs."""
    p = Path(path)
    data = read_bytes(p, "effects file", "Python")  # a regular file of at most 1 MiB of source
    sha = hashlib.sha256(data).hexdigest()
    if expect_sha256 is not None and sha != expect_sha256:
        raise InputError(
            f"effects file has sha256 {sha[:16]}…, the calibration was fitted with {expect_sha256[:16]}…: "
            "not run; pass the file the calibration was fitted with, or refit",
            where=str(p),
        )
    mod = _exec_user_module(data, p)
    found = getattr(mod, "EFFECTS", None)
    if found is None:
        found = [v for v in vars(mod).values() if isinstance(v, Effect)]
    out: dict[str, Effect] = {}
    for e in found:
        if not isinstance(e, Effect):
            raise InputError(f"EFFECTS contains {e!r}, not an accellog.Effect", where=str(p))
        if e.contribution is None or not callable(e.contribution):
            raise InputError(f"effect {e.name!r} has no callable contribution(p, f_g, drivers)", where=str(p))
        if e.name in LIBRARY or e.name in PRESETS:
            raise InputError(f"effect name {e.name!r} clashes with a built-in effect", where=str(p))
        guarded = _guarded(e.contribution, p, e.name)
        out[e.name] = Effect(**{**e.__dict__, "contribution": guarded, "source": str(p), "builtin": False})
    if not out:
        raise InputError("no effects found: define Effect objects (or a list EFFECTS)", where=str(p))
    return EffectsFile(str(p), sha, out)


def _exec_user_module(data: bytes, p: Path) -> types.ModuleType:
    """Execute source bytes as a module named after the file; any failure (SystemExit and
    os._exit included) becomes one InputError with the line in the file. A DeprecationWarning the
    file's own lines raise (an old import path, e.g. ``from accellog.effects import Effect``) is
    shown: Python hides those outside ``__main__``, and the file's author is the one to act on it."""
    mod = types.ModuleType(f"accellog_user_effects_{p.stem}")
    mod.__file__ = str(p)
    try:
        code = compile(data, str(p), "exec")
        with _no_process_exit(), warnings.catch_warnings():
            warnings.filterwarnings("default", category=DeprecationWarning, module=re.escape(mod.__name__))
            exec(code, mod.__dict__)
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # user code (SystemExit too): one line, with the line in the file
        line = getattr(exc, "lineno", None) if isinstance(exc, SyntaxError) else _user_line(exc, p)
        where = f"{p}:{line}" if line else str(p)
        raise InputError(f"effects file failed to load: {_exc_text(exc)}", where=where) from None
    return mod


class _ProcessExit(BaseException):
    """os._exit called by user code (turned into an error instead of ending the process silently)."""


@contextlib.contextmanager
def _no_process_exit():
    """While user code runs, os._exit raises instead of killing the process with no output."""
    real = os._exit

    def refuse(code: int) -> None:
        raise _ProcessExit(f"it called os._exit({code!r})")

    os._exit = refuse
    try:
        yield
    finally:
        os._exit = real


def _exc_text(exc: BaseException) -> str:
    if isinstance(exc, SystemExit):
        return f"it called sys.exit({exc.code!r})"
    if isinstance(exc, _ProcessExit):
        return str(exc)
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _user_line(exc: BaseException, path: Path) -> int | None:
    """Line number of the innermost traceback frame in the user's file (None if none is)."""
    target = str(path.resolve())
    line = None
    tb = exc.__traceback__
    while tb is not None:
        with contextlib.suppress(OSError):
            if str(Path(tb.tb_frame.f_code.co_filename).resolve()) == target:
                line = tb.tb_lineno
        tb = tb.tb_next
    return line


def _guarded(fn: Contribution, path: Path, name: str) -> Contribution:
    """The user's contribution h(p, f_g, drivers), with any exception (SystemExit included) or a
    result that is not a finite (n, 3) array in g turned into one InputError naming file, effect
    and line."""

    def call(p: Mapping[str, float], f_g: np.ndarray, drivers: Mapping[str, np.ndarray]) -> np.ndarray:
        out: Any = None  # whatever the user's code returned
        try:
            with _no_process_exit():
                out = fn(p, f_g, drivers)
            arr = np.broadcast_to(np.asarray(out, dtype=float), np.shape(f_g))
        except KeyboardInterrupt:
            raise
        except BaseException as exc:
            line = _user_line(exc, path)
            where = f"{path}:{line}" if line else str(path)
            if line is None and isinstance(exc, (ValueError, TypeError)):
                raise InputError(
                    f"effect {name!r}: contribution must return an (n, 3) array in g, got {type(out).__name__}"
                    f" of shape {np.shape(out)}",
                    where=where,
                ) from None
            raise InputError(f"effect {name!r} failed: {_exc_text(exc)}", where=where) from None
        if not np.isfinite(arr).all():
            raise InputError(
                f"effect {name!r}: contribution returned NaN/inf (or None) for {int((~np.isfinite(arr)).sum())} values",
                where=str(path),
            )
        return arr

    call.__wrapped__ = fn  # type: ignore[attr-defined]
    return call


def all_effects(effects_file: EffectsFile | None = None) -> dict[str, Effect]:
    """Built-in library plus the effects of a user file."""
    lib = dict(LIBRARY)
    if effects_file is not None:
        lib.update(effects_file.effects)
    return lib


def describe(effects_file: EffectsFile | None = None) -> list[dict]:
    """One row per effect: name, params, units, drivers, meaning, equation, reveal."""
    return [
        {
            "effect": e.name,
            "params": e.param_names,
            "units": [p.unit for p in e.params],
            "drivers": list(e.drivers),
            "meaning": e.meaning,
            "equation": e.equation,
            "reveal": e.reveal,
            "source": e.source or "builtin",
        }
        for e in all_effects(effects_file).values()
    ]
