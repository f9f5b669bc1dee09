"""Field sessions in a fleet (issue 44, item 5): emulated robots with a six-pose lab session each,
then a robot's run (30 stops on slopes <= 15 deg, no pose labels) 3 months later; the biases of
some have aged 5-8 mg since, the others only by their slow drift. `fleet run` on a real local Dask
cluster (2 workers) updates each device's lab calibration by its run's stops; `fleet report` flags
"recalibrate" exactly on the devices that moved, names which parameter moved by how many sigma,
and proposes the field update as the new calibration."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.cli import main
from accellog.flows.fleet import read_table, run_fleet
from accellog.flows.fleet_report import fleet_report
from accellog.flows.fleet_sim import FleetSpec, serial_of, simulate_fleet

pytestmark = pytest.mark.slow  # a real local Dask cluster

REPO = Path(__file__).resolve().parents[2]
PIPELINE = REPO / "pipelines" / "fleet.toml"
AGED = (1, 3, 4)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("fleet_field")
    spec = FleetSpec(n_devices=6, sessions_per_device=1, field_runs=1, aged_devices=AGED, damaged=None)
    sim = simulate_fleet(spec, root / "sessions", jobs=2)
    res = run_fleet(PIPELINE, str(root / "sessions" / "**" / "*.mcap"), root / "out", workers=2)
    return {"root": root, "sim": sim, "res": res}


def test_field_runs_update_the_lab_calibrations(fleet):
    res = fleet["res"]
    assert res.errors == [] and res.n_run == 12 and res.n_workers == 2
    rows = read_table(Path(res.table))
    field = [r for r in rows if r["field"]]
    assert sorted(r["device"] for r in field) == [serial_of(k) for k in range(6)]
    for r in field:
        lab = next(x for x in rows if x["device"] == r["device"] and not x["field"])
        assert r["prior_calibration"] == lab["calibration"] and r["session"].endswith("_f0.mcap")
        assert r["param_names"] == lab["param_names"]


def test_report_flags_exactly_the_devices_that_moved(fleet, capsys):
    rep = fleet_report(fleet["root"] / "out")
    truth = json.loads(Path(fleet["sim"].truth_file).read_text())["devices"]
    aged = sorted(serial_of(k) for k in AGED)
    assert [h.device for h in rep.flagged] == aged
    for h in rep.devices:
        if h.device not in aged:
            assert h.largest.z < rep.k_sigma and h.proposed is None
            continue
        moved = {c.param for c in h.flagged}
        assert moved <= {"b_x", "b_y", "b_z"} and moved, moved  # only what the stops identify moves
        cal = load_calibration(fleet["root"] / "out" / h.proposed)
        row = next(r for r in h.sessions if r["field"])
        assert h.proposed == row["calibration"] and all(c.proposed == h.proposed for c in h.flagged)
        true_b = np.add(truth[h.device]["bias_g"], truth[h.device]["field_aged_bias_g"])
        assert np.all(np.abs(cal.theta[:3] - true_b) < 4 * cal.sigma[:3] + 2e-4), (cal.theta[:3], true_b)
        for c in h.flagged:  # the lab value moved by the aged amount, with its size in sigma
            k = ["b_x", "b_y", "b_z"].index(c.param)
            assert abs(c.delta - truth[h.device]["field_aged_bias_g"][k]) < 4 * c.sigma_combined
            assert c.z > rep.k_sigma and c.to_session == row["session"]
    assert main(["fleet", "report", str(fleet["root"] / "out"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["recalibrate"] == aged
    assert all(x["proposed_calibration"] for x in d["devices"] if x["device"] in aged)
    assert main(["fleet", "report", str(fleet["root"] / "out")]) == 0
    text = " ".join(capsys.readouterr().out.split()[-12:])  # the closing line (wrapped to the terminal)
    for h in rep.flagged:
        assert f"{h.device} (proposed: {h.proposed})" in text


def test_a_rerun_skips_every_session(fleet):
    """Nothing changed: no session runs again, nor a second pass (the field rows updated the
    latest lab calibrations)."""
    root = fleet["root"]
    again = run_fleet(PIPELINE, str(root / "sessions" / "**" / "*.mcap"), root / "out", workers=0)
    assert again.n_run == 0 and again.n_skipped == 12
