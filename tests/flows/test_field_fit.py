"""Calibration from a robot's stops (issue 44): `fit RUN.mcap [RUN2.mcap] --prior LAB.json` updates
the lab calibration by the stops of unlabelled runs, says what the stops identify, and without a
prior fits only that instead of refusing stops that are all near level."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest
from calibrate.test_prior_fit import level_stops
from support.synthetic import synthetic_session

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.calibrate.model.compose import build_model
from accellog.cli import main
from accellog.core.protocol import six_position
from accellog.store.writer import write_session


def _robot(tmp_path):
    """A six-face lab session, and two runs of 15 stops each z-up tilted <= 15 deg after the biases
    aged 5-8 mg (labels removed: the stops are detected)."""
    m = build_model("model3")
    th = m.initial_theta()
    th[:3], th[3:6] = [0.05, -0.04, 0.07], [1.02, 0.98, 1.01]
    th[6:] = np.random.default_rng(3).uniform(-0.01, 0.01, 6)
    write_session(
        tmp_path / "lab.mcap", synthetic_session(m, th, protocol=six_position(20.0), hold_s=20.0, seed=1)
    )
    aged = th.copy()
    aged[:3] += [0.005, -0.008, 0.006]
    runs = []
    for k in (1, 2):
        s = synthetic_session(m, aged, protocol=level_stops(15, seed=k), hold_s=8.0, move_s=3.0, seed=10 + k)
        runs.append(write_session(tmp_path / f"run{k}.mcap", dataclasses.replace(s, poses=[])))
    return m, aged, runs


def _vector_error_g(cal, m, theta, ups) -> float:
    """RMS |f_corrected - f_true| (g) over the robot's attitudes (ups: gravity directions)."""
    reading = m.predict(theta, ups, {})
    return float(np.sqrt(np.mean(np.sum((cal.correct(reading) - ups) ** 2, axis=1))))


def test_robot_stops_update_the_lab_calibration(tmp_path, capsys):
    m, aged, runs = _robot(tmp_path)
    assert main(["fit", str(tmp_path / "lab.mcap"), "-o", str(tmp_path / "lab.json")]) == 0
    capsys.readouterr()
    args = ["fit", *map(str, runs), "--prior", str(tmp_path / "lab.json"), "-o", str(tmp_path / "f.json")]
    assert main([*args, "--json"]) == 0
    cap = capsys.readouterr()
    d = json.loads(cap.out)
    lab, field = load_calibration(tmp_path / "lab.json"), load_calibration(tmp_path / "f.json")
    ups = np.array([s.up_sensor for s in level_stops(200, seed=9)])  # the robot's attitudes
    assert _vector_error_g(field, m, aged, ups) <= 0.3 * _vector_error_g(lab, m, aged, ups)
    for k, name in enumerate(("b_x", "b_y", "b_z")):
        assert abs(field.theta[k] - aged[k]) < 3 * field.sigma[k], (name, field.theta[k], aged[k])
    src = {r["name"]: r["source"] for r in d["prior_sources"]}
    assert src["b_z"] == "data" and src["S_zx"] == "prior"
    ident = d["identification"]
    assert ident["identified"] == ["b_x", "b_y", "b_z"]
    assert "b_z + S_zz" in ident["not_identified"]["S_zz"]
    assert "van Hees" in ident["not_identified"]["S_xx"]
    assert (
        "S_zz not identified: seen only as b_z + S_zz" in cap.err and "kept at the prior's value" in cap.err
    )
    assert [x.path for x in field.sources] == [str(r) for r in runs]


