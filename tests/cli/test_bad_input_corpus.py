"""A standing corpus of bad inputs (issue 12, item 8): files, CSV, JSON, TOML, plugins, paths, options.

Every case builds its (broken) input in a fresh folder and runs the CLI in-process
(accellog.cli.main). Promise checked for each: a non-zero exit, exactly one stderr line
``accellog: error: ...`` naming the file or option and the place, no traceback, and nothing
written: the folder holds the same files with the same bytes afterwards (no output, no temporary
or lock file, no input replaced).
"""

from __future__ import annotations

import gc
import inspect
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from support.sessions import synth_session

from accellog.cli import main
from accellog.core.session import PoseLabel
from accellog.store.writer import write_session

# ----------------------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> dict[str, Path]:
    """Good inputs every case may copy: a six-pose session, its calibration, observations, a CSV."""
    d = tmp_path_factory.mktemp("good")
    s = synth_session(seed=3, hold_s=5.0, move_s=1.0, rate_hz=100.0)
    mcap = write_session(d / "six.mcap", s, chunk_size=8 * 1024)
    cal, obs = d / "cal.json", d / "obs.json"
    assert main(["fit", str(mcap), "--model", "model3", "-o", str(cal)]) == 0
    assert main(["segment", str(mcap), "-o", str(obs), "--json"]) == 0
    csv = d / "six.csv"
    rows = ["t,ax,ay,az,pose"]
    for p in s.poses:
        k = s.slice_time(p.start_s, p.end_s)
        for i in range(k.start, k.stop, 2):
            rows.append(
                f"{s.t_s[i]:.5f},{s.accel_g[i, 0]:.6f},{s.accel_g[i, 1]:.6f},{s.accel_g[i, 2]:.6f},{p.name}"
            )
    csv.write_text("\n".join(rows) + "\n")
    return {"mcap": mcap, "cal": cal, "obs": obs, "csv": csv, "session": s}


def _snapshot(d: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(d)): (p.read_bytes() if p.is_file() else None) for p in sorted(d.rglob("*"))}


@dataclass
class Case:
    id: str
    build: Callable[[Path, dict], list[str]]  # writes the bad input in a folder, returns argv
    needles: tuple[str, ...]  # each must appear in the error line


CASES: list[Case] = []


def case(id: str, *needles: str):
    def deco(fn):
        CASES.append(Case(id, fn, needles))
        return fn

    return deco


def add(id: str, build, *needles: str) -> None:
    CASES.append(Case(id, build, needles))


def cp(good: dict, key: str, d: Path, name: str | None = None) -> Path:
    dst = d / (name or good[key].name)
    shutil.copy(good[key], dst)
    return dst


# ----------------------------------------------------------------------- sessions (MCAP) x commands


_VARIANTS: dict[Callable, bytes] = {}


def _session_variant(mutate: Callable) -> Callable[[Path, dict], Path]:
    """The good session with `mutate` applied, as bad.mcap (built once, copied per case)."""

    def make(d: Path, good: dict) -> Path:
        p = d / "bad.mcap"
        if mutate not in _VARIANTS:
            s = synth_session(seed=3, hold_s=5.0, move_s=1.0, rate_hz=100.0)
            mutate(s)
            _VARIANTS[mutate] = write_session(p, s).read_bytes()
        p.write_bytes(_VARIANTS[mutate])
        return p

    return make


def _dup_time(s):
    s.t_s[300] = s.t_s[299]


def _decreasing_time(s):
    s.t_s[400], s.t_s[401] = s.t_s[401], s.t_s[400]


def _one_sample(s):
    for name in ("t_s", "accel_g", "accel_counts", "temp_degC"):
        setattr(s, name, getattr(s, name)[:1])
    s.sample_index = s.sample_index[:1]
    s.poses = []


def _zero_duration(s):
    s.t_s[:] = 0.0


def _flip_label(s):  # a hold labelled +z that is really -z
    p = s.poses[1]
    s.poses[1] = PoseLabel("+z", p.start_s, p.end_s, (0.0, 0.0, 1.0), None, 1)


def _swap_labels(s):  # +x and -x swapped
    a, b = s.poses[4], s.poses[5]
    s.poses[4] = PoseLabel(b.name, a.start_s, a.end_s, b.up_sensor, None, 0)
    s.poses[5] = PoseLabel(a.name, b.start_s, b.end_s, a.up_sensor, None, 0)


def _wrong_axis(s):  # a +y hold labelled +x
    p = s.poses[2]
    s.poses[2] = PoseLabel("+x", p.start_s, p.end_s, (1.0, 0.0, 0.0), None, 1)


def _dup_pose(s):
    p = s.poses[3]
    s.poses[3] = PoseLabel(s.poses[1].name, p.start_s, p.end_s, s.poses[1].up_sensor, None, 0)


