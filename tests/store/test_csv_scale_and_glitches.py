"""Unit and row mistakes a logger's CSV carries (issue 45, item 6): a gyro in rad/s read as deg/s
(the importer and the doctor compare it with the turns gravity shows), a +-8 g log printed as +-2 g (x4:
--accel-scale), a serial log with glitched rows (--bad-rows skip, every skipped row an event)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from accellog.cli import main
from accellog.core.errors import InputError
from accellog.core.plausible import GravityTurns
from accellog.flows.doctor import doctor
from accellog.flows.simulate import Scenario, simulate
from accellog.store.importers.csv import import_csv
from accellog.store.reader import read_session

HEADER = "t,ax,ay,az,gx,gy,gz"


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def six(tmp_path_factory):
    """A six-position session with its moves: t (s), accel (g), gyro (deg/s)."""
    d = tmp_path_factory.mktemp("six")
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0, seed=3), d / "s.mcap")
    s = read_session(d / "s.mcap")
    return s.t_s, s.accel_g, s.gyro_dps


def _csv(path, t, a, w):
    np.savetxt(path, np.column_stack([t, a, w]), delimiter=",", header=HEADER, comments="", fmt="%.9g")
    return path


def _unit_findings(path):
    return [f.detail for f in doctor(path).findings if f.kind == "unit"]


def test_gyro_in_rad_s_read_as_deg_s_is_a_defect_with_its_fix(six, tmp_path):
    t, a, w = six
    assert _unit_findings(_csv(tmp_path / "dps.csv", t, a, w)) == []
    rad = _csv(tmp_path / "rad.csv", t, a, np.deg2rad(w))
    (found,) = _unit_findings(rad)
    assert "gyro" in found and found.endswith("re-import with --gyro-unit rad/s")
    assert doctor(rad).healthy is False
    fixed = import_csv(rad, gyro_unit="rad/s")
    assert np.allclose(fixed.gyro_dps, w, rtol=1e-6, atol=1e-6)


def test_the_importer_refuses_a_gyro_in_rad_s_read_as_deg_s(six, tmp_path, capsys):
    """Judged from the motion (at rest 57x small rates look like a good gyro): the moves between the
    rests turn gravity ~57x further than the gyro integrates; the unit named by the user is taken."""
    t, a, w = six
    rad = _csv(tmp_path / "rad.csv", t, a, np.deg2rad(w))
    out = tmp_path / "rad.mcap"
    rc, _, err = _run(["import", "csv", rad, "-o", out], capsys)
    assert rc == 2 and not out.exists(), err
    (line,) = err.strip().splitlines()
    assert "they look like rad/s: pass --gyro-unit rad/s" in line and "rad.csv" in line, line
    with pytest.raises(InputError, match="look like rad/s"):
        import_csv(rad)  # the in-memory import has the same door
    rc, _, err = _run(["import", "csv", rad, "-o", out, "--gyro-unit", "rad/s"], capsys)
    assert rc == 0, err
    assert np.allclose(read_session(out).gyro_dps, w, rtol=1e-6, atol=1e-6)
    named = import_csv(rad, gyro_unit="deg/s")  # the user's word: read as deg/s
    assert np.allclose(named.gyro_dps, np.deg2rad(w), rtol=1e-6, atol=1e-9)
    assert import_csv(_csv(tmp_path / "dps.csv", t, a, w)).n == t.shape[0]  # deg/s passes


def _turns(t, a, w, piece):
    g = GravityTurns(round(0.1 / float(np.median(np.diff(t)))))
    for s in range(0, t.shape[0], piece):
        g.feed(t[s : s + piece], a[s : s + piece], w[s : s + piece])
    g.finish()
    return g


def test_gravity_turns_fed_in_any_pieces_and_blind_to_linear_acceleration(six):
    t, a, w = six
    whole = _turns(t, a, w, t.shape[0])
    assert 0.7 < whole.ratio() < 1.4 and not whole.looks_like_rad_s()  # deg/s: the gyro turns as gravity
    for piece in (7, 1001, 7777):
        g = _turns(t, a, w, piece)
        assert (g.turn_deg, g.gyro_deg) == pytest.approx((whole.turn_deg, whole.gyro_deg), rel=1e-9)
    assert 40 < _turns(t, a, np.deg2rad(w), 999).ratio() < 75
    # a vehicle braking and accelerating in a straight line (0.3 g, no rotation) tilts the
    # accelerometer's direction by 17 deg: no rest is turned, the gyro is not judged
    rng = np.random.default_rng(1)
    tv = np.arange(0, 300, 0.005)
    push = 0.3 * np.sign(np.sin(2 * np.pi * tv / 20)) * (np.abs(np.sin(2 * np.pi * tv / 20)) > 0.5)
    av = np.column_stack([push, 0 * tv, 1 + 0 * tv]) + rng.normal(0, 3e-3, (tv.size, 3))
    wv = np.array([0.3, -0.5, 0.2]) + rng.normal(0, 0.1, (tv.size, 3))
    assert _turns(tv, av, wv, 5000).ratio() is None
    still = _turns(t[:500], a[:500], np.deg2rad(w[:500]), 100)  # the first rest alone: nothing to judge
    assert still.ratio() is None and not still.looks_like_rad_s()


def test_a_full_scale_mismatch_names_the_scale_and_accel_scale_fixes_it(six, tmp_path, capsys):
    t, a, w = six
    quarter = _csv(tmp_path / "q.csv", t, a / 4, w)  # +-8 g counts converted with +-2 g's 16384 LSB/g
    out = tmp_path / "q.mcap"
    rc, _, err = _run(["import", "csv", quarter, "-o", out], capsys)
    assert rc == 2 and "x4 makes it" in err and err.rstrip().endswith("use --accel-scale 4"), err
    assert "no unit or scale" not in err and not out.exists()
    rc, _, err = _run(["import", "csv", quarter, "-o", out, "--accel-scale", "4"], capsys)
    assert rc == 0, err
    s = read_session(out)
    assert np.allclose(s.accel_g, a, rtol=1e-6, atol=1e-7)
    assert s.meta.extra["accel_scale"] == "4" and "* 4" in s.meta.extra["conversion"]
    (found,) = _unit_findings(quarter)  # the doctor reads it as declared and names the same fix
    assert found.endswith("re-import with --accel-scale 4")
    rc, _, err = _run(["import", "csv", quarter, "-o", out, "--force", "--accel-scale", "0"], capsys)
    assert rc == 2 and "--accel-scale" in err


def test_glitched_rows_refused_or_skipped_and_counted(six, tmp_path, capsys):
    t, a, w = six
    lines = _csv(tmp_path / "ok.csv", t, a, w).read_text().splitlines()
    lines[501] = lines[501][:9]  # a row cut short (data row 501 is file line 502)
    lines[1501] = lines[1501].replace(",", ",\x7f3", 1)  # a garbled byte
    glitched = tmp_path / "serial.csv"
    glitched.write_text("\n".join(lines) + "\n")
    out = tmp_path / "g.mcap"
    rc, _, err = _run(["import", "csv", glitched, "-o", out], capsys)
    assert rc == 2 and "serial.csv:502:" in err and "--bad-rows skip" in err and not out.exists()
    rc, stdout, err = _run(["import", "csv", glitched, "-o", out, "--bad-rows", "skip", "--json"], capsys)
    assert rc == 0, err
    assert "2 row(s) that do not parse skipped (serial.csv:502, serial.csv:1502)" in err
    assert len(json.loads(stdout)["skipped_rows"]) == 2
    s = read_session(out)
    assert s.n == t.shape[0] - 2
    kept = np.delete(np.arange(t.shape[0]), [500, 1500])
    assert np.array_equal(s.t_s, t[kept])
    events = [e for e in s.events if e.kind == "skipped_row"]
    assert [e.detail.split(": ")[0] for e in events] == ["serial.csv:502", "serial.csv:1502"]
    assert [e.t_s for e in events] == [t[499], t[1499]] and s.lost_samples() == 2
    memory = import_csv(glitched, bad_rows="skip")  # the in-memory import counts them the same way
    assert [e.detail for e in memory.events] == [e.detail for e in events]
    report = doctor(out)
    assert any(f.kind == "events" and "2 skipped_row" in f.detail for f in report.findings)
    rc, _, err = _run(["import", "csv", glitched, "-o", out, "--force", "--bad-rows", "drop"], capsys)
    assert rc == 2 and "--bad-rows must be one of refuse, skip" in err
