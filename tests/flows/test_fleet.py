"""Fleet: `simulate --fleet` -> `fleet run` on a real dask LocalCluster (2 worker processes) ->
`fleet report`, over 40 emulated devices x 3 sessions (3 months apart, slow ageing, one device
damaged after its first session) plus one corrupt file.

Done means (issue 15): every good session calibrated, the corrupt one reported with its one-line
message, the damaged device flagged "recalibrate" and no healthy one, a re-run skips everything,
the Parquet table and the calibration JSONs read back, the Rerun recording reads back.
"""

from __future__ import annotations

import json
import random
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.cli import main
from accellog.flows.fleet import read_table, run_fleet
from accellog.flows.fleet_report import fleet_report
from accellog.flows.fleet_sim import FleetSpec, simulate_fleet

pytestmark = pytest.mark.slow  # a real local Dask cluster per module

REPO = Path(__file__).resolve().parents[2]
PIPELINE = REPO / "pipelines" / "fleet.toml"
N_DEVICES, N_SESSIONS = 40, 3


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory):
    """The simulated fleet, a corrupt extra file, and the first fleet run (2 local workers)."""
    root = tmp_path_factory.mktemp("fleet")
    sim = simulate_fleet(
        FleetSpec(n_devices=N_DEVICES, sessions_per_device=N_SESSIONS), root / "sessions", jobs=2
    )
    good = sorted(str(p) for p in (root / "sessions").rglob("*.mcap"))
    bad = root / "sessions" / "IMU-0007" / "IMU-0007_s9.mcap"
    shutil.copy(good[0], bad)
    data = bytearray(bad.read_bytes())
    rnd = random.Random(15)
    data[200:] = bytes(rnd.randrange(256) for _ in range(len(data) - 200))  # valid magic, garbage after
    bad.write_bytes(bytes(data))
    res = run_fleet(PIPELINE, str(root / "sessions" / "**" / "*.mcap"), root / "out", workers=2)
    return {"root": root, "sim": sim, "good": good, "bad": str(bad), "res": res}


def test_every_good_session_calibrated_and_the_corrupt_one_reported(fleet):
    res, good = fleet["res"], fleet["good"]
    assert len(good) == N_DEVICES * N_SESSIONS
    assert res.n_workers == 2 and res.scheduler.startswith("tcp://127.0.0.1:")
    assert res.n_sessions == len(good) + 1 and res.n_run == res.n_sessions and res.n_skipped == 0
    assert [s for s, _ in res.errors] == [fleet["bad"]]
    msg = res.errors[0][1]
    assert "\n" not in msg and fleet["bad"] in msg and "MCAP" in msg
    rows = read_table(Path(res.table))
    ok = [r for r in rows if not r["error"]]
    assert sorted(r["session"] for r in ok) == good  # one model (model3) per session
    # the tasks ran in both worker processes, none in the client
    assert len({r["worker_pid"] for r in rows}) == 2


def test_table_columns_and_calibration_files(fleet):
    res, out = fleet["res"], fleet["root"] / "out"
    t = pq.read_table(res.table)
    for col in (
        "device",
        "session",
        "time",
        "model",
        "values",
        "sigmas",
        "chi2_dof",
        "heldout_rms_g",
        "noise_std_g",
        "flags",
        "error",
        "who_am_i",
        "i2c_address",
        "host",
    ):
        assert col in t.column_names
    rows = read_table(res.table)
    r = next(r for r in rows if r["device"] == "IMU-0001" and r["session"].endswith("_s0.mcap"))
    assert r["who_am_i"] == 0x71 and r["i2c_address"] == 0x68 and r["i2c_bus"] == "emulator"
    assert r["param_names"][:3] == ["b_x", "b_y", "b_z"] and len(r["sigmas"]) == 12
    truth = json.loads(Path(fleet["sim"].truth_file).read_text())["devices"]["IMU-0001"]
    b, s = np.array(r["values"][:3]), np.array(r["sigmas"][:3])
    assert np.all(np.abs(b - truth["bias_g"]) < 6 * s + 2e-4)  # the drawn zero-g offset is found
    assert 0.5 < r["chi2_dof"] < 2.0
    # held-out RMS is at its noise floor (the model explains the held-out windows)
    assert r["heldout_rms_g"] < 2.0 * r["heldout_noise_g"]
    cal = load_calibration(out / r["calibration"])
    assert cal.device.serial == "IMU-0001" and cal.device.who_am_i == 0x71
    np.testing.assert_allclose(cal.theta, r["values"])
    assert sum(1 for _ in (out / "cal").rglob("*.json")) == N_DEVICES * N_SESSIONS