def _overlap(s):
    p = s.poses[2]
    s.poses[2] = PoseLabel(p.name, s.poses[1].start_s + 1.0, p.end_s, p.up_sensor, None, 0)


def _end_before_start(s):
    p = s.poses[2]
    s.poses[2] = PoseLabel(p.name, p.end_s, p.start_s, p.up_sensor, None, 0)


def _no_labels(s):
    s.poses = []


def _nan(s):
    s.accel_counts = None
    s.meta = s.meta.replace(accel_lsb_per_g=None)
    k = s.slice_time(s.poses[0].start_s + 2.0, s.poses[0].start_s + 2.2)
    s.accel_g[k] = np.nan


def _counts_as_g(s):
    s.accel_g = s.accel_counts.astype(float)
    s.accel_counts = None
    s.meta = s.meta.replace(accel_lsb_per_g=None)


def _missing_poses(s):
    s.poses = s.poses[:3]


def _not_unit_up(s):
    p = s.poses[0]
    s.poses[0] = PoseLabel(p.name, p.start_s, p.end_s, (0.0, 0.0, 2.0), None, 0)


SESSION_BAD = {
    "dup_time": (_dup_time, ("bad.mcap", "duplicated time stamp at sample 300")),
    "decreasing_time": (_decreasing_time, ("bad.mcap", "decreasing time stamp at sample 401")),
    "one_sample": (_one_sample, ("bad.mcap", "1 sample")),
    "zero_duration": (_zero_duration, ("bad.mcap", "zero duration")),
    "label_flipped": (_flip_label, ("bad.mcap", "pose '+z'", "looks like '-z'", "--relabel")),
    "labels_swapped": (_swap_labels, ("bad.mcap", "pose '-x'", "looks like '+x'")),
    "label_wrong_axis": (_wrong_axis, ("bad.mcap", "pose '+x'", "looks like '+y'")),
    "dup_pose": (_dup_pose, ("bad.mcap", "labelled twice")),
    "overlap": (_overlap, ("bad.mcap", "overlap")),
    "end_before_start": (_end_before_start, ("bad.mcap", "<= start")),
    "nan": (_nan, ("bad.mcap", "NaN")),
    "counts_as_g": (_counts_as_g, ("bad.mcap", "counts declared as g")),
    "not_unit_up": (_not_unit_up, ("bad.mcap", "not a unit 3-vector")),
}
SESSION_CMDS = {
    "fit": lambda d, g, src: ["fit", str(src), "-o", str(d / "c.json")],
    "fit_rrd": lambda d, g, src: ["fit", str(src), "-o", str(d / "c.json"), "--rrd", str(d / "r.rrd")],
    "segment": lambda d, g, src: ["segment", str(src), "-o", str(d / "o.json")],
    "diagnose": lambda d, g, src: ["diagnose", str(src)],
}
for _name, (_mut, _needles) in SESSION_BAD.items():
    for _cmd, _argv in SESSION_CMDS.items():

        def _build(d, g, _mut=_mut, _argv=_argv):
            return _argv(d, g, _session_variant(_mut)(d, g))

        add(f"session-{_name}-{_cmd}", _build, *_needles)
for _name in ("no_labels", "missing_poses"):
    _mut = {"no_labels": _no_labels, "missing_poses": _missing_poses}[_name]
    # fit of a six-face session without labels fits what the faces identify (test_unlabelled_logger_csv)
    for _cmd in ("fit", "fit_rrd") if _name == "missing_poses" else ("segment",):
        add(
            f"session-{_name}-{_cmd}",
            lambda d, g, _mut=_mut, _cmd=_cmd: SESSION_CMDS[_cmd](d, g, _session_variant(_mut)(d, g)),
            "bad.mcap",
        )
for _name in ("dup_time", "decreasing_time", "one_sample", "zero_duration"):
    _mut = SESSION_BAD[_name][0]
    add(
        f"session-{_name}-integrate",
        lambda d, g, _mut=_mut: ["integrate", str(_session_variant(_mut)(d, g)), "-o", str(d / "i.csv")],
        *SESSION_BAD[_name][1],
    )
    add(
        f"session-{_name}-evaluate",
        lambda d, g, _mut=_mut: [
            "evaluate",
            str(_session_variant(_mut)(d, g)),
            "--cal",
            str(cp(g, "cal", d)),
        ],
        *SESSION_BAD[_name][1],
    )


# ------------------------------------------------------------------------------- damaged MCAP files


def _mcap_bytes(d: Path, g: dict, data: bytes, name: str = "bad.mcap") -> Path:
    p = d / name
    p.write_bytes(data)
    return p


def _header_only(g: dict) -> bytes:
    return g["mcap"].read_bytes()[:200]


