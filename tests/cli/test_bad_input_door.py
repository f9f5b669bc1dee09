"""Validation at the door and bounded work on hostile input (issue 27, items 2, 3 and 7).

Each failing case of the issue's corpus is a case here, run through the CLI in-process: a non-zero
exit, one stderr line ``accellog: error: ...`` naming the option, key or file, no traceback, and the
folder exactly as before (no output, no temporary or lock file, inputs intact). Property tests
(hypothesis) check the option door and the calibration validator on arbitrary values.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.refusal import assert_refused, snapshot
from support.sessions import synth_session

from accellog.calibrate.calfile.calibration import calibration_from_dict, load_calibration
from accellog.calibrate.gyro.model import GyroCalibration
from accellog.cli import main
from accellog.cli.option_checks import OPTION_RANGES, check_option
from accellog.core.errors import InputError
from accellog.core.textin import MAX_BYTES, nesting_depth
from accellog.flows.simulate import Scenario, build_sensor_model, check_session_runs
from accellog.store.writer import write_session

SIM = ["simulate", "--hold", "2", "--protocol", "+z"]


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("door_good")
    s = synth_session(seed=3, hold_s=5.0, move_s=1.0, rate_hz=100.0)
    mcap = write_session(d / "six.mcap", s, chunk_size=8 * 1024)
    cal = d / "cal.json"
    assert main(["fit", str(mcap), "--model", "model3", "-o", str(cal)]) == 0
    return {"mcap": mcap, "cal": cal}


def _obs(d: Path, good: dict) -> Path:
    """An observation table of the good session (made before the snapshot: an input)."""
    assert main(["segment", str(good["mcap"]), "-o", str(d / "obs.json")]) == 0
    return d / "obs.json"


def _cal(good: dict, d: Path, edit: Callable[[dict], object], name: str = "badcal.json") -> Path:
    c = json.loads(good["cal"].read_text())
    r = edit(c)
    p = d / name
    p.write_text(r if isinstance(r, str) else json.dumps(c))
    return p


def _gyro_section(bias=(0.1, -0.2, 0.3), **kw) -> dict:
    g = GyroCalibration(bias_dps=np.array(bias, float), bias_sigma_dps=np.full(3, 0.01), **kw).to_dict()
    return g


def _drift_section(q0_x=0.001) -> dict:
    from accellog.calibrate.calfile.drift_model import DriftModel

    d = DriftModel(q=np.full((3, 3), 1e-3), cov=np.zeros((3, 3, 3)), fit_duration_s=20.0).to_dict()
    d["axes"]["x"]["q0_m"] = q0_x
    return d


def _set_gyro(section: dict | str) -> Callable[[dict], object]:
    def edit(c):
        if isinstance(section, str):  # raw JSON text for the section (NaN literal)
            c["gyro"] = "@GYRO@"
            return json.dumps(c).replace('"@GYRO@"', section)
        c["gyro"] = section
        return None

    return edit


def _scenario(text: str) -> Callable[[Path, dict], list[str]]:
    def build(d, g):
        (d / "sc.toml").write_text(text)
        return ["simulate", "--scenario", str(d / "sc.toml"), "-o", str(d / "s.mcap")]

    return build


def _sparse(path: Path, size: int, head: bytes = b"") -> Path:
    with path.open("wb") as f:
        f.write(head)
        f.truncate(size)  # no blocks on disk: a "2 GB file" costs nothing here
    return path


def _deep(n: int) -> str:
    return "[" * n + "]" * n


CASES: dict[str, tuple[Callable[[Path, dict], list[str]], tuple[str, ...]]] = {
    # options: finite numbers and physical ranges
    "sim-temperature-nan": (
        lambda d, g: [*SIM, "--temperature", "constant:nan", "-o", str(d / "s.mcap")],
        ("temperature", "finite"),
    ),
    "sim-set-bias-nan": (
        lambda d, g: [*SIM, "--set", "bias_g=nan,0,0", "-o", str(d / "s.mcap")],
        ("set", "bias_g", "finite"),
    ),
    "sim-set-bias-1e300": (
        lambda d, g: [*SIM, "--set", "bias_g=1e300,0,0", "-o", str(d / "s.mcap")],
        ("bias_g", "physical range"),
    ),
    "sim-set-noise-negative": (
        lambda d, g: [*SIM, "--set", "noise_density_g_per_rtHz=-1e-4", "-o", str(d / "s.mcap")],
        ("noise_density_g_per_rtHz", "physical range"),
    ),
    "sim-scenario-quadratic-tempco-5-g": (  # ran: 2000 g at 20 degC from the reference
        lambda d, g: [
            "simulate",
            "--scenario",
            str(
                _write(
                    d / "sc.toml",
                    'protocol = "+z"\nhold_s = 2.0\n[set]\ntemp_bias2_g_per_degC2 = [0, 0, 5.0]\n',
                )
            ),
            "-o",
            str(d / "s.mcap"),
        ],
        ("sc.toml [set]", "temp_bias2_g_per_degC2", "physical range"),
    ),
    "sim-scenario-gyro-bias-beyond-full-scale": (  # the gyro's errors were not checked at all
        lambda d, g: [
            "simulate",
            "--scenario",
            str(_write(d / "sc.toml", 'protocol = "+z"\nhold_s = 2.0\n[gyro_set]\nbias_dps = [1e6, 0, 0]\n')),
            "-o",
            str(d / "s.mcap"),
        ],
        ("sc.toml [gyro_set]", "bias_dps", "physical range"),
    ),
    "sim-ramp-1e6": (
        lambda d, g: [*SIM, "--temperature", "ramp:25:1e6", "-o", str(d / "s.mcap")],
        ("ramp", "operating range"),
    ),
    "sim-seed-negative": (lambda d, g: [*SIM, "--seed", "-1", "-o", str(d / "s.mcap")], ("--seed", ">= 0")),
    "sim-chip-seed-negative": (
        lambda d, g: [*SIM, "--chip-seed", "-5", "-o", str(d / "s.mcap")],
        ("--chip-seed",),
    ),
    "sim-hold-inf": (
        lambda d, g: ["simulate", "--hold", "inf", "--protocol", "+z", "-o", str(d / "s.mcap")],
        ("--hold", "finite"),
    ),
    "sim-hold-nan": (
        lambda d, g: ["simulate", "--hold", "nan", "--protocol", "+z", "-o", str(d / "s.mcap")],
        ("--hold", "finite"),
    ),
    "sim-hold-1e9": (
        lambda d, g: ["simulate", "--hold", "1e9", "--protocol", "+z", "-o", str(d / "s.mcap")],
        ("--hold", "86400"),
    ),
    "record-hold-inf": (
        lambda d, g: [
            "record",
            "--sim",
            "--fast",
            "--hold",
            "inf",
            "--protocol",
            "+z",
            "-o",
            str(d / "r.mcap"),
        ],
        ("--hold", "finite"),
    ),
    "record-seed-negative": (
        lambda d, g: [
            "record",
            "--sim",
            "--fast",
            "--seed",
            "-3",
            "--protocol",
            "+z",
            "-o",
            str(d / "r.mcap"),
        ],
        ("--seed",),
    ),
    "sim-fleet-10M-sessions": (
        lambda d, g: ["simulate", "--fleet", "10000", "--fleet-sessions", "1000", "-o", str(d / "fleet")],
        ("10000 devices x 1000 sessions", "100,000"),
    ),
    "fit-trim-nan": (
        lambda d, g: ["fit", str(g["mcap"]), "--trim-s", "nan", "-o", str(d / "c.json")],
        ("--trim-s", "finite"),
    ),
    "fit-trim-negative": (
        lambda d, g: ["fit", str(g["mcap"]), "--trim-s", "-1", "-o", str(d / "c.json")],
        ("--trim-s",),
    ),
    "fit-window-1e-9": (
        lambda d, g: ["fit", str(g["mcap"]), "--window-s", "1e-9", "-o", str(d / "c.json")],
        ("six.mcap", "window_s", "needs >= 10"),
    ),
    "fit-window-0.0005": (
        lambda d, g: ["fit", str(g["mcap"]), "--window-s", "0.0005", "-o", str(d / "c.json")],
        ("six.mcap", "window_s", "needs >= 10"),
    ),
    "fit-window-5-samples": (  # 0.05 s at 100 Hz: 5 samples, refused at the file's own rate
        lambda d, g: ["fit", str(g["mcap"]), "--window-s", "0.05", "-o", str(d / "c.json")],
        ("six.mcap", "100 Hz", "needs >= 10"),
    ),
    "segment-window-inf": (
        lambda d, g: ["segment", str(g["mcap"]), "--window-s", "inf", "-o", str(d / "o.json")],
        ("--window-s", "finite"),
    ),
    "fit-local-gravity-1000": (
        lambda d, g: ["fit", str(g["mcap"]), "--local-gravity", "1000", "-o", str(d / "c.json")],
        ("--local-gravity", "9.7", "9.9"),
    ),
    "fit-local-gravity-moon": (
        lambda d, g: ["fit", str(g["mcap"]), "--local-gravity", "1.62", "-o", str(d / "c.json")],
        ("--local-gravity",),
    ),
    "evaluate-until-nan": (
        lambda d, g: ["evaluate", str(g["mcap"]), "--cal", str(g["cal"]), "--until-s", "nan"],
        ("--until-s",),
    ),
    "diagnose-gravity-g-5": (lambda d, g: ["diagnose", str(g["mcap"]), "--gravity-g", "5"], ("--gravity-g",)),
    # faults that could never finish
    "fault-fifo-rate-1": (
        lambda d, g: [*SIM, "--fault", "fifo_glitch_rate=1.0", "-o", str(d / "s.mcap")],
        ("fifo_glitch_rate", "0 <= p < 1"),
    ),
    "fault-i2c-rate-1": (
        lambda d, g: [*SIM, "--fault", "i2c_error_rate=1", "-o", str(d / "s.mcap")],
        ("i2c_error_rate",),
    ),
    "fault-stall-ge-period": (
        lambda d, g: [
            *SIM,
            *("--fault", "host_stall_s=2", "--fault", "host_stall_every_s=1"),
            *("-o", str(d / "s.mcap")),
        ],
        ("--fault", "host_stall_s", "shorter than"),
    ),
    "fault-disconnect-1e9": (
        lambda d, g: [
            *SIM,
            *("--fault", "disconnect_at_s=1", "--fault", "disconnect_s=1e9"),
            *("-o", str(d / "s.mcap")),
        ],
        ("disconnect_s", "longer than the session"),
    ),
    "fault-nan": (
        lambda d, g: [*SIM, "--fault", "host_stall_s=nan", "-o", str(d / "s.mcap")],
        ("host_stall_s", "finite"),
    ),
    # scenario fields
    "scenario-label-margin-5": (
        _scenario("hold_s = 3.0\nlabel_margin_s = 5.0\n"),
        ("sc.toml", "label_margin_s"),
    ),
    "scenario-label-margin-negative": (_scenario("label_margin_s = -0.1\n"), ("sc.toml", "label_margin_s")),
    "scenario-hold-inf": (_scenario("hold_s = inf\n"), ("sc.toml", "hold_s", "finite")),
    "scenario-move-nan": (_scenario("move_s = nan\n"), ("sc.toml", "move_s", "finite")),
    "scenario-set-nan": (_scenario("[set]\nbias_g = [nan, 0.0, 0.0]\n"), ("sc.toml", "set", "finite")),
    "scenario-seed-negative": (_scenario("seed = -1\n"), ("sc.toml", "seed")),
    "scenario-gravity-moon": (_scenario("local_gravity_mps2 = 1.62\n"), ("sc.toml", "local_gravity_mps2")),
    "scenario-tilt-1e6": (
        _scenario("fixture_tilt_deg = [1e6, 0.0]\n"),
        ("sc.toml", "fixture_tilt_deg", "90"),
    ),
    "scenario-tilt-inf": (_scenario("fixture_tilt_deg = [inf, 0.0]\n"), ("sc.toml", "fixture_tilt_deg")),
    "scenario-warmup-200C": (
        _scenario('[temperature]\nkind = "warmup"\nT_start = 25.0\nT_end = 200.0\ntau_s = 1.0\n'),
        ("warmup", "operating range"),
    ),
    "scenario-temperature-text": (
        _scenario('[temperature]\nkind = "constant"\nT = "hot"\n'),
        ("sc.toml", "temperature", "must be numbers"),
    ),
    "scenario-points-text": (
        _scenario('[temperature]\nkind = "points"\nt_s = [0.0, "a"]\nT = [25.0, 26.0]\n'),
        ("sc.toml", "temperature", "must be numbers"),
    ),
    "scenario-magnetometer-text": (_scenario('[magnetometer]\nfield_uT = "x"\n'), ("magnetometer field_uT",)),
    "scenario-magnetometer-noise-negative": (
        _scenario("[magnetometer]\nnoise_uT = -1.0\n"),
        ("noise_uT", ">= 0"),
    ),
    "scenario-stall-rate": (
        _scenario("[faults]\nhost_stall_s = 1.0\nhost_stall_every_s = 0.5\n"),
        ("sc.toml", "host_stall_s"),
    ),
    "scenario-deep-toml": (
        _scenario("hold_s = " + _deep(5000) + "\n"),
        ("sc.toml", "nested deeper"),
    ),
    "scenario-2MiB": (
        lambda d, g: (
            [*_scenario("")(d, g)[:2], str(_sparse(d / "big.toml", 2 * 1024 * 1024)), "-o", str(d / "s.mcap")]
        ),
        ("big.toml", "at most 1 MiB"),
    ),
    "scenario-2GB": (
        lambda d, g: (
            [*_scenario("")(d, g)[:2], str(_sparse(d / "huge.toml", 2 * 1024**3)), "-o", str(d / "s.mcap")]
        ),
        ("huge.toml", "at most 1 MiB"),
    ),
    "pipeline-deep-toml": (
        lambda d, g: [
            "run",
            str(_write(d / "p.toml", "[pipeline]\nx = " + _deep(5000) + "\n")),
            str(g["mcap"]),
        ],
        ("p.toml", "nested deeper"),
    ),
    "pipeline-2GB": (
        lambda d, g: ["run", str(_sparse(d / "p.toml", 2 * 1024**3)), str(g["mcap"])],
        ("p.toml", "at most 1 MiB"),
    ),
    "pipeline-times-empty": (
        lambda d, g: [
            "run",
            str(_write(d / "p.toml", _pipe(r"times_s = \[[^\]]*\]", "times_s = []"))),
            str(g["mcap"]),
        ],
        ("p.toml", "evaluate.times_s", "non-empty"),
    ),
    "pipeline-trim-nan": (
        lambda d, g: [
            "run",
            str(_write(d / "p.toml", _pipe(r"trim_s = [0-9.]+", "trim_s = nan"))),
            str(g["mcap"]),
        ],
        ("p.toml", "trim_s", "finite"),
    ),
    # calibration fields (one validator, when read)
    "cal-t-ref-string": (
        lambda d, g: [
            "evaluate",
            str(g["mcap"]),
            "--cal",
            str(_cal(g, d, lambda c: c["temperature"].__setitem__("t_ref_degC", "twenty-five"))),
        ],
        ("badcal.json", "t_ref_degC"),
    ),
    "cal-model-t-ref-string-apply": (
        lambda d, g: [
            "apply",
            str(g["mcap"]),
            "--cal",
            str(_cal(g, d, lambda c: c["model"].__setitem__("t_ref_degC", "twenty-five"))),
            "-o",
            str(d / "o.mcap"),
        ],
        ("badcal.json", "t_ref_degC"),
    ),
    "cal-gyro-bias-null-apply": (
        lambda d, g: [
            "apply",
            str(g["mcap"]),
            "--cal",
            str(_cal(g, d, _set_gyro(_gyro_section(bias=(np.nan, 0.0, 0.0))))),
            "-o",
            str(d / "o.mcap"),
        ],
        ("badcal.json", "gyro", "bias_dps", "finite"),
    ),
    "cal-gyro-bias-NaN-literal": (
        lambda d, g: [
            "evaluate",
            str(g["mcap"]),
            "--cal",
            str(_cal(g, d, _set_gyro(json.dumps(_gyro_section()).replace("0.1", "NaN", 1)))),
        ],
        ("badcal.json", "NaN is not JSON"),
    ),
    "cal-gyro-matrix-inf": (
        lambda d, g: [
            "evaluate",
            str(g["mcap"]),
            "--cal",
            str(_cal(g, d, _set_gyro(json.dumps(_gyro_section()).replace("1.0", "Infinity", 1)))),
        ],
        ("badcal.json", "Infinity is not JSON"),
    ),
    "cal-param-NaN-literal": (
        lambda d, g: [
            "evaluate",
            str(g["mcap"]),
            "--cal",
            str(
                _cal(
                    g,
                    d,
                    lambda c: json.dumps(c).replace(
                        '"value": ' + json.dumps(c["params"][0]["value"]), '"value": NaN', 1
                    ),
                )
            ),
        ],
        ("badcal.json", "NaN is not JSON"),
    ),
    "cal-drift-null-coefficient": (
        lambda d, g: [
            "evaluate",
            str(g["mcap"]),
            "--cal",
            str(_cal(g, d, lambda c: c.__setitem__("drift", _drift_section(q0_x=None)))),
        ],
        ("badcal.json", "malformed drift model", "finite"),
    ),
    "cal-deep-json": (
        lambda d, g: ["evaluate", str(g["mcap"]), "--cal", str(_write(d / "deep.json", _deep(200_000)))],
        ("deep.json", "nested deeper"),
    ),
    "cal-deep-json-under-recursion-limit": (
        lambda d, g: [
            "evaluate",
            str(g["mcap"]),
            "--cal",
            str(_write(d / "deep.json", '{"a": ' + _deep(500) + "}")),
        ],
        ("deep.json", "nested deeper than 64"),
    ),
    "cal-2GB": (
        lambda d, g: ["evaluate", str(g["mcap"]), "--cal", str(_sparse(d / "big.json", 2 * 1024**3, b"{"))],
        ("big.json", "at most 32 MiB"),
    ),
    "drift-of-observations-drawn": (  # the table was passed on as a session: a TypeError traceback
        lambda d, g: [
            "drift",
            str(_obs(d, g)),
            "--cal",
            str(g["cal"]),
            "-o",
            str(d / "d.json"),
            "--rrd",
            str(d / "d.rrd"),
        ],
        ("obs.json", "drift needs a recorded session"),
    ),
    "obs-65MiB": (
        lambda d, g: [
            "fit",
            str(_sparse(d / "obs.json", MAX_BYTES["JSON"] + 1, b"{")),
            "-o",
            str(d / "c.json"),
        ],
        ("obs.json", "at most 32 MiB"),
    ),
}


def _pipe(pattern: str, repl: str) -> str:
    """The shipped six-position pipeline with one edit (the pattern must match)."""
    import re

    text = (Path(__file__).resolve().parents[2] / "pipelines" / "six_position.toml").read_text()
    out, n = re.subn(pattern, repl, text, count=1)
    assert n == 1, pattern
    return out


def _write(p: Path, text: str) -> Path:
    p.write_text(text)
    return p


@pytest.mark.parametrize("name", list(CASES))
def test_refused_at_the_door(name, good, tmp_path, capsys):
    build, needles = CASES[name]
    d = tmp_path / "case"
    d.mkdir()
    assert_refused(build(d, good), d, capsys, needles)


def test_a_valid_scenario_at_the_limits_still_runs(tmp_path):
    """The door is not too tight: margin just under half a hold, a rate just under 1, a stall just
    shorter than its period, the coldest and hottest operating temperatures."""
    (tmp_path / "sc.toml").write_text(
        "hold_s = 1.0\nmove_s = 0.5\nlabel_margin_s = 0.49\nprotocol = '+z'\nsample_rate_hz = 200.0\n"
        "[faults]\nhost_stall_s = 0.01\nhost_stall_every_s = 0.011\n"
        "[temperature]\nkind = 'ramp'\nT0 = -40.0\nrate_degC_per_s = 60.0\n"
    )
    assert main(["simulate", "--scenario", str(tmp_path / "sc.toml"), "-o", str(tmp_path / "s.mcap")]) == 0


def test_a_calibration_is_checked_by_the_reader_before_it_is_written(good, tmp_path):
    """Calibration.save runs the reader's validation on what it would write: a NaN gyro bias or a
    gravity no loader accepts is refused and nothing is written."""
    cal = load_calibration(good["cal"])
    cal.gyro = GyroCalibration(bias_dps=np.array([np.nan, 0.0, 0.0]), bias_sigma_dps=np.full(3, 0.01))
    with pytest.raises(InputError, match="bias_dps"):
        cal.save(tmp_path / "c.json")
    cal = load_calibration(good["cal"])
    cal.local_gravity_mps2 = 1000.0
    with pytest.raises(InputError, match="local_gravity_mps2"):
        cal.save(tmp_path / "c.json")
    assert list(tmp_path.iterdir()) == []
    load_calibration(good["cal"]).save(tmp_path / "ok.json")  # a good one is written
    assert load_calibration(tmp_path / "ok.json").theta.size == cal.theta.size


def test_nesting_depth_is_iterative():
    deep: list = []
    x = deep
    for _ in range(100_000):
        x.append([])
        x = x[0]
    assert nesting_depth(deep) == 65  # stops counting past the limit, no RecursionError
    assert nesting_depth({"a": [1, {"b": 2}]}) == 3


# -------------------------------------------------------------------------------- property tests

_numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**70), max_value=2**70),
)


@settings(max_examples=300, deadline=None)
@given(opt=st.sampled_from([*sorted(OPTION_RANGES), "--count-offset", "--not-ranged"]), value=_numbers)
def test_option_door_property(opt, value):
    """check_option refuses exactly the non-finite and out-of-range values, with one InputError
    naming the option, and never raises anything else."""
    finite = not isinstance(value, float) or math.isfinite(value)
    if opt in OPTION_RANGES and finite:
        lo, hi, lo_open, _unit = OPTION_RANGES[opt]
        ok = (value > lo if lo_open else value >= lo) and value <= hi
    else:
        ok = finite
    if ok:
        check_option(opt, value)
    else:
        with pytest.raises(InputError) as exc:
            check_option(opt, value)
        assert str(exc.value).startswith(f"{opt}: ") and "\n" not in str(exc.value)


_json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.integers(min_value=-(10**30), max_value=10**30)
    | st.text(max_size=8),
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=6), kids, max_size=4),
    max_leaves=12,
)
_CAL_PATHS = [
    ("params", 0, "value"),
    ("params", 4, "value"),
    ("params", 8, "value"),
    ("covariance", 0, 0),
    ("covariance", 3),
    ("gravity", "local_gravity_mps2"),
    ("gravity", "truth_g"),
    ("temperature", "t_ref_degC"),
    ("model", "t_ref_degC"),
    ("gyro",),
    ("gyro", "bias_dps"),
    ("gyro", "bias_dps", 1),
    ("gyro", "matrix", 0, 0),
    ("gyro", "t_ref_degC"),
    ("sources",),
    ("fit",),
]


@pytest.fixture(scope="module")
def cal_dict(good) -> dict:
    c = json.loads(good["cal"].read_text())
    c["gyro"] = _gyro_section()
    return c


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(path=st.sampled_from(_CAL_PATHS), value=_json_values)
def test_calibration_validator_property(cal_dict, path, value):
    """Any value anywhere: the validator either builds a calibration whose numbers are all finite
    and physical, or raises one InputError naming the file; never another exception."""
    d = json.loads(json.dumps(cal_dict))
    x = d
    for k in path[:-1]:
        x = x[k]
    x[path[-1]] = value
    try:
        cal = calibration_from_dict(d, where="prop.json")
    except InputError as exc:
        assert str(exc).startswith("prop.json") and "\n" not in str(exc)
        return
    assert np.isfinite(cal.theta).all() and np.isfinite(cal.cov).all()
    assert 9.7 <= cal.local_gravity_mps2 <= 9.9
    if cal.gyro is not None:
        assert np.isfinite(cal.gyro.bias_dps).all() and np.isfinite(cal.gyro.matrix).all()
        assert math.isfinite(cal.gyro.t_ref_degC)
    S, b = cal.S_b()
    assert np.isfinite(S).all() and np.isfinite(b).all()


# ------------------------------------------------------------------- truncated and zero-filled MCAP


@pytest.fixture(scope="module")
def cut_head(tmp_path_factory) -> bytes:
    """The first 2/3 of a labelled session (the labels are written at the end: all lost)."""
    d = tmp_path_factory.mktemp("cut")
    s = synth_session(seed=3, hold_s=20.0, move_s=1.0, rate_hz=200.0)
    data = write_session(d / "s.mcap", s, chunk_size=64 * 1024).read_bytes()
    return data[: len(data) * 2 // 3]


@pytest.mark.parametrize("tail", [0, 20 * 1024**2, 2 * 1024**3], ids=["cut", "zeros-20MiB", "zeros-2GB"])
@pytest.mark.parametrize("cmd", ["segment", "fit"])
def test_truncated_without_labels_says_truncated_and_zero_tails_cost_nothing(
    cut_head, tmp_path, capsys, tail, cmd
):
    src = _sparse(tmp_path / "cut.mcap", len(cut_head) + tail, cut_head)
    before = snapshot(tmp_path)
    capsys.readouterr()
    t0 = time.process_time()
    rc = main([cmd, str(src), "-o", str(tmp_path / "o.json")])
    cpu_s = time.process_time() - t0
    *warned, err = capsys.readouterr().err.strip().splitlines()  # a chunk cut by the zeros is named
    assert all(w.startswith("accellog: warning: ") and "damaged chunk" in w for w in warned), warned
    assert rc == 2 and err.startswith("accellog: error: "), err
    assert "cut.mcap" in err and "truncated" in err, err
    if tail and cmd == "segment":
        assert "zero-filled space at byte" in err and "MiB not read" in err, err
    assert snapshot(tmp_path) == before
    assert cpu_s < 5.0, f"{cpu_s:.1f} s of CPU"


def test_apply_on_a_truncated_file_notes_what_was_recovered(cut_head, good, tmp_path, capsys):
    src = tmp_path / "cut.mcap"
    src.write_bytes(cut_head)
    capsys.readouterr()
    assert main(["apply", str(src), "--cal", str(good["cal"]), "-o", str(tmp_path / "o.mcap")]) == 0
    err = capsys.readouterr().err
    assert "accellog: note: " in err and "cut.mcap: truncated file recovered" in err, err


@pytest.mark.slow
def test_door_in_a_real_process(good, tmp_path):
    """The same promise from a shell: one line, exit 2, nothing written (no in-process catch helps)."""
    import subprocess
    import sys

    cases = [
        ["simulate", "--hold", "inf", "-o", str(tmp_path / "s.mcap")],
        ["fit", str(_sparse(tmp_path / "nul.csv", 1 << 30)), "-o", str(tmp_path / "c.json")],
        ["evaluate", str(good["mcap"]), "--cal", str(_write(tmp_path / "deep.json", _deep(100_000)))],
    ]
    for argv in cases:
        before = snapshot(tmp_path)
        p = subprocess.run(
            [sys.executable, "-m", "accellog", *argv], capture_output=True, text=True, timeout=60
        )
        err = p.stderr.strip()
        assert p.returncode == 2 and err.startswith("accellog: error: ") and "\n" not in err, err
        assert snapshot(tmp_path) == before


_SCENARIO_KEYS = sorted(
    [*(f.name for f in dataclasses.fields(Scenario)), "i2c_error_rate"]
)  # + old flat form
_TABLE_KEYS = [
    "i2c_error_rate",
    "host_stall_s",
    "kind",
    "T",
    "T0",
    "rate_degC_per_s",
    "t_s",
    "T_start",
    "T_end",
    "tau_s",
    "bias_g",
    "field_uT",
    "noise_uT",
]
_scenario_values = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers(-(10**20), 10**20) | st.text(max_size=6),
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.sampled_from(_TABLE_KEYS), kids, max_size=4),
    max_leaves=10,
)


@settings(max_examples=120, deadline=None)
@given(data=st.dictionaries(st.sampled_from(_SCENARIO_KEYS), _scenario_values, max_size=3))
def test_scenario_door_property(data):
    """Any scenario table: refused with one InputError, or a scenario whose numbers are all finite
    and whose session can run (sensor model built, duration, temperature and faults checked)."""
    try:
        sc = Scenario.from_dict(data, where="prop.toml")
        model, motion = build_sensor_model(sc)
        check_session_runs(sc, model.temperature, motion.duration_s)
    except InputError as exc:
        assert "\n" not in str(exc)
        return
    assert all(math.isfinite(v) for v in (sc.hold_s, sc.move_s, sc.label_margin_s, sc.local_gravity_mps2))
    assert 0 <= sc.label_margin_s < sc.hold_s / 2 and sc.seed >= 0 and sc.chip_seed >= 0


def test_json_of_a_million_containers_is_refused_before_parsing(tmp_path):
    from accellog.core.textin import read_json

    p = _write(tmp_path / "lists.json", "[" + "[]," * 1_000_001 + "[]]")
    with pytest.raises(InputError, match=r"lists\.json: JSON with 1,000,003 arrays/objects"):
        read_json(p)


def test_a_time_beyond_int64_nanoseconds_is_refused_not_wrapped(tmp_path):
    s = synth_session(seed=3, hold_s=2.0, move_s=1.0, rate_hz=100.0)
    s.t_s[-1] = 1e300  # would become -9.2e9 s through astype(int64)
    with pytest.raises(InputError, match=r"time stamp 1e\+300 s at sample \d+ does not fit int64"):
        write_session(tmp_path / "o.mcap", s)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "tail, match",
    [
        (bytes(9_000_000), "zero-filled space at byte 8; the last 8.6 MiB not read"),
        ((b"\x80" + bytes(8)) * 1_000_000, r"no MCAP record \(opcode 0x80\) at byte 8"),
        (b"\x06" + (10**9).to_bytes(8, "little") + bytes(100), "claims 1000000000 bytes, past the end"),
    ],
    ids=["zeros", "unknown-opcodes", "length-past-end"],
)
def test_salvage_scan_stops_at_once(tail, match):
    """The salvaging scan ends at the first record that cannot be MCAP, in O(1) (not 9 bytes at a
    time through 9 MB), and never allocates a length the file does not have."""
    import io

    from accellog.store.collect import _SalvageReader
    from accellog.store.layout import MCAP_MAGIC

    data = MCAP_MAGIC + tail
    t0 = time.process_time()
    with pytest.raises(Exception, match=match):
        list(_SalvageReader(io.BytesIO(data), len(data)).records)
    assert time.process_time() - t0 < 0.5
