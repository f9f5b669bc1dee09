"""An effects file written in each form the docs ever gave loads through the loader the CLI uses, and
its effect fits; the two old import paths warn with the new import, the two current ones do not."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from support.synthetic import synthetic_obs, true_theta

from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model

ROOT = Path(__file__).resolve().parents[2]
NEW_IMPORT = "from accellog import Effect, per_axis"
FORMS = {  # import line -> deprecated (docs/effects.md, "The plugin API is stable")
    "from accellog import Effect, per_axis": False,
    "from accellog.calibrate.model.effects import Effect, per_axis": False,
    "from accellog.calibrate.effects import Effect, per_axis": True,
    "from accellog.effects import Effect, per_axis": True,
}
SHIMS = ("accellog.effects", "accellog.calibrate.effects")

BODY = """
import numpy as np


def creep(p, f_g, drivers):
    t = drivers["t_in_pose_s"]
    return np.stack([p["cr_x"] * t, p["cr_y"] * t, p["cr_z"] * t], axis=1)


CREEP = Effect(
    name="creep1",
    params=per_axis("cr", "g/s", 0.0, 1e-5),
    drivers=("t_in_pose_s",),
    meaning="mount creep after placement, linear in the time in pose",
    contribution=creep,
)
"""


def _effects_file(tmp_path: Path, line: str) -> Path:
    path = tmp_path / "fx.py"
    path.write_text(line + "\n" + BODY)
    return path


@pytest.fixture
def fresh_shims(monkeypatch):
    """The shims warn when first imported: drop them from sys.modules so each test sees its import."""
    for name in SHIMS:
        monkeypatch.delitem(sys.modules, name, raising=False)


@pytest.mark.parametrize("line", list(FORMS))
def test_each_documented_form_loads_and_fits(tmp_path, fresh_shims, line):
    """build_model(effects_file=...) (what --effects-file calls) registers the effect, and a fit of
    model3 + creep1 on synthetic holds recovers its slopes (g/s) within 5 sigma."""
    path = _effects_file(tmp_path, line)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = build_model("model3", add=["creep1"], effects_file=path)
    deprecations = [w for w in caught if issubclass(w.category, DeprecationWarning)]
    if FORMS[line]:
        assert len(deprecations) == 1, [str(w.message) for w in caught]
        (w,) = deprecations
        assert NEW_IMPORT in str(w.message) and line.split()[1] in str(w.message)
        assert Path(w.filename) == path and w.lineno == 1  # points at the user's import line
    else:
        assert deprecations == []
    assert model.term_names[-1] == "creep1" and model.param_names[-3:] == ["cr_x", "cr_y", "cr_z"]
    truth = {"cr_x": 2e-5, "cr_y": -1.5e-5, "cr_z": 1e-5}
    theta = true_theta(model, truth, seed=5)
    obs = synthetic_obs(model, theta, hold_s=60.0, windows_per_hold=8, repeats=2, seed=5)
    fit = fit_model(obs, model)
    for name, value in truth.items():
        i = model.param_names.index(name)
        assert abs(fit.theta[i] - value) < 5 * fit.sigma[i], (name, fit.theta[i], fit.sigma[i])


@pytest.mark.parametrize("line", [ln for ln, old in FORMS.items() if old])
def test_old_paths_warn_with_the_new_import(fresh_shims, line):
    module = line.split()[1]
    with pytest.warns(DeprecationWarning, match=re.escape(f"{module} is deprecated: use `{NEW_IMPORT}`")):
        exec(line, {})


@pytest.mark.parametrize("line", list(FORMS))
def test_cli_loads_each_form_and_shows_the_deprecation(tmp_path, line):
    """In a fresh process (Python's own warning filters, which hide DeprecationWarning outside
    __main__) `accellog effects --effects-file` lists the effect, and says on stderr, naming the
    file's line, when the file uses an old path; no circular import from `from accellog import`."""
    path = _effects_file(tmp_path, line)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("PYTHONWARNINGS", None)
    cmd = [sys.executable, "-m", "accellog", "effects", "--effects-file", str(path), "--json"]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert out.returncode == 0, out.stderr
    assert '"creep1"' in out.stdout
    if FORMS[line]:
        assert f"{path}:1: DeprecationWarning" in out.stderr and NEW_IMPORT in out.stderr, out.stderr
    else:
        assert "Warning" not in out.stderr, out.stderr
