"""The workbench never keeps an effect that does not earn its place out of sample (issue 25 item 6).

Short emulated sessions (tests/support/discovery.py; the seed sweeps: benchmarks/bench_discovery.py):

- a bias following dT/dt and a thermal hysteresis are outside the library: the final verdict
  names "no library effect" with the driver the residual follows and docs/effects.md, and the
  calibration's bias stays within 3 sigma of model3's (proxies are dropped, not written);
- two library effects at once end transferring (held-out chi2/dof < 2);
- the backward step drops an earlier effect a later one made redundant;
- a tied choice written with -o carries a note; a session that already heated and cooled is not
  told to record "heat then cool".
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.discovery import handheld_path, session_obs

from accellog.calibrate.diagnosis.choose import heats_and_cools, new_recording
from accellog.calibrate.diagnosis.strategy import LABELLED
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.flows.workbench import backward_step, discover, run_workbench

KW = {"rounds": 3, "hold_s": 8.0}


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return tmp_path_factory.mktemp("discovery")


def _pair(root, name, seed=1):
    return session_obs(root, name, seed, **KW), session_obs(root, name, seed + 100, held=True, **KW)


def _no_worse_than_model3(found, cal, held) -> None:
    """An effect kept outside the library is the in-library part: on the common yardstick (the
    richest model's repeat-free scatter) the final model predicts the held-out session at least as
    well as model3."""
    from accellog.calibrate.model.variance import yardstick

    yard, _ = yardstick(fit_model(cal, build_model(found.yardstick["model"])), cal)
    m3 = LABELLED.mean_heldout_stats(fit_model(cal, build_model("model3")), [held], yard)
    assert found.heldout["heldout_chi2_dof"] <= m3["heldout_chi2_dof"], (found.heldout, m3)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["rate", "hysteresis"])
def test_outside_the_library_the_verdict_says_so_and_the_bias_stays(root, name):
    cal, held = _pair(root, name)
    found = discover(cal, "model3", heldout=held)
    _no_worse_than_model3(found, cal, held)
    assert "no library effect explains what is left" in found.verdict, found.verdict
    assert "docs/effects.md" in found.verdict and "nothing is missing" not in found.verdict
    assert found.transfers is False
    assert not any(a.startswith("refit with --add") for a in found.advice), found.advice
    m3 = fit_model(cal, build_model("model3"))
    fin = fit_model(cal, build_model(found.final_model))
    tol = 3.0 * np.hypot(m3.sigma[:3], fin.sigma[:3])
    if not found.added:  # an in-library part kept (a warm-up standing for dT/dt) moves the bias with it
        assert np.all(np.abs(fin.b - m3.b) <= tol)


@pytest.mark.slow
def test_two_library_effects_transfer(root):
    cal, held = _pair(root, "two")
    found = discover(cal, "model3", heldout=held)
    assert sorted(found.added) == ["temp_bias", "time_drift"], (found.added, found.verdict)
    assert found.heldout["heldout_chi2_dof"] < 2.0 and "no library effect" not in found.verdict


@pytest.mark.slow
def test_backward_step_drops_an_effect_a_later_one_made_redundant(root):
    """temp_bias alone is hidden: model3 + time_drift + temp_bias -> time_drift earns nothing once
    temp_bias is in; temp_bias + time_drift on the two-effect chip keeps both."""
    cal, held = _pair(root, "single")
    score = LABELLED.scores(cal, [held])
    drop = backward_step(["time_drift", "temp_bias"], "model3", None, cal, score)
    assert drop is not None and drop[0] == "time_drift" and "no longer earns its place" in drop[1]
    cal2, held2 = _pair(root, "two")
    assert (
        backward_step(["time_drift", "temp_bias"], "model3", None, cal2, LABELLED.scores(cal2, [held2]))
        is None
    )


def test_tied_choice_is_noted_in_the_calibration_file(root, tmp_path):
    """One warm-up session, no held-out: temperature follows time, temp_bias ties with warmup."""
    session_obs(root, "single", 1, **KW)
    out = tmp_path / "cal.json"
    res = run_workbench(root / "single_1_cal_3_8.mcap", output=out)
    assert res.found.undecided, res.found.verdict
    notes = json.loads(out.read_text())["fit"]["warnings"]
    assert any("cannot tell it from" in n for n in notes), notes
    assert any("what separates them" in n for n in notes), notes


def test_no_heat_then_cool_advice_on_a_session_that_heated_and_cooled(root):
    hyst = session_obs(root, "hysteresis", 1, **KW)
    warm = session_obs(root, "single", 1, **KW)
    assert heats_and_cools(hyst) and not heats_and_cools(warm)
    m3 = build_model("model3")
    assert "heat then cool" in new_recording("temp_bias", "warmup", m3, warm)
    text = new_recording("temp_bias", "warmup", m3, hyst)
    assert "heat then cool" not in text and "another temperature path" in text
    # three rounds of the six faces already repeat every pose over the session
    assert "repeats a pose at the start" not in new_recording("time_drift", "warmup", m3, warm)
    assert "more orientations" in new_recording("nonlin2", "scale", m3, warm)  # faces only: edges are new


@pytest.mark.slow
@pytest.mark.parametrize("name", ["rate", "hysteresis"])
def test_handheld_outside_the_library_says_what_is_left(root, name):
    """The same on hand-held sessions (labels removed; gravity-norm residual): the verdict says the
    model does not transfer and that no library effect explains what is left."""
    cal = handheld_path(root, name, 1)
    held = handheld_path(root, name, 101, held=True)
    found = run_workbench(cal, heldout=[held]).found
    assert found.transfers is False and "nothing is missing" not in found.verdict, found.verdict
    assert "no library effect explains what is left" in found.verdict, found.verdict
    assert "docs/effects.md" in found.verdict


@pytest.mark.slow
def test_two_effects_that_only_help_together_are_added_together(root):
    """Hand-held temperature + nonlinearity (issue 42): after temp_bias2 neither nonlin2 nor
    temp_bias alone predicts the held-out session better (each stands for part of the other's
    residual); the pair does, and the search ends transferring with the chip's three effects."""
    cal = handheld_path(root, "temp_nonlin", 1)
    held = handheld_path(root, "temp_nonlin", 101, held=True)
    found = run_workbench(cal, heldout=[held]).found
    assert set(found.added) == {"temp_bias", "temp_bias2", "nonlin2"}, (found.added, found.verdict)
    pair = [c for c in found.choices if c.chosen and "+" in c.chosen]
    assert pair and "together" in pair[0].reason, [c.reason for c in found.choices]
    assert found.transfers and found.heldout["heldout_chi2_dof"] < 1.5, found.heldout
    assert "no library effect" not in found.verdict


@pytest.mark.slow
def test_diagnose_heldout_says_when_its_choice_leaves_something(root):
    """diagnose --heldout takes the effect that predicts the other session best; when the other
    session is still far from the noise with it (a warm-up standing for dT/dt), the verdict says more
    is missing instead of 'refit and done'; with the right effect it does not."""
    from accellog.calibrate.diagnosis.diagnose import diagnose

    cal, held = _pair(root, "rate")
    d = diagnose(cal, build_model("model3"), heldout=[held])
    assert d.choice.chosen == "warmup" and "more is missing" in d.verdict, d.verdict
    cal, held = _pair(root, "single")
    d = diagnose(cal, build_model("model3"), heldout=[held])
    assert d.choice.chosen == "temp_bias" and "more is missing" not in d.verdict, d.verdict