MCAP_DAMAGE = {
    "empty": (lambda g: b"", ("bad.mcap",)),
    "magic_only": (lambda g: g["mcap"].read_bytes()[:8], ("bad.mcap",)),
    "header_only": (_header_only, ("bad.mcap",)),
    "cut_5pct": (lambda g: g["mcap"].read_bytes()[: len(g["mcap"].read_bytes()) // 20], ("bad.mcap",)),
    "garbage": (
        lambda g: bytes(np.random.default_rng(1).integers(0, 256, 5000, dtype=np.uint8)),
        ("bad.mcap",),
    ),
    "text": (lambda g: b"t,ax,ay,az\n0,0,0,1\n", ("bad.mcap",)),
    "json": (lambda g: b'{"format": "accellog.calibration"}', ("bad.mcap",)),
    "wrong_magic": (lambda g: b"\x89XCAP0\r\n" + g["mcap"].read_bytes()[8:], ("bad.mcap",)),
    "zeros": (lambda g: bytes(4096), ("bad.mcap",)),
}
for _name, (_fn, _needles) in MCAP_DAMAGE.items():
    for _cmd in ("fit", "segment", "apply"):

        def _build(d, g, _fn=_fn, _cmd=_cmd):
            src = _mcap_bytes(d, g, _fn(g))
            if _cmd == "apply":
                return ["apply", str(src), "--cal", str(cp(g, "cal", d)), "-o", str(d / "out.mcap")]
            return SESSION_CMDS[_cmd](d, g, src)

        add(f"mcap-{_name}-{_cmd}", _build, *_needles)


@case("mcap-directory-input", "in.mcap")
def _(d, g):
    (d / "in.mcap").mkdir()
    return ["fit", str(d / "in.mcap"), "-o", str(d / "c.json")]


@case("mcap-missing-input", "nothere.mcap", "no such file")
def _(d, g):
    return ["fit", str(d / "nothere.mcap"), "-o", str(d / "c.json")]


@case("mcap-unknown-suffix", "s.dat", "unknown input type")
def _(d, g):
    (d / "s.dat").write_bytes(g["mcap"].read_bytes())
    return ["fit", str(d / "s.dat"), "-o", str(d / "c.json")]


@case("mcap-truncated-before-poses", "cut.mcap")
def _(d, g):
    data = g["mcap"].read_bytes()
    (d / "cut.mcap").write_bytes(data[: len(data) // 2])
    return ["fit", str(d / "cut.mcap"), "-o", str(d / "c.json")]


# ---------------------------------------------------------------------------- calibration JSON files


def _cal_variant(edit: Callable[[dict], object]) -> Callable[[Path, dict], Path]:
    def make(d: Path, g: dict) -> Path:
        c = json.loads(g["cal"].read_text())
        r = edit(c)
        p = d / "badcal.json"
        p.write_text(r if isinstance(r, str) else json.dumps(c))
        return p

    return make


def _set_param(name: str, value):
    def edit(c):
        for p in c["params"]:
            if p["name"] == name:
                p["value"] = value

    return edit


def _set(path: list, value):
    def edit(c):
        x = c
        for k in path[:-1]:
            x = x[k]
        x[path[-1]] = value

    return edit


def _del(key: str):
    def edit(c):
        c.pop(key)

    return edit


CAL_BAD = {
    "S_xx_1e308": (_set_param("S_xx", 1e308), ("badcal.json", "S_xx", "absurd")),
    "S_zz_negative": (_set_param("S_zz", -0.002), ("badcal.json", "S_zz", "absurd")),
    "S_yy_zero": (_set_param("S_yy", 0.0), ("badcal.json", "S_yy")),
    "b_x_5g": (_set_param("b_x", 5.0), ("badcal.json", "b_x")),
    "b_z_minus_2g": (_set_param("b_z", -2.0), ("badcal.json", "b_z")),
    "S_xy_huge": (_set_param("S_xy", 0.9), ("badcal.json", "S_xy")),
    "value_null": (_set_param("b_y", None), ("badcal.json",)),
    "value_string": (_set_param("b_y", "abc"), ("badcal.json",)),
    "cov_wrong_shape": (_set(["covariance"], [[1.0]]), ("badcal.json", "covariance")),
    "cov_negative_var": (
        lambda c: c["covariance"][0].__setitem__(0, -1.0),
        ("badcal.json", "negative variance", "b_x"),
    ),
    "cov_nan": (lambda c: c["covariance"][1].__setitem__(1, "x"), ("badcal.json",)),
    "gravity_zero": (_set(["gravity", "local_gravity_mps2"], 0.0), ("badcal.json", "local_gravity_mps2")),
    "gravity_moon": (_set(["gravity", "local_gravity_mps2"], 1.62), ("badcal.json", "local_gravity_mps2")),
    "truth_g_2": (_set(["gravity", "truth_g"], 2.0), ("badcal.json", "truth_g")),
    "no_format": (_del("format"), ("badcal.json", "not an accellog calibration")),
    "future_version": (_set(["format_version"], 99), ("badcal.json", "format_version")),
    "no_params": (_del("params"), ("badcal.json", "params")),
    "no_gravity": (_del("gravity"), ("badcal.json", "gravity")),
    "params_renamed": (
        lambda c: c["params"][0].__setitem__("name", "zz"),
        ("badcal.json", "do not match"),
    ),
    "unknown_model": (_set(["model", "terms"], ["bogus"]), ("badcal.json",)),
    "top_level_list": (lambda c: "[1, 2, 3]", ("badcal.json", "not an accellog calibration")),
    "not_json": (lambda c: "format = 'toml'\n", ("badcal.json", "not valid JSON")),
    "empty": (lambda c: "", ("badcal.json",)),
    "truncated": (lambda c: json.dumps(c)[:300], ("badcal.json", "not valid JSON")),
    "binary": (lambda c: "\x00\x01\x02", ("badcal.json",)),
}
CAL_CMDS = {
    "evaluate": lambda d, g, cal: ["evaluate", str(cp(g, "mcap", d)), "--cal", str(cal)],
    "apply": lambda d, g, cal: ["apply", str(cp(g, "mcap", d)), "--cal", str(cal), "-o", str(d / "out.mcap")],
    "integrate": lambda d, g, cal: [
        "integrate",
        str(cp(g, "mcap", d)),
        "--cal",
        str(cal),
        "-o",
        str(d / "i.csv"),
    ],
}
for _name, (_edit, _needles) in CAL_BAD.items():
    for _cmd, _argv in CAL_CMDS.items():
        add(
            f"cal-{_name}-{_cmd}",
            lambda d, g, _edit=_edit, _argv=_argv: _argv(d, g, _cal_variant(_edit)(d, g)),
            *_needles,
        )


@case("cal-imucal-file", "example_cal.json", "imucal")
def _(d, g):
    src = Path(__file__).resolve().parents[3] / "shared" / "data" / "imucal" / "example_cal.json"
    if not src.is_file():
        pytest.skip("shared data not found")
    shutil.copy(src, d / "example_cal.json")
    return ["evaluate", str(cp(g, "mcap", d)), "--cal", str(d / "example_cal.json")]


@case("cal-missing", "nocal.json")
def _(d, g):
    return ["evaluate", str(cp(g, "mcap", d)), "--cal", str(d / "nocal.json")]


# ---------------------------------------------------------------------------- observation JSON files


def _obs_variant(edit) -> Callable[[Path, dict], list[str]]:
    def build(d, g):
        o = json.loads(g["obs"].read_text())
        r = edit(o)
        p = d / "badobs.json"
        p.write_text(r if isinstance(r, str) else json.dumps(o))
        return ["fit", str(p), "-o", str(d / "c.json")]

    return build


add("obs-no-format", _obs_variant(lambda o: o.pop("format")), "badobs.json")
add("obs-truncated", _obs_variant(lambda o: json.dumps(o)[:200]), "badobs.json", "not valid JSON")
add("obs-list", _obs_variant(lambda o: "[]"), "badobs.json")
add("obs-empty", _obs_variant(lambda o: ""), "badobs.json")
add("obs-wrong-format", _obs_variant(lambda o: o.__setitem__("format", "other")), "badobs.json")
add("obs-calibration-given", lambda d, g: ["fit", str(cp(g, "cal", d)), "-o", str(d / "c.json")], "cal.json")


# ----------------------------------------------------------------------------------------- CSV files


def _csv(text: str, name: str = "bad.csv") -> Callable[[Path, dict], Path]:
    def make(d, g):
        p = d / name
        p.write_text(text)
        return p

    return make


CSV_BAD = {
    "empty": "",
    "header_only": "t,ax,ay,az\n",
    "one_row": "t,ax,ay,az\n0.0,0,0,1\n",
    "zero_duration": "t,ax,ay,az\n0.0,0,0,1\n0.0,0,0,1\n0.0,0,0,1\n",
    "dup_time": "t,ax,ay,az\n" + "".join(f"{0.01 * (i - (i == 5)):.2f},0,0,1\n" for i in range(20)),
    "decreasing_time": "t,ax,ay,az\n" + "".join(f"{0.01 * (20 - i):.2f},0,0,1\n" for i in range(20)),
    "not_numeric": "t,ax,ay,az\n0.0,0,0,1\n0.01,zero,0,1\n",
    "missing_column": "t,ax,ay\n0.0,0,0\n0.01,0,0\n",
    "short_row": "t,ax,ay,az\n0.0,0,0,1\n0.01,0,0\n",
    "nan": "t,ax,ay,az\n0.0,0,0,1\n0.01,nan,0,1\n0.02,0,0,1\n",
    "binary": "\x00\x01\x02\x03",
    "no_header": "0.0,0,0,1\n0.01,0,0,1\n",
    "unknown_pose": "t,ax,ay,az,pose\n" + "".join(f"{0.01 * i:.2f},0,0,1,+w\n" for i in range(20)),
}
for _name, _text in CSV_BAD.items():
    add(
        f"csv-{_name}-import",
        lambda d, g, _t=_text: ["import", "csv", str(_csv(_t)(d, g)), "-o", str(d / "o.mcap")],
        "bad.csv",
    )
    add(
        f"csv-{_name}-fit",
        lambda d, g, _t=_text: ["fit", str(_csv(_t)(d, g)), "-o", str(d / "c.json")],
        "bad.csv",
    )


@case("csv-one-column-mapped-twice", "--columns", "'ax' is mapped twice", "ax and ay")
def _csv_column_twice(d: Path, good: dict) -> list[str]:
    csv = cp(good, "csv", d)
    return ["import", "csv", str(csv), "--columns", "ax=ax,ay=ax,az=az", "-o", str(d / "o.mcap")]


@case("csv-out-is-input", "six.csv", "input")
def _(d, g):
    src = cp(g, "csv", d)
    return ["import", "csv", str(src), "-o", str(src)]


# ---------------------------------------------------------------------------------------- TOML files


def _pipeline(text: str):
    def build(d, g):
        p = d / "pipe.toml"
        p.write_text(text)
        return ["run", str(p), str(cp(g, "mcap", d))]

    return build


GOOD_PIPE = (Path(__file__).resolve().parents[2] / "pipelines" / "six_position.toml").read_text()
PIPE_BAD = {
    "not_toml": "[pipeline\nname = 1",
    "empty": "",
    "unknown_table": GOOD_PIPE + "\n[bogus]\nx = 1\n",
    "unknown_key": GOOD_PIPE.replace("[segment]\n", "[segment]\nbogus = 1\n"),
    "wrong_type": GOOD_PIPE.replace("window_s = 2.0", 'window_s = "two"'),
    "no_pipeline_table": "[segment]\nwindow_s = 2.0\n",
    "inputs_not_list": GOOD_PIPE.replace(
        'inputs = ["calibration", "test", "drift_fit", "drift_apply"]', 'inputs = "calibration"'
    ),
    "binary": "\x00\x01",
    "window_1e308": GOOD_PIPE.replace("window_s = 2.0", "window_s = 1e308"),
    "report_at_negative": GOOD_PIPE.replace("at_s = 60.0", "at_s = -5.0"),
    "times_negative": GOOD_PIPE.replace("times_s = [10.0, 30.0, 60.0]", "times_s = [10.0, -30.0]"),
    "gravity_on_the_moon": GOOD_PIPE.replace("local_gravity_mps2 = 9.797", "local_gravity_mps2 = 1.62"),
}
for _name, _text in PIPE_BAD.items():
    add(f"pipeline-{_name}", _pipeline(_text), "pipe.toml")
add("pipeline-wrong-input-count", _pipeline(GOOD_PIPE), "pipe.toml", "takes 4 inputs")


def _scenario(text: str):
    def build(d, g):
        p = d / "sc.toml"
        p.write_text(text)
        return ["simulate", "--scenario", str(p), "-o", str(d / "sim.mcap")]

    return build


SCENARIO_BAD = {
    "not_toml": ("hold_s = = 3", ()),
    "unknown_key": ("bogus_key = 1\n", ("bogus_key",)),
    "wrong_type": ('hold_s = "long"\n', ("hold_s",)),
    "negative_hold": ("hold_s = -1.0\n", ("hold_s",)),
    "zero_rate": ("sample_rate_hz = 0.0\n", ("sample_rate_hz",)),
    "bad_protocol": ('protocol = "+q,-q"\n', ()),
    "bad_errors": ('errors = "awful"\n', ("errors",)),
    "bad_motion": ('motion = "flying"\n', ("motion",)),
    "bad_temperature": ('temperature = {kind = "sauna"}\n', ("temperature",)),
    "bad_range": ("accel_range_g = 3\n", ("accel_range_g",)),
    "fault_rate_above_1": ("i2c_error_rate = 1.5\n", ("i2c_error_rate",)),
    "fault_negative_stall": ("[faults]\nhost_stall_s = -0.1\n", ("host_stall_s", "faults")),
    "fault_unknown_in_table": ("[faults]\nbogus = 1\n", ("faults",)),
    "binary": ("\x00\x01", ()),
    "empty": ("", ("sets nothing",)),
    "only_comments": ("# a scenario\n\n", ("sets nothing",)),
    "gyro_errors_misspelt": ('gyro_error = "datasheet"\n', ("did you mean gyro_errors?",)),
}
for _name, (_text, _extra) in SCENARIO_BAD.items():
    add(f"scenario-{_name}", _scenario(_text), "sc.toml", *_extra)
# checked when the chip is built (the line names the scenario, not its file)
add(
    "scenario-temp_bias_1e3",
    _scenario("[set]\ntemp_bias_g_per_degC = 1e3\n"),
    "temp_bias_g_per_degC",
    "physical",
)
add(
    "scenario-temp_scale_huge", _scenario("[set]\ntemp_scale_per_degC = [0.1, 0, 0]\n"), "temp_scale_per_degC"
)


# ---------------------------------------------------------------------------------- effects plugins


def _plugin(body: str, argv_extra: tuple[str, ...] = ("--add", "mine")):
    def build(d, g):
        p = d / "fx.py"
        p.write_text(body)
        return ["fit", str(cp(g, "mcap", d)), "--effects-file", str(p), *argv_extra, "-o", str(d / "c.json")]

    return build


HEAD = "import numpy as np\nfrom accellog.calibrate.model.effects import Effect, per_axis\n\n"


def _effect(fn_body: str) -> str:
    return (
        HEAD
        + "def h(p, f_g, drivers):\n"
        + "".join(f"    {line}\n" for line in fn_body.splitlines())
        + "\nMINE = Effect(name='mine', params=per_axis('m', 'g', 0.0, 1e-3), contribution=h)\n"
    )


PLUGIN_BAD = {
    "syntax": ("def f(:\n", ("fx.py:1", "effects file failed to load")),
    "raises_on_import": (HEAD + "\n\nraise RuntimeError('boom')\n", ("fx.py:6", "RuntimeError: boom")),
    "exit_on_import": (HEAD + "import sys\nsys.exit(3)\n", ("fx.py:5", "sys.exit(3)")),
    "import_error": ("import not_a_module_xyz\n", ("fx.py:1", "ModuleNotFoundError")),
    "contribution_raises": (_effect("raise ValueError('bad physics')"), ("fx.py:5", "'mine'", "bad physics")),
    "contribution_exits": (_effect("import sys\nsys.exit(0)"), ("fx.py:6", "'mine'", "sys.exit(0)")),
    "contribution_keyerror": (_effect("return drivers['nope'] * f_g"), ("fx.py:5", "'mine'", "KeyError")),
    "contribution_zero_div": (_effect("return f_g / 0 + 1 // 0"), ("fx.py:5", "'mine'", "ZeroDivisionError")),
    "contribution_wrong_shape": (_effect("return np.zeros(7)"), ("fx.py", "'mine'", "(n, 3)")),
    "contribution_returns_none": (_effect("return None"), ("fx.py", "'mine'")),
    "contribution_returns_str": (_effect("return 'x'"), ("fx.py", "'mine'")),
    "no_effects": (HEAD + "x = 1\n", ("fx.py", "no effects found")),
    "not_callable": (
        HEAD + "MINE = Effect(name='mine', params=per_axis('m', 'g'), contribution=3)\n",
        ("fx.py", "callable"),
    ),
    "clash": (
        HEAD + "MINE = Effect(name='bias', params=per_axis('m', 'g'), contribution=lambda p, f, d: f)\n",
        ("fx.py", "clashes"),
    ),
    "effects_not_effect": (HEAD + "EFFECTS = [1, 2]\n", ("fx.py", "not an accellog")),
    "empty_file": ("", ("fx.py", "no effects found")),
}
for _name, (_body, _needles) in PLUGIN_BAD.items():
    add(f"plugin-{_name}", _plugin(_body), *_needles)
add(
    "plugin-missing-file",
    lambda d, g: [
        "fit",
        str(cp(g, "mcap", d)),
        "--effects-file",
        str(d / "none.py"),
        "-o",
        str(d / "c.json"),
    ],
    "none.py",
    "no such effects file",
)
add("plugin-not-python", _plugin("\x00\x01binary", ()), "fx.py")


# ------------------------------------------------------------------------------------- output paths


def _outdir(cmd: str):
    def build(d, g):
        (d / "out").mkdir()
        src = cp(g, "mcap", d)
        cal = cp(g, "cal", d)
        o = str(d / "out")
        return {
            "fit": ["fit", str(src), "-o", o],
            "apply": ["apply", str(src), "--cal", str(cal), "-o", o],
            "segment": ["segment", str(src), "-o", o],
            "drift": ["drift", str(src), "--cal", str(cal), "-o", o],
            "integrate": ["integrate", str(src), "-o", o],
            "simulate": ["simulate", "-o", o, "--hold", "2"],
            "import": ["import", "csv", str(cp(g, "csv", d)), "-o", o],
            "fit_rrd": ["fit", str(src), "-o", str(d / "c.json"), "--rrd", o],
            "record": ["record", "--sim", "--fast", "-o", o, "--hold", "1", "--protocol", "+z"],
            "run_rrd": ["run", str(d / "p.toml"), str(src), "--rrd", o],
        }[cmd]

    return build


for _cmd in (
    "fit",
    "apply",
    "segment",
    "drift",
    "integrate",
    "simulate",
    "import",
    "fit_rrd",
    "record",
    "run_rrd",
):
    add(f"path-out-is-dir-{_cmd}", _outdir(_cmd), "out", "directory")


def _same(cmd: str):
    def build(d, g):
        src = cp(g, "mcap", d)
        cal = cp(g, "cal", d)
        obs = cp(g, "obs", d)
        return {
            "fit_mcap": ["fit", str(src), "-o", str(src)],
            "fit_obs": ["fit", str(obs), "-o", str(obs)],
            "fit_rrd_is_input": ["fit", str(src), "-o", str(d / "c.json"), "--rrd", str(src)],
            "fit_rrd_is_output": ["fit", str(src), "-o", str(d / "c.json"), "--rrd", str(d / "c.json")],
            "apply": ["apply", str(src), "--cal", str(cal), "-o", str(src)],
            "apply_cal": ["apply", str(src), "--cal", str(cal), "-o", str(cal)],
            "drift_cal": ["drift", str(src), "--cal", str(cal), "-o", str(cal)],
            "segment": ["segment", str(src), "-o", str(src)],
            "integrate": ["integrate", str(src), "-o", str(src)],
            "fit_via_dotdot": ["fit", str(src), "-o", str(d / "x" / ".." / src.name)],
        }[cmd]

    return build


for _cmd in (
    "fit_mcap",
    "fit_obs",
    "fit_rrd_is_input",
    "fit_rrd_is_output",
    "apply",
    "apply_cal",
    "drift_cal",
    "segment",
    "integrate",
):
    add(f"path-out-is-input-{_cmd}", _same(_cmd), "input" if "is_output" not in _cmd else "same file")


@case("path-out-is-input-symlink", "input")
def _(d, g):
    src = cp(g, "mcap", d)
    (d / "link.json").symlink_to(src)
    return ["fit", str(src), "-o", str(d / "link.json")]


@case("path-out-is-input-hardlink", "input")
def _(d, g):
    src = cp(g, "mcap", d)
    (d / "hard.mcap").hardlink_to(src)
    return ["apply", str(src), "--cal", str(cp(g, "cal", d)), "-o", str(d / "hard.mcap")]


@case("path-rrd-missing-folder", "missing", "folder does not exist")
def _(d, g):
    return ["fit", str(cp(g, "mcap", d)), "-o", str(d / "c.json"), "--rrd", str(d / "missing" / "x.rrd")]


@case("path-apply-missing-folder", "missing", "folder does not exist")
def _(d, g):
    return [
        "apply",
        str(cp(g, "mcap", d)),
        "--cal",
        str(cp(g, "cal", d)),
        "-o",
        str(d / "missing" / "o.mcap"),
    ]


@case("path-simulate-existing", "exists.mcap", "--force")
def _(d, g):
    (d / "exists.mcap").write_bytes(b"precious")
    return ["simulate", "-o", str(d / "exists.mcap"), "--hold", "2"]


@case("path-record-existing", "exists.mcap", "--force")
def _(d, g):
    (d / "exists.mcap").write_bytes(b"precious session")
    return ["record", "--sim", "--fast", "-o", str(d / "exists.mcap"), "--hold", "1", "--protocol", "+z"]


@case("path-run-output-dir-is-file", "results", "file")
def _(d, g):
    (d / "results").write_text("not a folder")
    return [
        "run",
        str(Path(__file__).resolve().parents[2] / "pipelines" / "six_position.toml"),
        *[str(cp(g, "mcap", d))] * 4,
        "-o",
        str(d / "results"),
    ]


@case("path-fit-output-under-file", "afile", "not a folder")
def _(d, g):
    (d / "afile").write_text("x")
    return ["fit", str(cp(g, "mcap", d)), "-o", str(d / "afile" / "c.json")]


@case("path-input-is-dir-evaluate", "dir.mcap")
def _(d, g):
    (d / "dir.mcap").mkdir()
    return ["evaluate", str(d / "dir.mcap"), "--cal", str(cp(g, "cal", d))]


# ------------------------------------------------------------------------------------------- options

OPTION_BAD = {
    "record-rate-0": (["record", "--sim", "--fast", "--rate", "0"], ("--rate",)),
    "record-rate-negative": (["record", "--sim", "--fast", "--rate", "-5"], ("--rate",)),
    "record-rate-333": (["record", "--sim", "--fast", "--rate", "333"], ("--rate",)),
    "record-rate-inf": (["record", "--sim", "--fast", "--rate", "inf"], ("--rate",)),
    "record-rate-nan": (["record", "--sim", "--fast", "--rate", "nan"], ("--rate",)),
    "record-rate-text": (["record", "--sim", "--fast", "--rate", "fast"], ("--rate",)),
    "record-range-3": (["record", "--sim", "--fast", "--accel-range", "3"], ("--accel-range",)),
    "record-wait": (["record", "--sim", "--fast", "--wait", "never"], ("--wait",)),
    "record-hold-0": (["record", "--sim", "--fast", "--hold", "0"], ("--hold",)),
    "record-protocol": (["record", "--sim", "--fast", "--protocol", "+q"], ("+q",)),
    "record-address": (["record", "--sim", "--fast", "--address", "zz"], ("--address",)),
    "simulate-rate-0": (["simulate", "--rate", "0"], ("sample_rate_hz",)),
    "simulate-set-no-eq": (["simulate", "--set", "bias"], ("--set",)),
    "simulate-set-text": (["simulate", "--set", "bias=x"], ("--set",)),
    "simulate-temperature": (["simulate", "--temperature", "hot"], ("--temperature",)),
    "simulate-temperature-text": (["simulate", "--temperature", "constant:warm"], ("--temperature",)),
    "simulate-errors": (["simulate", "--errors", "awful"], ("errors",)),
    "simulate-motion": (["simulate", "--motion", "swim"], ("motion",)),
    "simulate-fault-rate": (["simulate", "--fault", "i2c_error_rate=2"], ("i2c_error_rate",)),
    "simulate-fault-unknown": (["simulate", "--fault", "gremlins=1"], ("gremlins",)),
    "simulate-fault-no-eq": (["simulate", "--fault", "i2c_error_rate"], ("--fault",)),
    "unknown-command": (["fitt"], ("fitt",)),
    "unknown-option": (["fit", "x.mcap", "--bogus"], ("--bogus",)),
}
for _name, (_argv, _needles) in OPTION_BAD.items():
    add(
        f"option-{_name}",
        lambda d, g, _argv=_argv: (
            [*_argv, "-o", str(d / "o.mcap")] if _argv[0] in ("record", "simulate") else list(_argv)
        ),
        *_needles,
    )


add(
    "option-export-device-id-beyond-32-bits",
    lambda d, g: ["export", str(cp(g, "cal", d)), "--to", "px4", "--device-id", str(2**40)],
    "--device-id",
    "32-bit",
)


def _fit_opt(*opts: str):
    return lambda d, g: ["fit", str(cp(g, "mcap", d)), "-o", str(d / "c.json"), *opts]


for _name, _opts, _needles in (
    ("model", ("--model", "model9"), ("model9",)),
    ("add", ("--add", "gremlin"), ("gremlin",)),
    ("gravity", ("--gravity", "moon"), ("moon",)),
    ("window-0", ("--window-s", "0"), ("--window-s",)),
    ("trim-huge", ("--trim-s", "100"), ("samples after trimming",)),
    ("effects-file-dir", ("--effects-file", "."), ("effects file",)),
    ("model-bias-twice", ("--model", "bias+bias"), ("'bias' twice",)),
    ("model-model3-twice", ("--model", "model3+model3"), ("model3+model3", "'cross_axis'", "twice")),
    ("model-preset-term-again", ("--model", "model3+bias"), ("'bias' twice",)),
    ("add-a-term-of-the-model", ("--model", "model2", "--add", "scale"), ("'scale' twice",)),
    ("model-with-clock", ("--model", "model3+clock"), ("model3+clock", "static pose means")),
):
    add(f"option-fit-{_name}", _fit_opt(*_opts), *_needles)


# -------------------------------------------------------------------------------------------- runner


@pytest.mark.parametrize("c", CASES, ids=[c.id for c in CASES])
def test_bad_input(c: Case, good, tmp_path, capsys):
    d = tmp_path / "case"
    d.mkdir()
    argv = c.build(d, good)
    before = _snapshot(d)
    capsys.readouterr()
    gc.collect()
    gc.disable()  # what the failed command left open stays visible (_open_readers)
    try:
        rc = main(argv)
        left_open = _open_readers()
    finally:
        gc.enable()
    err = capsys.readouterr().err.strip()
    assert rc != 0, f"exit 0: {err}"
    assert "Traceback" not in err, err
    assert err.startswith("accellog: error: ") and "\n" not in err, err
    for n in c.needles:
        assert n in err, (n, err)
    assert _snapshot(d) == before, "files were written, changed or left behind"
    assert not left_open, f"readers left for the garbage collector to close: {left_open}"


def _open_readers() -> list[str]:
    """Suspended generators of the command (not closed when it ended): the garbage collector would
    close them later on whatever thread it runs, and a reader's close joins its worker threads, which
    can deadlock inside threading (seen in CI: a collection during Thread.start)."""
    return sorted(
        f"{o.gi_code.co_filename.rsplit('/', 1)[-1]}:{o.gi_code.co_name}"
        for o in gc.get_objects()
        if inspect.isgenerator(o) and o.gi_frame is not None and "accellog" in o.gi_code.co_filename
    )


def test_corpus_size():
    assert len(CASES) >= 150, len(CASES)
