"""The held-out yardstick a missing effect cannot bend (calibrate.model.variance.yardstick).

Emulated sessions with three rounds of the six faces (each pose visited three times) at a warm-up:
the between-hold scatter of a model that misses an effect swallows the misfit when it is estimated
from that model's own residual; the repeat-free scatter (visits of one orientation, freed of what
follows temperature and time) stays near the chip's true placement scatter (none here). Models
compared on that one yardstick: adding the correct effect lowers the held-out score, always.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.discovery import session_obs

from accellog.calibrate.diagnosis.strategy import LABELLED
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.calibrate.model.variance import estimate_scatter, repeat_free_scatter, yardstick

KW = {"rounds": 3, "hold_s": 8.0}


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return tmp_path_factory.mktemp("yardstick")


def test_repeat_free_scatter_is_not_inflated_by_a_missing_effect(root):
    """model3 on a chip with a temperature bias: its own residual's scatter is many times the
    noise; the repeat-free scatter of the same residual is not (the misfit follows temperature)."""
    cal = session_obs(root, "single", 1, **KW)
    m3 = fit_model(cal, build_model("model3"))
    noise_g = float(np.sqrt(np.mean(np.asarray(cal.sigma_g) ** 2)))
    own = estimate_scatter(m3, cal)
    free = repeat_free_scatter(m3, cal)
    assert free is not None and free.dof >= 10
    assert max(own.taus) > 5 * noise_g  # the yardstick that bends
    assert max(free.taus) < 0.25 * max(own.taus), (free.taus, own.taus, noise_g)
    yard, source = yardstick(fit_model(cal, build_model("model3+temp_bias")), cal)
    assert source == "replicates" and max(yard.taus) < 2 * noise_g


def test_no_replicates_no_repeat_free_scatter(root):
    """One visit per pose: nothing repeats, so the repeat-free scatter cannot be estimated."""
    cal = session_obs(root, "single", 1, rounds=1, hold_s=8.0)
    res = fit_model(cal, build_model("model3+temp_bias"))
    assert repeat_free_scatter(res, cal) is None
    assert yardstick(res, cal)[1] == "model residual"


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_adding_the_correct_effect_never_raises_the_score(root, seed):
    """On one yardstick (the richest model's repeat-free scatter), model3 + temp_bias predicts a
    held-out session of the chip better than model3, on new seeds; on model3's own scatter it
    would not always (the bent yardstick let a bare model score better)."""
    cal = session_obs(root, "single", seed, **KW)
    held = session_obs(root, "single", seed + 100, held=True, **KW)
    m3 = fit_model(cal, build_model("model3"))
    right = fit_model(cal, build_model("model3+temp_bias"))
    yard, _ = yardstick(right, cal)
    s3 = LABELLED.heldout_stats(m3, held, yard)
    sr = LABELLED.heldout_stats(right, held, yard)
    assert sr["heldout_chi2_dof"] < s3["heldout_chi2_dof"], (sr, s3)
    assert sr["heldout_chi2_dof"] < 2.0 and s3["heldout_chi2_dof"] > 10 * sr["heldout_chi2_dof"]
    assert sr["heldout_rms_g"] < s3["heldout_rms_g"]


def test_no_it_transfers_over_a_model_far_from_the_noise(root):
    """model3 on a nonlinear chip (the misfit repeats at each pose, so it is no scatter): on its own
    repeat-free yardstick it is not called transferring, and a small predictive chi2/dof alone never
    makes a model transfer when its residual is > 3x the noise plus the repeat-free scatter."""
    from accellog.flows.workbench import held_out_ok

    cal = session_obs(root, "nonlin", 1, **KW)
    held = session_obs(root, "nonlin", 101, held=True, **KW)
    m3 = fit_model(cal, build_model("model3"))
    yard, source = yardstick(m3, cal)
    assert source == "replicates"
    st = LABELLED.mean_heldout_stats(m3, [held], yard)
    assert st["heldout_rms_g"] > 3 * np.hypot(st["heldout_noise_g"], st["heldout_scatter_g"])
    assert not held_out_ok(st), st
    right = LABELLED.mean_heldout_stats(fit_model(cal, build_model("model3+nonlin2")), [held], yard)
    assert held_out_ok(right), right
    bent = {
        "heldout_chi2_dof": 0.9,
        "heldout_rms_g": 2e-3,
        "heldout_noise_g": 1e-4,
        "heldout_scatter_g": 1e-4,
    }
    assert not held_out_ok(bent)