def test_level_stops_without_a_prior_fit_what_they_identify(tmp_path, capsys):
    """No prior: a single unlabelled run with level stops only fits the biases (what the stops
    identify), holds the scale and cross-axis terms at nominal, says why for each and names
    --prior; the biases land where the aged chip's biases plus the unseen S_zz put them."""
    _, aged, runs = _robot(tmp_path)
    out = tmp_path / "f.json"
    assert main(["fit", str(runs[0]), "-o", str(out), "--json"]) == 0
    cap = capsys.readouterr()
    ident = json.loads(cap.out)["identification"]
    assert ident["identified"] == ["b_x", "b_y", "b_z"]
    assert set(ident["not_identified"]) == {"S_xx", "S_yy", "S_zz", "S_yx", "S_zx", "S_zy"}
    assert "b_z + S_zz" in ident["not_identified"]["S_zz"] and "van Hees" in ident["not_identified"]["S_xx"]
    assert "--prior LAB.json" in cap.err and "Fitting only what these stops identify" in cap.err
    cal = load_calibration(out)
    p = {n: (v, s) for n, v, s in zip(cal.param_names, cal.theta, cal.sigma, strict=True)}
    assert [p[n][0] for n in ("S_xx", "S_yy", "S_zz")] == [1.0, 1.0, 1.0]
    # |f| = 1 on near-level stops: b_z carries S_zz - 1; b_x, b_y the tilt-weighted cross terms
    assert abs(p["b_z"][0] - (aged[2] + aged[5] - 1.0)) < 3 * p["b_z"][1]


def test_gyro_bias_curve_from_the_stops_of_an_emulated_robot(tmp_path, capsys):
    """An emulated robot (the real path: emulator -> driver -> recorder -> MCAP) warming 20 -> 36 degC
    on its 10-minute run, labels removed, updated from a six-face lab calibration at 25 degC: the
    accelerometer-still intervals include turns in place (a yaw rate leaves the specific force
    unchanged), which are left out of the gyro bias; its temperature curve then matches the chip's
    (the emulator's truth) within 2 sigma (honest sigmas leave 1 in 20 coefficients beyond: at
    most one of the 12 may be, none beyond 3 sigma), and the sigmas are honest on average."""
    from accellog.acquire.emulator.sensor_model import GyroErrors
    from accellog.flows.simulate import Scenario, simulate
    from accellog.store.source import open_source

    lab = Scenario(protocol="six", hold_s=20.0, sample_rate_hz=200.0)
    simulate(lab, tmp_path / "lab.mcap")
    assert main(["fit", str(tmp_path / "lab.mcap"), "-o", str(tmp_path / "lab.json")]) == 0
    truth = GyroErrors.datasheet(lab.chip_seed)
    z = []
    for seed in (6, 7):
        run = Scenario(motion="robot", robot_path="long", sample_rate_hz=200.0, seed=seed,
                       temperature={"kind": "warmup", "T_start": 20.0, "T_end": 36.0, "tau_s": 200.0})  # fmt: skip
        simulate(run, tmp_path / f"r{seed}.mcap")
        s = open_source(tmp_path / f"r{seed}.mcap").whole()
        bare = write_session(tmp_path / f"run{seed}.mcap", dataclasses.replace(s, poses=[]))
        capsys.readouterr()
        out = tmp_path / f"f{seed}.json"
        assert main(["fit", str(bare), "--prior", str(tmp_path / "lab.json"), "-o", str(out)]) == 0
        assert "still windows turn" in capsys.readouterr().err
        g = json.loads(out.read_text())["gyro"]
        assert g["effects"][:2] == ["bias", "temp_bias"] and g["t_ref_degC"] == truth.t_ref_degC
        z += list((np.array(g["bias_dps"]) - truth.bias_dps) / np.array(g["bias_sigma_dps"]))
        z += list(
            (np.array(g["temp_bias_dps_per_degC"]) - truth.temp_bias_dps_per_degC)
            / np.array(g["temp_bias_sigma_dps_per_degC"])
        )
    z = np.array(z)
    assert np.all(np.abs(z) < 3.0) and np.sum(np.abs(z) >= 2.0) <= 1, z.round(2)
    assert np.sqrt(np.mean(z**2)) < 1.5, z.round(2)


