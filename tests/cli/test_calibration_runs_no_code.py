"""A calibration file never runs code (issue 27, item 1).

A calibration fitted with a user effect records the effect's file and sha256. Every command that
reads a calibration must not import that file on its own: it needs the user's --effects-file,
checks its sha256 before executing it, and otherwise fails with one line naming the effect and the
hash. The "trojan" effects file below leaves a marker file whenever it is executed.
"""

from __future__ import annotations

import json

import pytest
from support.sessions import synth_session

from accellog.cli import main
from accellog.store.writer import write_session

TROJAN = """
from pathlib import Path
import numpy as np
from accellog.calibrate.model.effects import Effect, per_axis
Path({marker!r}).write_text("ran")
def h(p, f_g, d):
    t = d["t_in_pose_s"]
    return np.stack([p["tj_x"] * t, p["tj_y"] * t, p["tj_z"] * t], axis=1)
TROJAN = Effect(name="trojan", params=per_axis("tj", "g/s"), drivers=("t_in_pose_s",), contribution=h)
"""


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("trojan")
    marker = d / "MARKER"
    fx = d / "fx.py"
    fx.write_text(TROJAN.format(marker=str(marker)))
    s = write_session(d / "s.mcap", synth_session(seed=3, hold_s=5.0, rate_hz=100.0))
    cal = d / "cal.json"
    assert main(["fit", str(s), "--add", "trojan", "--effects-file", str(fx), "-o", str(cal)]) == 0
    assert marker.exists()  # the user named the file on the command line: it ran
    marker.unlink()
    return d, s, cal, fx, marker


def _commands(d, s, cal):
    return {
        "evaluate": ["evaluate", str(s), "--cal", str(cal)],
        "apply": ["apply", str(s), "--cal", str(cal), "-o", str(d / "out.mcap")],
        "drift": ["drift", str(s), "--cal", str(cal), "-o", str(d / "drift.json")],
        "integrate": ["integrate", str(s), "--cal", str(cal), "-o", str(d / "i.csv")],
        "compare": ["compare", str(s), "--cal", str(cal)],
        "replay": ["replay", str(s), "--cal", str(cal), "--speed", "max"],
    }


@pytest.mark.parametrize("cmd", ["evaluate", "apply", "drift", "integrate", "compare", "replay"])
def test_no_command_imports_the_effects_file_a_calibration_names(fitted, cmd, capsys):
    d, s, cal, _fx, marker = fitted
    before = sorted(p.name for p in d.iterdir())
    assert main(_commands(d, s, cal)[cmd]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'trojan'" in err[0] and "--effects-file" in err[0], err
    assert not marker.exists()
    assert sorted(p.name for p in d.iterdir()) == before  # nothing written


def test_a_path_edited_into_the_calibration_is_not_imported_either(fitted, tmp_path, capsys):
    d, s, _, _, marker = fitted
    other = tmp_path / "evil.py"
    other.write_text(f"open({str(marker)!r}, 'w').write('ran')\n")
    doc = json.loads((d / "cal.json").read_text())
    doc["model"]["effects_file"] = str(other)
    doc["model"]["effects_file_sha256"] = None
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(doc))
    assert main(["evaluate", str(s), "--cal", str(edited)]) == 2
    assert "--effects-file" in capsys.readouterr().err
    assert not marker.exists()


@pytest.mark.parametrize("recorded", [None, "missing", "", "abc"])
def test_a_user_effect_without_a_recorded_hash_runs_no_file(fitted, tmp_path, capsys, recorded):
    """The hash is null, missing or malformed: nothing could be checked, so --effects-file is not run."""
    _d, s, cal, fx, marker = fitted
    doc = json.loads(cal.read_text())
    if recorded == "missing":
        del doc["model"]["effects_file_sha256"]
    else:
        doc["model"]["effects_file_sha256"] = recorded
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(doc))
    assert main(["evaluate", str(s), "--cal", str(edited), "--effects-file", str(fx)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'trojan'" in err[0] and "no valid sha256" in err[0], err
    assert not marker.exists()


def test_a_changed_effects_file_is_refused_before_it_runs(fitted, tmp_path, capsys):
    _d, s, cal, fx, marker = fitted
    changed = tmp_path / "fx.py"
    changed.write_text(fx.read_text() + "\n# edited after the fit\n")
    assert main(["evaluate", str(s), "--cal", str(cal), "--effects-file", str(changed)]) == 2
    err = capsys.readouterr().err
    assert "sha256" in err and len(err.strip().splitlines()) == 1
    assert not marker.exists()


def test_the_file_the_user_names_runs(fitted, capsys):
    _d, s, cal, fx, marker = fitted
    assert main(["evaluate", str(s), "--cal", str(cal), "--effects-file", str(fx), "--json"]) == 0
    assert marker.exists()
    marker.unlink()


def test_commands_that_do_not_apply_the_model_still_read_it(fitted, tmp_path, capsys):
    """Copying a calibration with a noise section, or exporting its S and b, needs no code: the
    stored S and b_g are used."""
    _d, s, cal, _, marker = fitted
    out = tmp_path / "with_noise.json"
    assert main(["noise", str(s), "--cal", str(cal), "-o", str(out)]) == 0, capsys.readouterr().err
    doc = json.loads(out.read_text())
    src = json.loads(cal.read_text())
    assert doc["S"] == src["S"] and doc["b_g"] == src["b_g"] and doc["model"] == src["model"]
    assert not marker.exists()
    px4 = tmp_path / "cal.params"
    assert main(["export", str(cal), "--to", "px4", "-o", str(px4)]) == 0
    assert "trojan" in capsys.readouterr().err  # says what it cannot hold
    assert not marker.exists()


def test_a_pipeline_file_names_no_code(tmp_path, capsys):
    p = tmp_path / "p.toml"
    p.write_text(
        '[pipeline]\nname = "x"\ninputs = ["cal"]\n[fit]\ninput = "cal"\nmodels = ["model3"]\n'
        'effects_file = "fx.py"\n'
    )
    assert main(["run", str(p), str(tmp_path / "s.mcap")]) == 2
    err = capsys.readouterr().err
    assert "names no code" in err and f"{p}:7" in err