def test_report_flags_the_damaged_device_only(fleet):
    rep = fleet_report(fleet["root"] / "out")
    damaged = fleet["sim"].damaged_serial
    assert len(rep.devices) == N_DEVICES
    assert [h.device for h in rep.flagged] == [damaged]
    h = rep.flagged[0]
    big = {c.param: c for c in h.flagged}
    assert abs(big["b_x"].delta - 0.020) < 0.002 and big["b_x"].z > 20  # the 20 mg jump, with its size
    assert big["b_x"].to_session.endswith("_s1.mcap")
    healthy_z = [d.largest.z for d in rep.devices if d.device != damaged]
    assert max(healthy_z) < rep.k_sigma
    assert [e["session"] for e in rep.errors] == [fleet["bad"]]
    names = {p.param for p in rep.distributions}
    assert {"b_x", "S_xx", "S_xy"} <= names
    bx = next(p for p in rep.distributions if p.param == "b_x")
    assert bx.n == N_DEVICES and bx.limit == 0.060
    assert bx.std > 0.01  # datasheet-distributed offsets: uniform +-60 mg has std 35 mg


def test_rerun_skips_everything_and_force_recomputes_one(fleet, tmp_path):
    root = fleet["root"]
    before = (root / "out" / "fleet.parquet").read_bytes()
    res = run_fleet(PIPELINE, str(root / "sessions" / "**" / "*.mcap"), root / "out", workers=2)
    assert res.n_run == 0 and res.n_skipped == N_DEVICES * N_SESSIONS + 1
    assert read_table(root / "out" / "fleet.parquet") == read_table_from_bytes(before, tmp_path)
    # a changed pipeline is a new pipeline hash: everything would rerun; check on two files, serially
    spec = (PIPELINE.read_text()).replace("window_s = 0.5", "window_s = 0.6")
    p2 = tmp_path / "p2.toml"
    p2.write_text(spec)
    files = fleet["good"][:2]
    shutil.copytree(root / "out", tmp_path / "out")
    res2 = run_fleet(p2, files, tmp_path / "out", workers=0)
    assert res2.n_run == 2 and res2.scheduler == "serial"


def test_the_client_writes_what_the_workers_write(fleet, tmp_path):
    """--client-writes (a remote cluster whose workers do not share FLEET/) and the workers' own
    writing give the same table rows and calibration files (up to their creation time)."""
    from accellog.flows.fleet_dask import close_own, start_client

    files = fleet["good"][:6]
    client = start_client(None, 2).result()
    try:
        by = {w: run_fleet(PIPELINE, files, tmp_path / w, client=client, workers_write=(w == "workers"))
              for w in ("workers", "client")}  # fmt: skip
    finally:
        close_own(client)
    rows = {w: read_table(r.table) for w, r in by.items()}
    drop = ("task_s", "task_cpu_s", "worker_pid")
    assert [{k: v for k, v in r.items() if k not in drop} for r in rows["workers"]] == [
        {k: v for k, v in r.items() if k not in drop} for r in rows["client"]
    ]
    for r in rows["workers"]:
        w, c = (json.loads((tmp_path / x / r["calibration"]).read_text()) for x in ("workers", "client"))
        assert {**w, "created_utc": ""} == {**c, "created_utc": ""}
    assert not [p for p in (tmp_path / "workers").rglob(".*")]  # no temporary or lock file left