@pytest.fixture(scope="module")
def parked(tmp_path_factory):
    """An emulated ground robot (emulator -> driver -> recorder -> MCAP): 30 stops parked on slopes
    tilted <= 15 deg, the die warming 20 -> 36 degC, the accelerometer biases aged 3-8 mg since a
    six-face lab calibration at 25 degC (lab.json); the run written without its labels."""
    from accellog.acquire.emulator.sensor_model import AccelErrors
    from accellog.flows.simulate import Scenario, simulate
    from accellog.store.source import open_source

    tmp_path = tmp_path_factory.mktemp("parked")
    lab = Scenario(protocol="six", hold_s=20.0, sample_rate_hz=200.0)
    simulate(lab, tmp_path / "lab.mcap")
    assert main(["fit", str(tmp_path / "lab.mcap"), "-o", str(tmp_path / "lab.json")]) == 0
    chip = AccelErrors.datasheet(lab.chip_seed)
    aged = dataclasses.replace(chip, bias_g=np.add(chip.bias_g, [0.005, -0.008, 0.003]))
    run = Scenario(motion="robot", robot_path="parked", hold_s=8.0, sample_rate_hz=200.0, seed=5,
                   set={"bias_g": list(aged.bias_g)},
                   temperature={"kind": "warmup", "T_start": 20.0, "T_end": 36.0, "tau_s": 200.0})  # fmt: skip
    simulate(run, tmp_path / "r.mcap")
    bare = write_session(
        tmp_path / "run.mcap", dataclasses.replace(open_source(tmp_path / "r.mcap").whole(), poses=[])
    )
    return tmp_path, aged, bare


def test_parked_robot_warming_up_beats_the_lab_calibration(parked, capsys):
    """The Done-means of field calibration on the parked robot: `fit RUN --prior LAB.json --add
    temp_bias` (the tempco at the datasheet's +-1.5 mg/degC as its prior): the vector error over the
    robot's attitudes and temperatures <= 0.3x the lab calibration's, every bias within 3 sigma of
    the truth, the unidentified terms named."""
    tmp_path, aged, bare = parked
    capsys.readouterr()
    args = [
        "fit",
        str(bare),
        "--prior",
        str(tmp_path / "lab.json"),
        "--add",
        "temp_bias",
        "-o",
        str(tmp_path / "f.json"),
    ]
    assert main([*args, "--json"]) == 0
    cap = capsys.readouterr()
    assert "bT_x, bT_y, bT_z not in the prior" in cap.err
    ident = json.loads(cap.out)["identification"]
    labc, field = load_calibration(tmp_path / "lab.json"), load_calibration(tmp_path / "f.json")
    rng = np.random.default_rng(9)  # the robot's attitudes (z-up within 15 deg) and temperatures
    tilt, az, temp = (
        np.deg2rad(rng.uniform(0, 15, 400)),
        rng.uniform(0, 2 * np.pi, 400),
        rng.uniform(20, 36, 400),
    )
    ups = np.c_[np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)]
    reading = aged.apply(ups, temp, np.zeros(400))

    def vector_error_g(cal) -> float:
        return float(np.sqrt(np.mean(np.sum((cal.correct(reading, {"temp_degC": temp}) - ups) ** 2, axis=1))))

    assert vector_error_g(field) <= 0.3 * vector_error_g(labc), (vector_error_g(field), vector_error_g(labc))
    for k, name in enumerate(("b_x", "b_y", "b_z")):
        assert abs(field.theta[k] - aged.bias_g[k]) < 3 * field.sigma[k], (
            name,
            field.theta[k],
            aged.bias_g[k],
        )
    assert set(ident["identified"]) == {"b_x", "b_y", "b_z", "bT_x", "bT_y", "bT_z"}
    assert {"S_xx", "S_yy", "S_zz", "S_xz", "S_zx"} <= set(ident["not_identified"])
    assert "S_zz not identified" in cap.err and "kept at the prior's value" in cap.err


