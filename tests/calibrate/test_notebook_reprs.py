"""What a notebook shows for the README snippet's objects (issue 45, item 7): one short line each
(the dataclass repr was a 16-30 kB dump of every array), a parameter table in HTML for a fit and a
calibration."""

from __future__ import annotations

import re

import pytest

import accellog as al
from accellog.flows.simulate import Scenario, simulate


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    path = tmp_path_factory.mktemp("nb") / "cal.mcap"
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0, seed=8), path)
    s = al.read_session(path)
    obs = al.observations(s)
    fit = al.fit_model(obs, al.build_model("model3"))
    cal_path = path.with_suffix(".json")
    al.Calibration.from_fit(fit, obs=obs).save(cal_path)
    return s, obs, fit, al.load_calibration(cal_path)


def test_reprs_are_one_short_line_naming_what_matters(fitted):
    s, obs, _, _ = fitted
    texts = {type(x).__name__: repr(x) for x in fitted}
    for name, text in texts.items():
        assert len(text) < 300 and "\n" not in text and "array(" not in text, (name, text)
        assert text.startswith(f"<{name}: "), text
    assert f"{s.n} samples" in texts["Session"] and "6 poses" in texts["Session"]
    assert f"{obs.n} windows" in texts["ObsTable"] and "+z, -z" in texts["ObsTable"]
    assert "model3 (12 params)" in texts["FitResult"]
    assert re.search(r"chi2/dof [\d.]+, rms [\d.]+ mg", texts["FitResult"])
    assert "model3 (12 params)" in texts["Calibration"] and "cal.json" in texts["Calibration"]


def test_fit_and_calibration_show_a_parameter_table(fitted):
    _, _, fit, cal = fitted
    for x in (fit, cal):
        page = x._repr_html_()
        assert page.startswith("<table>") and page.count("<tr>") == 1 + len(fit.param_names)
        assert "<td>b_x</td>" in page and "&plusmn;" in page
    assert f"<td>{fit.theta[0]:.4g}</td>" in fit._repr_html_()


def test_a_diagnosis_and_a_discovery_are_one_short_line(fitted):
    """diagnose() and discover() results (16 kB and more as dataclass dumps) show one line each."""
    _, obs, _, _ = fitted
    d = al.diagnose(obs, al.build_model("model3"))
    found = al.discover(obs, "model3")
    for x, name in ((d, "Diagnosis"), (found, "Discovery")):
        text = repr(x)
        assert text.startswith(f"<{name}: ") and len(text) < 300 and "\n" not in text, text
    assert "model3 (12 params)" in repr(d) and "missing" in repr(d)
    assert repr(found).startswith("<Discovery: model3")