def read_table_from_bytes(data: bytes, tmp: Path) -> list[dict]:
    p = tmp / "before.parquet"
    p.write_bytes(data)
    return read_table(p)


def test_cli_report_json_and_rerun_recording(fleet, tmp_path, capsys):
    from rrd_readback import load_rrd

    rrd = tmp_path / "fleet.rrd"
    rc = main(["fleet", "report", str(fleet["root"] / "out"), "--json", "--rerun", f"save:{rrd}"])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert d["recalibrate"] == [fleet["sim"].damaged_serial] and d["n_devices"] == N_DEVICES
    r = load_rrd(rrd)
    damaged = fleet["sim"].damaged_serial
    t, v = r.series(f"fleet/devices/{damaged}/b_x", timeline="session_time")
    assert v.shape == (N_SESSIONS, 3) and np.all(np.diff(t) > 0)
    assert v[1, 0] - v[0, 0] > 0.015  # the damage shows in the recorded history
    assert "/fleet/scatter/bias_mg" in r.entities and f"/fleet/devices/{damaged}/recalibrate" in r.entities


def test_cli_bad_inputs_are_one_line(tmp_path, capsys):
    assert (
        main(["fleet", "run", str(PIPELINE), str(tmp_path / "none" / "*.mcap"), "-o", str(tmp_path / "o")])
        != 0
    )
    err = capsys.readouterr().err
    assert err.startswith("accellog: error: ") and "no session file matches" in err and err.count("\n") == 1
    (tmp_path / "f").mkdir()
    (tmp_path / "f" / "fleet.parquet").write_text("not parquet")
    assert main(["fleet", "report", str(tmp_path / "f")]) != 0
    err = capsys.readouterr().err
    assert "not a readable fleet table" in err and err.count("\n") == 1


def test_simulate_fleet_cli(tmp_path):
    out = tmp_path / "fl"
    assert main(["simulate", "--fleet", "2", "--fleet-sessions", "2", "-o", str(out)]) == 0
    files = sorted(out.rglob("*.mcap"))
    assert [f.name for f in files] == [
        "IMU-0001_s0.mcap",
        "IMU-0001_s1.mcap",
        "IMU-0002_s0.mcap",
        "IMU-0002_s1.mcap",
    ]
    from accellog.store.reader import read_session

    s0, s1 = read_session(files[0]), read_session(files[1])
    assert s0.meta.serial == "IMU-0001" and s0.meta.device.id == "IMU-0001"
    months = (s1.meta.start_time_unix_ns - s0.meta.start_time_unix_ns) / 1e9 / 86400 / 30.4375
    assert abs(months - 3.0) < 0.01
    assert main(["simulate", "--fleet", "2", "-o", str(tmp_path / "x.mcap")]) != 0


def test_cli_run_on_a_running_scheduler(tmp_path, capsys):
    """--scheduler tcp://HOST:PORT: the client connects to an existing cluster (here a 1-worker
    LocalCluster on 127.0.0.1 standing in for a real one) and leaves it running."""
    from dask.distributed import LocalCluster

    simulate_fleet(FleetSpec(n_devices=3, sessions_per_device=1, damaged=None), tmp_path / "s")
    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address="127.0.0.1:0"
    ) as lc:
        addr = lc.scheduler_address
        argv = [
            "fleet",
            "run",
            str(PIPELINE),
            str(tmp_path / "s" / "**" / "*.mcap"),
            "-o",
            str(tmp_path / "o"),
        ]
        assert main([*argv, "--scheduler", addr, "--json"]) == 0
        d = json.loads(capsys.readouterr().out)
        assert d["scheduler"] == addr and d["n_run"] == 3 and d["n_errors"] == 0 and d["n_workers"] == 1
        assert lc.status.name == "running"
    assert len(read_table(tmp_path / "o" / "fleet.parquet")) == 3
