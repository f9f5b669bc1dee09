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


def _snapshot(d: Path) -> dict[str, tuple]:
    return {str(p.relative_to(d)): (p.stat().st_mtime_ns, p.read_bytes()) for p in sorted(d.rglob("*"))}


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
    before = _snapshot(d)
    capsys.readouterr()
    t0 = time.process_time()
    rc = main(argv)
    cpu_s = time.process_time() - t0
    err = capsys.readouterr().err.strip()
    assert rc != 0, f"exit 0: {err}"
    assert "Traceback" not in err, err
    assert err.startswith("accellog: error: ") and "\n" not in err, err
    for n in needles:
        assert n in err, (n, err)
    assert _snapshot(d) == before, "files were written, changed or left behind (or user code ran)"
    assert cpu_s < 5.0


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