def test_a_fit_from_stops_draws_its_stops_residuals_and_gyro_curve(parked, tmp_path):
    """--rrd of a field fit: the stops' gravity directions on the sphere with the van Hees caps (only
    +z seen by a ground robot), |f| - g per stop before (the lab's) and after (smaller), the gyro
    bias against temperature over the run's temperatures (the fitted curve)."""
    from rrd_readback import load_rrd

    lab_dir, _, bare = parked
    rrd, out = tmp_path / "f.rrd", tmp_path / "f.json"
    args = ["fit", str(bare), "--prior", str(lab_dir / "lab.json"), "--add", "temp_bias", "-o", str(out)]
    assert main([*args, "--rrd", str(rrd)]) == 0
    r = load_rrd(rrd)
    ups = np.array(r.static("/field/sphere/stops", "Points3D:positions"))
    assert len(ups) >= 25 and np.all(ups[:, 2] > np.cos(np.deg2rad(16))), ups[:, 2].min()
    assert "/field/sphere/caps" in r.entities
    caps = r.texts("/docs/field/caps", "TextDocument:text")[0][1]
    assert "caps seen: +z; not seen: +x, -x, +y, -y, -z" in caps
    assert "/charts/field/norm_residual/bars" in r.entities
    doc = r.texts("/docs/field/norm_residual", "TextDocument:text")[0][1]
    before, after = map(float, re.findall(r"RMS before \(prior\) ([\d.]+) mg, after ([\d.]+) mg", doc)[0])
    assert after < 0.5 * before, doc.splitlines()[0]
    t, b = r.series("/field/gyro_bias/curve", timeline="temperature_mdegC")
    g = load_calibration(out).gyro
    assert 19_000 < t[0] < 22_000 and 34_000 < t[-1] < 37_000
    np.testing.assert_allclose(b, g.bias_at(t / 1000.0), atol=1e-9)
    names = {v["name"] for v in r.views()}
    assert "stops: gravity directions and van Hees caps" in names


def test_a_warm_up_with_a_prior_without_temperature_terms_is_warned(parked, tmp_path, capsys):
    """Without --add temp_bias the one-temperature lab prior fits one bias to the whole warm-up:
    said (the fix named), in the notes and the fit's warnings."""
    lab_dir, _, bare = parked
    args = ["fit", str(bare), "--prior", str(lab_dir / "lab.json"), "-o", str(tmp_path / "f.json"), "--json"]
    assert main(args) == 0
    cap = capsys.readouterr()
    assert "has no temperature term" in cap.err and "--add temp_bias" in cap.err
    assert any("has no temperature term" in w for w in json.loads(cap.out)["warnings"])


def test_a_fleet_field_session_warming_up_gets_the_tempco_added(parked):
    """fleet_field.field_result on the parked robot's warm-up with the one-temperature lab
    calibration: temp_bias added to the prior (flagged), the row in the lab's parameters (what the
    report compares), the biases within 3 sigma of the aged truth, the tempco in the calibration."""
    from accellog.flows.fleet_field import field_result
    from accellog.store.reader import read_session

    lab_dir, aged, bare = parked
    lab = load_calibration(lab_dir / "lab.json")
    priors = {"EMU-7": {"calibration": "cal/lab.json", "text": (lab_dir / "lab.json").read_text()}}
    r = field_result(read_session(bare), {"device": "EMU-7", "session": str(bare)}, priors)
    (row,) = r["rows"]
    assert row["error"] == "" and row["param_names"] == lab.param_names and row["model"] == lab.model.name
    assert any("temp_bias added to the prior" in f for f in row["flags"])
    b, s = np.array(row["values"][:3]), np.array(row["sigmas"][:3])
    assert np.all(np.abs(b - aged.bias_g) < 3 * s), (b, aged.bias_g, s)
    names = [p["name"] for p in r["cals"][row["model"]]["params"]]
    assert names[-3:] == ["bT_x", "bT_y", "bT_z"]


def test_a_labelled_robot_run_with_short_stops_updates_the_prior(parked, tmp_path, capsys):
    """The emulated demo loop (9 stops, 0.5-3.5 s labelled) with its labels, given --prior and a
    short --trim-s and --window-s: its stops update the lab calibration (the field path once trimmed
    0.5 s whatever --trim-s said: 'has 0 samples after trimming 0.5 s at each end')."""
    from accellog.flows.simulate import Scenario, simulate

    lab_dir, _, _ = parked
    simulate(
        Scenario(motion="robot", robot_path="demo", sample_rate_hz=200.0, seed=3), tmp_path / "demo.mcap"
    )
    args = [
        "fit",
        str(tmp_path / "demo.mcap"),
        "--prior",
        str(lab_dir / "lab.json"),
        "--trim-s",
        "0.1",
        "--window-s",
        "0.5",
    ]
    assert main([*args, "-o", str(tmp_path / "f.json")]) == 0, capsys.readouterr().err


