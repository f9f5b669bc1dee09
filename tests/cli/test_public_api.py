"""The notebook API in accellog/__init__.py: every public name resolves, and the docstring's example runs."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import accellog as al
from accellog.core.jsonio import JsonResult


def test_every_public_name_resolves():
    assert {n for n in al.__all__ if getattr(al, n) is None} == set()
    assert set(dir(al)) == set(al.__all__)


def test_plugin_api_and_result_types_are_exported():
    """The names of issue #41 part 5 come from `accellog` and are the defining modules' objects."""
    from accellog import (
        Diagnosis,
        Discovery,
        Effect,
        Evaluation,
        FitResult,
        Model,
        Param,
        import_ros2,
        per_axis,
    )
    from accellog.calibrate.diagnosis import diagnose
    from accellog.calibrate.model import compose, effects, fit
    from accellog.flows import workbench
    from accellog.navigate import evaluation
    from accellog.store import importers
    from accellog.store.importers import ros2

    assert (Effect, Param, per_axis) == (effects.Effect, effects.Param, effects.per_axis)
    assert (FitResult, Model, Diagnosis) == (fit.FitResult, compose.Model, diagnose.Diagnosis)
    assert (Evaluation, Discovery) == (evaluation.Evaluation, workbench.Discovery)
    assert import_ros2 is ros2.import_ros2 is importers.import_ros2  # beside the other importers
    assert per_axis("c", "g/s")[2] == Param("c_z", "g/s")


def test_import_accellog_loads_no_heavy_module():
    code = "import sys, accellog; print(' '.join(m for m in ('numpy', 'scipy', 'rerun', 'mcap') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == []


def test_notebook_example(tmp_path):
    """The module docstring's example on a simulated six-pose session recovers the chip's bias (g)."""
    sc = al.Scenario(protocol="six", hold_s=6.0, sample_rate_hz=200.0, seed=3)
    al.simulate(sc, tmp_path / "cal.mcap")
    s = al.read_session(tmp_path / "cal.mcap")
    obs = al.observations(s)
    fit = al.fit_model(obs, al.build_model("model3"))
    cal = al.Calibration.from_fit(fit, obs=obs)
    cal.save(tmp_path / "cal.json")
    back = al.load_calibration(tmp_path / "cal.json")
    assert np.allclose(back.correct(s.accel_g[:10]), cal.correct(s.accel_g[:10]))
    from accellog.flows.simulate import build_sensor_model

    model, _ = build_sensor_model(sc)
    z = (fit.b - model.accel.bias_g) / fit.sigma[[fit.param_names.index(f"b_{a}") for a in "xyz"]]
    assert np.all(np.abs(z) < 5), z  # the chip's bias (g) within its 1-sigma, up to 5 sigma
    assert isinstance(fit, al.FitResult) and isinstance(al.build_model("model3"), al.Model)
    diagnosis = al.diagnose(obs, al.build_model("model3"))
    assert isinstance(diagnosis, al.Diagnosis) and isinstance(diagnosis.verdict, str)


def test_typed_results_serialise_to_strict_json(tmp_path):
    """to_json() of a result is the strict JSON of its to_dict() (NaN -> null), keys unchanged."""
    import json
    import math

    from accellog.flows.stages import run_fit, run_segment

    sc = al.Scenario(protocol="six", hold_s=4.0, sample_rate_hz=200.0, seed=4)
    al.simulate(sc, tmp_path / "s.mcap")
    seg = run_segment(tmp_path / "s.mcap")
    fo = run_fit(al.read_session(tmp_path / "s.mcap"), "model2")
    for res in (seg, fo, fo.cal):
        d = json.loads(res.to_json())
        assert set(d) == set(res.to_dict())
    assert not math.isnan(json.loads(fo.to_json())["chi2_dof"])

    class Nan(JsonResult):
        def to_dict(self) -> dict:
            return {"chi2_dof": float("nan"), "b_g": np.array([1.0, np.inf, 2.0])}

    assert json.loads(Nan().to_json()) == {"chi2_dof": None, "b_g": [1.0, None, 2.0]}


def test_type_checkers_see_the_real_public_types(tmp_path):
    """The TYPE_CHECKING imports give the same names as the lazy table, and mypy reads real types
    (not Any) through them."""
    import ast
    from pathlib import Path

    src = Path(al.__file__).read_text()
    tree = ast.parse(src)
    typed = {
        a.asname or a.name
        for node in ast.walk(tree)
        if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING"
        for imp in node.body
        if isinstance(imp, ast.ImportFrom)
        for a in imp.names
    }
    assert typed == set(al._API) and set(al.__all__) == {"__version__", *al._API}
    api = pytest.importorskip("mypy.api")
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import accellog as al\n"
        "reveal_type(al.read_session)\n"
        "reveal_type(al.load_calibration)\n"
        "reveal_type(al.ModelError)\n"
    )
    out, err, _code = api.run(
        [str(probe), "--follow-imports=silent", "--ignore-missing-imports", "--no-error-summary"]
    )
    revealed = [ln for ln in out.splitlines() if "Revealed type" in ln]
    assert len(revealed) == 3, out + err
    assert "Session" in revealed[0] and "Calibration" in revealed[1] and "ModelError" in revealed[2], out
    assert not any(ln.rsplit('"', 2)[-2] == "Any" for ln in revealed), out
