"""Every calibration field typed and bounded, by one schema (issue 46, items 2 and 3).

Each case edits a good calibration (or one fitted with a user effect) and runs a command that
reads it: a non-zero exit, one stderr line ``accellog: error: ...`` naming the field, no traceback,
the folder as before (no output, inputs intact) and no user code run. Before, these were applied
without a word (``"value": true`` read as 1, a near-singular S giving 1e10 g) or a traceback.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from support.refusal import assert_refused
from support.sessions import synth_session

from accellog.calibrate.calfile.calibration import calibration_from_dict, load_calibration
from accellog.calibrate.calfile.schema import MAX_COND_S, check_S
from accellog.cli import main
from accellog.core.errors import InputError
from accellog.store.writer import write_session

EFFECT = """
from pathlib import Path
import numpy as np
from accellog.calibrate.model.effects import Effect, per_axis
Path(__file__).with_name("MARKER").write_text("ran")
def h(p, f_g, d):
    t = d["t_in_pose_s"]
    return np.stack([p["tj_x"] * t, p["tj_y"] * t, p["tj_z"] * t], axis=1)
TJ = Effect(name="tj", params=per_axis("tj", "g/s"), drivers=("t_in_pose_s",), contribution=h)
"""


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("values_good")
    write_session(d / "six.mcap", synth_session(seed=7, hold_s=5.0, move_s=1.0, rate_hz=100.0))
    assert main(["fit", str(d / "six.mcap"), "--model", "model3", "-o", str(d / "cal.json")]) == 0
    (d / "fx.py").write_text(EFFECT)
    fx = ["--add", "tj", "--effects-file", str(d / "fx.py")]
    assert main(["fit", str(d / "six.mcap"), *fx, "-o", str(d / "user.json")]) == 0
    (d / "MARKER").unlink()  # named on the command line by the user: it ran
    return d


def _param(name: str, value) -> Callable[[dict], None]:
    def edit(c: dict) -> None:
        next(p for p in c["params"] if p["name"] == name)["value"] = value

    return edit


def _set(*keys, value) -> Callable[[dict], None]:
    def edit(c: dict) -> None:
        x = c
        for k in keys[:-1]:
            x = x[k]
        if value is _DELETE:
            del x[keys[-1]]
        else:
            x[keys[-1]] = value

    return edit


_DELETE = object()


def _near_singular_S(c: dict) -> None:
    """S = [[a, e, e], [e, a, e], [e, e, a]] with e just above -a/2: det ~ 0, every entry within
    the per-parameter limits (|S_ii - 1| <= 0.5, |S_ij| <= 0.3)."""
    for p in c["params"]:
        if p["name"] in ("S_xx", "S_yy", "S_zz"):
            p["value"] = 0.5
        elif p["name"].startswith("S_"):
            p["value"] = -0.2499999999


def _cov(edit: Callable[[np.ndarray], np.ndarray]) -> Callable[[dict], None]:
    def apply(c: dict) -> None:
        c["covariance"] = edit(np.array(c["covariance"])).tolist()

    return apply


def _not_psd(cov: np.ndarray) -> np.ndarray:
    cov[0, 1] = cov[1, 0] = 10 * np.sqrt(cov[0, 0] * cov[1, 1])
    return cov


def _asymmetric(cov: np.ndarray) -> np.ndarray:
    cov[0, 1] = cov[1, 0] + 1e-3 * cov[0, 0]
    return cov


def _huge(cov: np.ndarray) -> np.ndarray:
    cov[0, 0] = 1e300
    return cov


Edit = Callable[[dict], object]
CASES: dict[str, tuple[str, Edit, tuple[str, ...]]] = {
    # (calibration to edit, edit, words the error names)
    "value-true": ("cal", _param("b_x", True), ("b_x", "'value' = True", "finite number")),
    "value-string": ("cal", _param("S_xx", "1.0"), ("S_xx", "finite number")),
    "value-null": ("cal", _param("b_y", None), ("b_y", "finite number")),
    "value-int-beyond-float": ("cal", _param("b_z", "@BIG@"), ("params[", "beyond float range")),
    "sigma-true": ("cal", lambda c: c["params"][0].update(sigma=True), ("'sigma'",)),
    "S-near-singular": ("cal", _near_singular_S, ("near-singular", "condition number")),
    "stored-S-singular": ("cal", _set("S", value=[[1, 0, 0], [1, 0, 0], [0, 0, 1]]), ("S", "near-singular")),
    "stored-S-bool": ("cal", _set("S", value=[[True, 0, 0], [0, 1, 0], [0, 0, 1]]), ("'S'", "3 x 3 numbers")),
    "b_g-short": ("cal", _set("b_g", value=[0, 0]), ("'b_g'", "3 numbers")),
    "cov-not-psd": ("cal", _cov(_not_psd), ("covariance", "positive semi-definite")),
    "cov-asymmetric": ("cal", _cov(_asymmetric), ("covariance", "not symmetric")),
    "cov-1e300": ("cal", _cov(_huge), ("variance of b_x",)),
    "cov-bool": ("cal", lambda c: c["covariance"][0].__setitem__(0, True), ("covariance", "numbers")),
    "model-string": ("cal", _set("model", value="model3"), ("'model' must be an object",)),
    "model-int": ("cal", _set("model", value=3), ("'model' must be an object",)),
    "terms-int": ("cal", _set("model", "terms", value=3), ("'terms' must be a list",)),
    "terms-null": ("cal", _set("model", "terms", value=None), ("'terms' must be a list",)),
    "terms-missing": ("cal", _set("model", "terms", value=_DELETE), ("'terms' must be a list",)),
    "terms-not-strings": ("cal", _set("model", "terms", value=["bias", 3]), ("'terms' must be a list",)),
    "terms-duplicate": (
        "cal",
        _set("model", "terms", value=["bias", "bias", "scale", "cross_axis"]),
        ("twice", "bias"),
    ),
    "terms-unknown": ("cal", _set("model", "terms", value=["bias", "scal"]), ("unknown effect", "scal")),
    "model-name-int": ("cal", _set("model", "name", value=3), ("model 'name' must be a string",)),
    "t_ref-true": ("cal", _set("model", "t_ref_degC", value=True), ("t_ref_degC",)),
    "truth_g-true": ("cal", _set("gravity", "truth_g", value=True), ("gravity.truth_g",)),
    "software-null": ("cal", _set("software", value=None), ("'software' must be a string",)),
    "sensor-null": ("cal", _set("sensor", value=None), ("'sensor' must be an object",)),
    "sources-object": ("cal", _set("sources", value={}), ("'sources' must be a list",)),
    # a user effect with no recorded hash runs nothing (item 2)
    "user-hash-null": ("user", _set("model", "effects_file_sha256", value=None), ("tj", "no valid sha256")),
    "user-hash-missing": (
        "user",
        _set("model", "effects_file_sha256", value=_DELETE),
        ("tj", "no valid sha256"),
    ),
    "user-hash-short": ("user", _set("model", "effects_file_sha256", value="abc"), ("no valid sha256",)),
}


@pytest.mark.parametrize("cmd", ["evaluate", "export"])
@pytest.mark.parametrize("name", list(CASES))
def test_refused(name, cmd, good, tmp_path, capsys):
    which, edit, needles = CASES[name]
    d = tmp_path / "case"
    shutil.copytree(good, d)
    c = json.loads((d / f"{which}.json").read_text())
    edit(c)
    (d / "bad.json").write_text(json.dumps(c).replace('"@BIG@"', "1" + "0" * 400))
    argv = {
        "evaluate": ["evaluate", str(d / "six.mcap"), "--cal", str(d / "bad.json")],
        "export": ["export", str(d / "bad.json"), "--to", "yaml", "-o", str(d / "out.yaml")],
    }[cmd] + (["--effects-file", str(d / "fx.py")] if which == "user" else [])
    assert_refused(argv, d, capsys, needles)


def test_the_schema_runs_on_write_too(good, tmp_path):
    cal = load_calibration(good / "cal.json")
    cal.model_spec = {**cal.model_spec, "name": 3}
    with pytest.raises(InputError, match="model 'name' must be a string"):
        cal.save(tmp_path / "out.json")
    assert not (tmp_path / "out.json").exists()


def test_a_good_calibration_passes_and_a_tiny_asymmetry_is_rounding(good):
    c = json.loads((good / "cal.json").read_text())
    c["covariance"][0][1] *= 1 + 1e-12  # float rounding of a fit: still symmetric within tolerance
    assert calibration_from_dict(c, "c.json").theta.size == 12


def test_condition_bound():
    check_S(np.diag([1.0, 1.0, 1.0 / MAX_COND_S]))
    with pytest.raises(InputError, match="condition number"):
        check_S(np.diag([1.0, 1.0, 0.5 / MAX_COND_S]))


# ------------------------------------------------------------------- ROS 2 import: the CSV door (item 5)
def _bag(
    d: Path, stamp=None, acc=None, temp_garbage_at: int | None = None, imu_garbage_at: int | None = None
) -> str:
    from accellog.store.ros2_writer import TEMP_TOPIC, Ros2BagWriter

    n = 200
    t0 = 1_700_000_000_000_000_000
    st = t0 + np.arange(n, dtype=np.int64) * 10_000_000 if stamp is None else stamp(t0, n)
    a = np.tile([0.0, 0.0, 9.80665], (n, 1)) if acc is None else acc(n)
    with Ros2BagWriter(d / "bag.mcap") as w:
        w.write_imu(st, a, np.zeros((n, 3)), np.zeros(9), np.zeros(9), log_ns=t0 + np.arange(n) * 10_000_000)
        tt = t0 + np.arange(5, dtype=np.int64) * 10_000_000
        w.write_temperature(tt, [25.0] * 5)
        if temp_garbage_at is not None:  # message index 5 of the temperature topic
            garbage = b"\x00\x01\x00\x00\xff"
            w._w.write(w._conn(TEMP_TOPIC, "sensor_msgs/msg/Temperature"), int(tt[-1]) + 1, garbage)
    return str(d / "bag.mcap")


def _swap(i: int):
    def stamp(t0: int, n: int) -> np.ndarray:
        s = t0 + np.arange(n, dtype=np.int64) * 10_000_000
        s[[i, i + 1]] = s[[i + 1, i]]
        return s

    return stamp


def _dup(i: int):
    def stamp(t0: int, n: int) -> np.ndarray:
        s = t0 + np.arange(n, dtype=np.int64) * 10_000_000
        s[i] = s[i - 1]
        return s

    return stamp


def _acc_at(i: int, value: float):
    def acc(n: int) -> np.ndarray:
        a = np.tile([0.0, 0.0, 9.80665], (n, 1))
        a[i, 0] = value
        return a

    return acc


ROS2_CASES: dict[str, tuple[Callable[[Path], str], tuple[str, ...]]] = {
    "backwards": (lambda d: _bag(d, stamp=_swap(40)), ("/imu/data message 41", "time goes backwards")),
    "duplicate": (lambda d: _bag(d, stamp=_dup(70)), ("/imu/data message 70", "duplicated timestamp")),
    "before-1970": (
        lambda d: _bag(d, stamp=lambda t0, n: np.arange(n, dtype=np.int64) * 10_000_000 - 10**12),
        ("/imu/data message 0", "out of range"),
    ),
    "accel-nan": (lambda d: _bag(d, acc=_acc_at(33, np.nan)), ("/imu/data message 33", "not finite")),
    "accel-1e300": (lambda d: _bag(d, acc=_acc_at(120, 1e300)), ("/imu/data message 120", "MEMS range")),
    "temperature-garbage": (
        lambda d: _bag(d, temp_garbage_at=5),
        ("/imu/temperature message 5", "cannot decode"),
    ),
}


@pytest.mark.parametrize("cmd", ["import", "fit"])
@pytest.mark.parametrize("name", list(ROS2_CASES))
def test_ros2_refused(name, cmd, tmp_path, capsys):
    build, needles = ROS2_CASES[name]
    bag = build(tmp_path)
    argv = {
        "import": ["import", "ros2", bag, "-o", str(tmp_path / "out.mcap")],
        "fit": ["fit", bag, "-o", str(tmp_path / "c.json")],
    }[cmd]
    assert_refused(argv, tmp_path, capsys, needles)


def test_csv_refuses_an_absurd_acceleration_with_its_line(tmp_path, capsys):
    rows = ["t,ax,ay,az"] + [f"{i * 0.01:.2f},0.0,0.0,{'1e300' if i == 7 else '1.0'}" for i in range(100)]
    (tmp_path / "in.csv").write_text("\n".join(rows) + "\n")
    assert main(["import", "csv", str(tmp_path / "in.csv"), "-o", str(tmp_path / "o.mcap")]) == 2
    err = capsys.readouterr().err.strip()
    assert "in.csv:9" in err and "MEMS range" in err and "\n" not in err, err
    assert not (tmp_path / "o.mcap").exists()


def _bag_dir(d: Path) -> Path:
    from accellog.store.ros2_writer import Ros2BagWriter

    n, t0 = 200, 1_700_000_000_000_000_000
    st = t0 + np.arange(n, dtype=np.int64) * 10_000_000
    with Ros2BagWriter(d / "bag") as w:
        w.write_imu(st, np.tile([0.0, 0.0, 9.80665], (n, 1)), np.zeros((n, 3)), np.zeros(9), np.zeros(9))
    assert (d / "bag" / "metadata.yaml").is_file()
    return d / "bag"


def test_ros2_metadata_over_1MiB_is_refused_unread(tmp_path, capsys):
    bag = _bag_dir(tmp_path)
    with (bag / "metadata.yaml").open("ab") as f:
        f.truncate(100 * 1024**2)  # sparse: 100 MB costs nothing here
    t0 = time.process_time()
    assert main(["import", "ros2", str(bag), "-o", str(tmp_path / "o.mcap")]) == 2
    err = capsys.readouterr().err.strip()
    assert "metadata.yaml" in err and "at most 1 MiB" in err and "\n" not in err, err
    assert time.process_time() - t0 < 5.0 and not (tmp_path / "o.mcap").exists()


def test_ros2_metadata_fifo_is_refused(tmp_path, capsys):
    import os

    bag = _bag_dir(tmp_path)
    (bag / "metadata.yaml").unlink()
    os.mkfifo(bag / "metadata.yaml")
    assert main(["import", "ros2", str(bag), "-o", str(tmp_path / "o.mcap")]) == 2
    assert "FIFO" in capsys.readouterr().err


def test_ros2_an_absurd_declared_message_count_costs_no_memory(tmp_path, capsys):
    import re

    bag = _bag_dir(tmp_path)
    meta = bag / "metadata.yaml"
    meta.write_text(re.sub(r"message_count: \d+", "message_count: 1000000000000", meta.read_text()))
    assert main(["import", "ros2", str(bag), "-o", str(tmp_path / "o.mcap"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["samples"] == 200