def test_few_stops_warming_up_say_which_terms_they_barely_determine(tmp_path, capsys):
    """Ten stops (faces and four corners) while the chip warms 20 -> 36 degC fit bias, scale,
    misalignment and the bias tempco, but some of them lie mostly along directions the stops barely
    see: the fit says which, in a note and in the calibration's warnings, and what pins them; 24
    stops over the sphere through the same warm-up leave no such term."""
    from accellog.flows.simulate import Scenario, simulate
    from accellog.store.reader import read_session

    warm = {"kind": "warmup", "T_start": 20.0, "T_end": 36.0, "tau_s": 200.0}
    few = "+z,-z,+x,-x,+y,-y,+x+y+z,-x-y+z,+x-y-z,-x+y-z"
    many = few + ",+x+y,-x-y,+x-y,-x+y,+x+z,-x-z,+x-z,-x+z,+y+z,-y-z,+y-z,-y+z,+x+y-z,-x-y-z"
    weak = {}
    for name, protocol in (("few", few), ("many", many)):
        sim = tmp_path / f"{name}.labelled.mcap"
        simulate(
            Scenario(protocol=protocol, hold_s=25.0, sample_rate_hz=200.0, temperature=warm, seed=21), sim
        )
        run = write_session(tmp_path / f"{name}.mcap", dataclasses.replace(read_session(sim), poses=[]))
        out = tmp_path / f"{name}.json"
        assert main(["fit", str(run), "--add", "temp_bias", "-o", str(out), "--json"]) == 0
        cap = capsys.readouterr()
        weak[name] = json.loads(cap.out)["identification"]["weakly_determined"]
        said = [w for w in json.loads(out.read_text())["fit"]["warnings"] if "weakly determined" in w]
        assert bool(said) == bool(weak[name]) and ("weakly determined" in cap.err) == bool(weak[name])
        if said:
            assert all(p in said[0] for p in weak[name]) and ">= 12" in said[0]
    assert weak["many"] == []
    assert weak["few"] and any(p.startswith("bT_") for p in weak["few"]), weak


def test_labelled_holds_all_near_level_are_fitted_as_stops(parked, capsys):
    """The parked robot's run with its labels (r.mcap: 30 labelled holds, all z-up within 15 deg):
    `fit` was refused ('cannot separate bias from scale', 30 pose names in one line) and so was the
    workbench; now both fit what the holds identify, as for unlabelled stops, and say so: the
    horizontal biases within 3 sigma of the truth (b_z only with S_zz), the rest held and named."""
    tmp_path, aged, _ = parked
    run, cal = tmp_path / "r.mcap", tmp_path / "labelled_field.json"
    assert main(["fit", str(run), "--add", "temp_bias", "-o", str(cal), "--json"]) == 0
    out = capsys.readouterr()
    first = next(ln for ln in out.err.splitlines() if "cannot separate bias from scale" in ln)
    assert "30 poses cannot separate" in first and "up(" not in first and "Fitting only what" in first
    assert "S_xx not identified" in out.err
    c = load_calibration(cal)
    p, s = dict(zip(c.param_names, c.theta, strict=True)), dict(zip(c.param_names, c.sigma, strict=True))
    for i, a in enumerate("xy"):
        assert s[f"b_{a}"] > 0 and abs(p[f"b_{a}"] - aged.bias_g[i]) < 3 * s[f"b_{a}"] + 2e-4, (a, p, s)
    assert s["S_xx"] == 0 and s["S_yy"] == 0  # held at nominal, not fitted
    assert main(["workbench", str(run)]) == 0
    assert "temp_bias" in capsys.readouterr().out
