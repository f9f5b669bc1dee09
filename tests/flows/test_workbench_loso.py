"""`accellog workbench A B C`: several calibration sessions of one chip, each candidate effect judged
by leaving one session out (issue #10, item 1: out-of-session prediction whenever a second session
exists). Three emulated warm-ups on different temperature paths with a bias quadratic in
temperature hidden in them: the workbench ends at the true model with every left-out session at
its noise floor, reports the held-out chi2/dof per session, and its calibration file matches the
truth; two clean sessions add nothing."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.cli import main
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session
from accellog.store.writer import write_session

TRUTH = {
    "bias_g": [0.04, -0.03, 0.06],
    "scale": [0.02, -0.01, 0.015],
    "temp_bias_g_per_degC": [0.0012, -0.0008, 0.001],
    "temp_bias2_g_per_degC2": [6e-5, -5e-5, 7e-5],
}
PATHS = [
    {"kind": "warmup", "T_start": 24.0, "T_end": 40.0, "tau_s": 80.0},
    {"kind": "warmup", "T_start": 22.0, "T_end": 36.0, "tau_s": 50.0},
    {"kind": "warmup", "T_start": 28.0, "T_end": 44.0, "tau_s": 100.0},
]


def _session(path, seed: int, temperature: dict, hidden: bool = True):
    errors = dict(TRUTH) if hidden else {k: TRUTH[k] for k in ("bias_g", "scale")}
    sc = Scenario(
        protocol="24",
        hold_s=6.0,
        move_s=2.0,
        sample_rate_hz=200.0,
        errors="perfect",
        set={**errors, "noise_density_g_per_rtHz": 300e-6},
        chip_seed=3,
        seed=seed,
        temperature=temperature,
    )
    simulate(sc, path)
    return path


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("loso")
    hidden = [_session(d / f"warm{i}.mcap", i + 1, T) for i, T in enumerate(PATHS)]
    clean = [_session(d / f"clean{i}.mcap", i + 11, T, hidden=False) for i, T in enumerate(PATHS[:2])]
    return {"hidden": hidden, "clean": clean, "dir": d}


def test_three_warmups_left_out_in_turn_reach_the_true_model(sessions, tmp_path, capsys):
    cal = tmp_path / "cal.json"
    paths = [str(p) for p in sessions["hidden"]]
    assert main(["workbench", *paths, "-o", str(cal), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["sessions"] == paths
    assert all(s["evidence"] == "leave-one-session-out" for s in out["steps"]), out["steps"]
    if not out["decided"]:  # allowed: an explicit "cannot decide" with the reason
        assert "cannot decide" in out["verdict"] and "nothing is missing" not in out["verdict"]
        return
    assert sorted(out["added"]) == ["temp_bias", "temp_bias2"], (out["added"], out["verdict"])
    assert out["transfers"] and "it transfers" in out["verdict"]
    # per-session held-out chi2/dof: every session predicted by the fit to the other two
    per = out["heldout_per_session"]
    assert len(per) == 3 and all(p["heldout_chi2_dof"] < 2.0 for p in per), per
    loso = out["leave_one_session_out"]
    assert loso["sessions"] == paths
    steps = loso["steps"]
    assert [s["model"] for s in steps] == [r["model"] for r in out["ladder"]]
    assert all(len(s["heldout_chi2_dof"]) == 3 for s in steps)
    # model3 vs final: far from the noise floor against the window noise alone; with the predictive
    # covariance (the calibration's own scatter counted) still worse on every session
    lad = out["ladder"]
    assert lad[2]["heldout_chi2_dof_noise"] > 100 * lad[-1]["heldout_chi2_dof_noise"]
    assert min(steps[2]["heldout_chi2_dof"]) > max(steps[-1]["heldout_chi2_dof"])
    for s, r in zip(steps, out["ladder"], strict=True):  # the ladder's held-out column: their mean
        assert r["heldout_chi2_dof"] == pytest.approx(np.mean(s["heldout_chi2_dof"]), rel=1e-9)
    # the calibration file (all three sessions' windows) matches the truth within its 1-sigma
    c = load_calibration(cal)
    got = dict(zip(c.param_names, zip(c.theta, c.sigma, strict=True), strict=True))
    for i, a in enumerate("xyz"):
        for name, truth in (
            (f"b_{a}", TRUTH["bias_g"][i]),
            (f"S_{a}{a}", 1.0 + TRUTH["scale"][i]),
            (f"bT_{a}", TRUTH["temp_bias_g_per_degC"][i]),
            (f"bT2_{a}", TRUTH["temp_bias2_g_per_degC2"][i]),
        ):
            v, sg = got[name]
            assert abs(v - truth) < 3.5 * sg, (name, v, truth, sg)
    # the terminal shows the per-session table
    assert main(["workbench", *paths, "--max-steps", "1"]) == 0
    text = capsys.readouterr().out
    assert "leave one session out" in text and "warm2.mcap" in text


def test_clean_sessions_left_out_in_turn_add_nothing(sessions, capsys):
    assert main(["workbench", *map(str, sessions["clean"]), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["added"] == [] and out["transfers"], out["verdict"]
    assert len(out["leave_one_session_out"]["steps"][-1]["heldout_chi2_dof"]) == 2


def test_several_sessions_refusals_are_one_line(sessions, capsys):
    a, b = map(str, sessions["hidden"][:2])
    hand = write_session(sessions["dir"] / "hand.mcap", dataclasses.replace(read_session(a), poses=[]))
    for args in ([a, b, "--heldout", a], [a, str(hand)]):
        assert main(["workbench", *args]) != 0
        err = capsys.readouterr().err.strip()
        assert err.startswith("accellog: error:") and "\n" not in err, err
