"""Data safety (issue 12): outputs never replace inputs or another writer's file, recovery is
announced, labels are checked against physics, faults can be injected, bad input never gives a
traceback (also in a real subprocess), and fuzzed MCAP / CSV files only ever give one-line errors.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.sessions import synth_session

from accellog.cli import main
from accellog.core.errors import AccellogError, InputError
from accellog.core.session import PoseLabel
from accellog.flows.pipeline import run_pipeline
from accellog.flows.simulate import Scenario, simulate
from accellog.store.atomic import AtomicOutput, OutputLock, atomic_output, check_output
from accellog.store.reader import read_session
from accellog.store.writer import SessionWriter, write_session

PIPELINES = Path(__file__).resolve().parents[2] / "pipelines"

CLI = [sys.executable, "-c", "import sys; from accellog.cli import main; sys.exit(main())"]
ENV = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}


# ------------------------------------------------------------------------------- atomic outputs


def test_second_writer_gets_one_line_error_and_first_file_survives(tmp_path):
    out = tmp_path / "x.json"
    with atomic_output(out) as tmp:
        tmp.write_text("first")
        with pytest.raises(InputError, match="another process is writing this file"), atomic_output(out):
            pass
    assert out.read_text() == "first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.json"]  # no temp, no lock file left


def test_lock_is_exclusive_across_processes(tmp_path):
    out = tmp_path / "s.mcap"
    code = (
        "import sys, time; from accellog.store.atomic import OutputLock; "
        f"l = OutputLock({str(out)!r}).acquire(); print('locked', flush=True); time.sleep(30)"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=ENV)
    try:
        assert proc.stdout.readline().strip() == "locked"
        with pytest.raises(InputError, match="another process"):
            OutputLock(out).acquire()
    finally:
        proc.kill()
        proc.wait()
    OutputLock(out).acquire().release()  # the dead holder's lock is gone with its process


def test_a_waiting_writer_takes_its_turn_across_processes(tmp_path):
    """wait=True (the fleet's workers writing one calibration name): the second writer blocks until
    the holder's process releases the lock, then writes; nothing is left beside the file."""
    out = tmp_path / "c.json"
    code = (
        "from accellog.store.atomic import write_text_atomic; print('writing', flush=True); "
        f"write_text_atomic({str(out)!r}, 'second', wait=True); print('written', flush=True)"
    )
    with atomic_output(out) as tmp:
        tmp.write_text("first")
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=ENV)
        assert proc.stdout.readline().strip() == "writing"
        with pytest.raises(subprocess.TimeoutExpired):
            proc.wait(timeout=0.5)  # blocked while the lock is held (without wait: exit 1 at once)
        assert not out.exists()
    assert proc.stdout.readline().strip() == "written" and proc.wait(timeout=30) == 0
    assert out.read_text() == "second"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.json"]


def test_no_overwrite_mode_refuses_existing_and_aborts_cleanly(tmp_path):
    out = tmp_path / "keep.mcap"
    out.write_bytes(b"session")
    with pytest.raises(InputError, match="--force"):
        check_output(out, overwrite=False)
    ao = AtomicOutput(tmp_path / "new.mcap", overwrite=False)
    tmp = ao.begin()
    tmp.write_bytes(b"abc")
    (tmp_path / "new.mcap").write_bytes(b"someone else")  # a foreign writer creates it meanwhile
    with pytest.raises(InputError, match="file exists"):
        ao.commit()
    assert (tmp_path / "new.mcap").read_bytes() == b"someone else"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.mcap", "new.mcap"]


def test_two_concurrent_simulations_of_one_path(tmp_path):
    """One wins, the other gets a one-line error; the file is a complete, readable session."""
    out = tmp_path / "sim.mcap"
    procs = [
        subprocess.Popen(
            [*CLI, "simulate", "-o", str(out), "--hold", "3", "--protocol", "+z,-z", "--seed", str(k)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=ENV,
        )
        for k in (1, 2)
    ]
    results = [(p.wait(60), p.stderr.read()) for p in procs]
    for p in procs:
        p.stdout.close()
        p.stderr.close()
    assert sorted(rc for rc, _ in results) == [0, 2], results
    err = next(e for rc, e in results if rc)
    assert "Traceback" not in err and err.strip().startswith("accellog: error: ")
    assert "another process" in err or "--force" in err
    assert read_session(out).n > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim.mcap"]


def test_record_and_simulate_refuse_existing_unless_force(tmp_path, capsys):
    out = tmp_path / "s.mcap"
    out.write_bytes(b"a precious session")
    assert main(["simulate", "-o", str(out), "--hold", "2", "--protocol", "+z"]) == 2
    assert out.read_bytes() == b"a precious session"
    assert main(["simulate", "-o", str(out), "--hold", "2", "--protocol", "+z", "--force"]) == 0
    assert read_session(out).n > 0
    assert "--force" in capsys.readouterr().err


def test_live_writer_exclusive_create(tmp_path):
    from accellog.core.session import SessionMeta

    out = tmp_path / "live.mcap"
    out.write_bytes(b"keep")
    with pytest.raises(InputError, match="--force"):
        SessionWriter(out, SessionMeta(source="test"), exclusive=True)
    assert out.read_bytes() == b"keep"
    with (
        SessionWriter(out, SessionMeta(source="test"), exclusive=True, overwrite=True),
        pytest.raises(InputError, match="another process"),
    ):
        SessionWriter(out, SessionMeta(source="test"), exclusive=True, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["live.mcap"]


def test_rrd_error_leaves_no_calibration(tmp_path, capsys):
    src = write_session(tmp_path / "s.mcap", synth_session(seed=4, hold_s=5.0, rate_hz=100.0))
    cal = tmp_path / "c.json"
    assert main(["fit", str(src), "-o", str(cal), "--rrd", str(tmp_path / "missing" / "x.rrd")]) == 2
    assert not cal.exists()
    (tmp_path / "d.rrd").mkdir()
    assert main(["fit", str(src), "-o", str(cal), "--rrd", str(tmp_path / "d.rrd")]) == 2
    assert not cal.exists() and list((tmp_path / "d.rrd").iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.rrd", "s.mcap"]
    capsys.readouterr()


# --------------------------------------------------------------------------------- subprocess


@pytest.mark.parametrize(
    "argv",
    [
        ["record", "--sim", "--fast", "--rate", "0", "-o", "{d}/r.mcap"],
        ["fit", "{d}/s.mcap", "-o", "{d}"],
        ["fit", "{d}/s.mcap", "-o", "{d}/s.mcap"],
        ["fit", "{d}/s.mcap", "-o", "{d}/c.json", "--effects-file", "{d}/fx.py", "--add", "mine"],
        ["simulate", "-o", "{d}", "--hold", "2"],
    ],
    ids=["rate0", "out-dir", "out-is-input", "plugin-exit", "simulate-dir"],
)
def test_subprocess_one_line_no_traceback(tmp_path, argv):
    write_session(tmp_path / "s.mcap", synth_session(seed=5, hold_s=5.0, rate_hz=100.0))
    (tmp_path / "fx.py").write_text(
        "import sys\nfrom accellog.calibrate.model.effects import Effect, per_axis\n"
        "def h(p, f_g, d):\n    sys.exit(0)\n"
        "MINE = Effect(name='mine', params=per_axis('m', 'g'), contribution=h)\n"
    )
    before = sorted(p.name for p in tmp_path.iterdir())
    r = subprocess.run(
        [*CLI, *[a.format(d=tmp_path) for a in argv]], capture_output=True, text=True, env=ENV, timeout=120
    )
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("accellog: error: "), r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before


# ----------------------------------------------------------------------------------- recovery


def _live_style_file(path: Path, s) -> Path:
    """Poses written as their holds end (as the recorder does), small chunks."""
    with SessionWriter(path, s.meta, chunk_size=8192) as w:
        t_ns = np.round(s.t_s * 1e9).astype(np.int64)
        k = 0
        for a in range(0, s.n, 100):
            while k < len(s.poses) and s.poses[k].end_s < s.t_s[a]:
                w.write_pose(s.poses[k])
                k += 1
            w.write_imu(int(s.sample_index[a]), t_ns[a : a + 100], accel_counts=s.accel_counts[a : a + 100])
    return path


def test_recovery_is_announced_in_stderr_json_and_provenance(tmp_path, capsys):
    full = _live_style_file(tmp_path / "full.mcap", synth_session(seed=6, hold_s=5.0, rate_hz=100.0))
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.9)])
    out = tmp_path / "c.json"
    capsys.readouterr()
    assert main(["fit", str(cut), "--model", "model1", "-o", str(out), "--json"]) == 0
    cap = capsys.readouterr()
    note = [ln for ln in cap.err.splitlines() if ln.startswith("accellog: note:")]
    assert len(note) == 1 and "cut.mcap" in note[0] and "truncated file recovered" in note[0], cap.err
    assert " holds kept" in note[0] and " s, " in note[0]
    rec = json.loads(cap.out)["recovered"][0]
    kept = read_session(cut)
    assert rec["holds"] == len(kept.poses) >= 5 and rec["samples"] == kept.n > 2000
    assert rec["duration_s"] == pytest.approx(kept.t_s[-1] - kept.t_s[0])
    src = json.loads(out.read_text())["sources"][0]
    assert src["recovered"] == rec
    # a pipeline's calibration keeps it too (it named its input anew and dropped it)
    res = run_pipeline(PIPELINES / "fleet.toml", [str(cut)])
    assert res.fits["model3"].cal.sources[0].recovered == rec
    assert res.fits["model3"].cal.sources[0].sha256 == src["sha256"]
    # a finished file: no note, no 'recovered'
    assert main(["fit", str(full), "--model", "model1", "-o", str(tmp_path / "d.json"), "--json"]) == 0
    cap = capsys.readouterr()
    assert "note" not in cap.err and "recovered" not in json.loads(cap.out)


# ------------------------------------------------------------------------------------- labels


def test_mislabelled_hold_named_and_relabel_fixes_it(tmp_path, capsys):
    s = synth_session(seed=7, hold_s=6.0, rate_hz=100.0)
    p = s.poses[1]  # really -z
    s.poses[1] = PoseLabel("+z", p.start_s, p.end_s, (0.0, 0.0, 1.0), None, 1)
    src = write_session(tmp_path / "s.mcap", s)
    out = tmp_path / "c.json"
    assert main(["fit", str(src), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "pose '+z'" in err and "looks like '-z'" in err and "deg from the label" in err
    assert main(["fit", str(src), "-o", str(out), "--relabel", "--json"]) == 0
    cap = capsys.readouterr()
    assert "relabelled '+z' as '-z'" in cap.err
    cal = json.loads(out.read_text())
    s_zz = next(q["value"] for q in cal["params"] if q["name"] == "S_zz")
    assert abs(s_zz - 1.0) < 0.05  # not -0.002: the fit used the true pose


def test_absurd_calibration_values_are_refused(tmp_path):
    from accellog.calibrate.calfile.calibration import load_calibration

    src = write_session(tmp_path / "s.mcap", synth_session(seed=8, hold_s=5.0, rate_hz=100.0))
    good = tmp_path / "c.json"
    assert main(["fit", str(src), "-o", str(good)]) == 0
    load_calibration(good)
    for name, value in (("S_xx", 1e308), ("S_zz", -0.002), ("b_y", 3.0), ("S_yx", 0.7)):
        d = json.loads(good.read_text())
        next(q for q in d["params"] if q["name"] == name)["value"] = value
        bad = tmp_path / f"{name}.json"
        bad.write_text(json.dumps(d))
        with pytest.raises(InputError, match=f"absurd calibration value {name}"):
            load_calibration(bad)


# ------------------------------------------------------------------------------------- faults


def test_fault_injection_counts_every_lost_sample(tmp_path):
    sc = Scenario(
        protocol="+z,-z",
        hold_s=4.0,
        move_s=1.0,
        sample_rate_hz=500.0,
        faults={
            "i2c_error_rate": 0.02,
            "fifo_glitch_rate": 0.02,
            "host_stall_s": 0.2,
            "host_stall_every_s": 3.0,
            "disconnect_at_s": 5.0,
            "disconnect_s": 0.5,
        },
    )
    summary = simulate(sc, tmp_path / "f.mcap")
    s = read_session(tmp_path / "f.mcap")
    kinds = {e.kind for e in s.events}
    assert {"retry", "misaligned", "fifo_overflow", "i2c_error"} <= kinds, kinds
    lost = sum(e.lost_samples for e in s.events)
    assert lost == summary.lost_samples > 0
    # every sample the session lacks is an accounted loss (sample_index gaps == counted losses)
    gaps = int(np.sum(np.diff(s.sample_index) - 1))
    assert gaps == lost
    assert json.loads(s.meta.extra["scenario"])["faults"]["disconnect_s"] == 0.5


def test_fault_keys_in_help_and_validation(capsys):
    main(["simulate", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    for key in ("i2c_error_rate", "fifo_glitch_rate", "host_stall_s", "disconnect_s"):
        assert key in out
    with pytest.raises(InputError, match=r"scenario \[faults\]: fault key 'i2c_error_rate' = 2"):
        Scenario.from_dict({"faults": {"i2c_error_rate": 2.0}})


def test_fault_keys_of_the_old_flat_form_still_work(tmp_path):
    """Before Scenario.faults the fault keys were Scenario's own: as keywords, attributes and TOML
    keys at the top level they still give the same scenario, with a DeprecationWarning (and a note
    for the command line)."""
    from accellog.acquire.emulator.faults import FaultPlan
    from accellog.core import notices

    new = Scenario(protocol="+z", faults={"i2c_error_rate": 0.02, "disconnect_s": 0.5})
    assert new.faults == FaultPlan(i2c_error_rate=0.02, disconnect_s=0.5)
    with pytest.warns(DeprecationWarning, match=r"Scenario\(i2c_error_rate=0.02, disconnect_s=0.5\)"):
        old = Scenario(protocol="+z", i2c_error_rate=0.02, disconnect_s=0.5)
    assert old == new and old.to_json() == new.to_json()
    with pytest.warns(
        DeprecationWarning, match=r"Scenario.disconnect_s: deprecated, read Scenario.faults.disconnect_s"
    ):
        assert old.disconnect_s == 0.5
    with pytest.warns(DeprecationWarning):
        old.host_stall_s = 0.1
    assert old.faults == FaultPlan(i2c_error_rate=0.02, host_stall_s=0.1, disconnect_s=0.5)
    with pytest.raises(TypeError, match="both"):
        Scenario(i2c_error_rate=0.02, faults={"disconnect_s": 0.5})
    toml_old, toml_new = tmp_path / "old.toml", tmp_path / "new.toml"
    toml_old.write_text('protocol = "+z"\ni2c_error_rate = 0.02\ndisconnect_s = 0.5\n')
    toml_new.write_text('protocol = "+z"\n[faults]\ni2c_error_rate = 0.02\ndisconnect_s = 0.5\n')
    notices.take()
    assert Scenario.from_toml(toml_new) == new and not notices.take()
    with pytest.warns(DeprecationWarning, match="top level"):
        assert Scenario.from_toml(toml_old) == new
    assert any("[faults]" in n for n in notices.take())
    with pytest.raises(InputError, match="both at the top level and in"):
        Scenario.from_dict({"i2c_error_rate": 0.02, "faults": {"disconnect_s": 0.5}})


def test_long_poll_makes_progress_and_no_overflow_at_start(tmp_path):
    """The issue: a 50 ms poll at 1 kHz overflowed the 36 ms FIFO on every read (no progress)."""
    summary = simulate(
        Scenario(protocol="+z", hold_s=3.0, sample_rate_hz=1000.0), tmp_path / "p.mcap", poll_s=0.05
    )
    assert summary.lost_samples == 0 and summary.samples > 2900
    assert not [e for e in summary.events if e.kind == "fifo_overflow"]


# --------------------------------------------------------------------------------------- fuzz


def _fuzz_one(path: Path) -> None:
    """The readers behind every command: a result or a one-line AccellogError naming the file."""
    from accellog.flows.stages import load_input

    try:
        load_input(path)
    except AccellogError as exc:
        msg = str(exc)
        assert path.name in msg and "\n" not in msg, msg


@pytest.fixture(scope="module")
def mcap_bytes(tmp_path_factory) -> bytes:
    d = tmp_path_factory.mktemp("fuzz")
    return write_session(
        d / "s.mcap", synth_session(seed=9, hold_s=3.0, rate_hz=50.0), chunk_size=4096
    ).read_bytes()


def _mutate(buf: bytearray, data, kinds: list[str]) -> bytearray:
    for _ in range(data.draw(st.integers(1, 4))):
        kind = data.draw(st.sampled_from(kinds))
        i = data.draw(st.integers(0, len(buf) - 1))
        if kind == "flip":
            buf[i] ^= 1 << data.draw(st.integers(0, 7))
        elif kind == "byte":
            buf[i] = data.draw(st.integers(0, 255))
        elif kind == "cut":
            del buf[i:]
        else:
            buf[i:i] = data.draw(st.binary(min_size=1, max_size=16))
        if not buf:
            break
    return buf


FUZZ = settings(
    max_examples=150,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)


@FUZZ
@given(data=st.data())
def test_fuzz_mcap_reader_cuts(mcap_bytes, tmp_path, data):
    """Truncated MCAP files (a crash, a full disk, a partial copy): recovered or one-line error."""
    p = tmp_path / "fz.mcap"
    p.write_bytes(bytes(_mutate(bytearray(mcap_bytes), data, ["cut"])))
    _fuzz_one(p)


@FUZZ
@given(data=st.data())
def test_fuzz_mcap_reader_damage(mcap_bytes, tmp_path, data):
    """Bit flips, byte overwrites, insertions and cuts of a real MCAP: any outcome but a traceback."""
    p = tmp_path / "fz.mcap"
    p.write_bytes(bytes(_mutate(bytearray(mcap_bytes), data, ["flip", "byte", "cut", "insert"])))
    _fuzz_one(p)


@settings(
    max_examples=200,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    header=st.sampled_from(["t,ax,ay,az", "t,ax,ay,az,pose", "t,ax,ay,az,temp", "t,ax", "x,y", ""]),
    rows=st.lists(
        st.lists(
            st.one_of(
                st.floats(allow_nan=True, allow_infinity=True).map(repr),
                st.sampled_from(["+z", "-x", "", "nan", "1e999", "abc", '"', "0x10"]),
                st.text(max_size=4),
            ),
            max_size=6,
        ),
        max_size=12,
    ),
)
def test_fuzz_csv_reader(tmp_path, header, rows):
    p = tmp_path / "fz.csv"
    p.write_text(
        header + "\n" + "\n".join(",".join(r) for r in rows), encoding="utf-8", errors="surrogatepass"
    )
    _fuzz_one(p)


# ----------------------------------------------------------------------------- sandbox (library)


def test_plugin_errors_name_file_effect_line(tmp_path):
    from accellog.calibrate.model.effects import load_effects_file

    fx = tmp_path / "fx.py"
    fx.write_text(
        "from accellog.calibrate.model.effects import Effect, per_axis\n"
        "def h(p, f_g, d):\n"
        "    x = 1\n"
        "    raise SystemExit('bye')\n"
        "MINE = Effect(name='mine', params=per_axis('m', 'g'), contribution=h)\n"
    )
    eff = load_effects_file(fx).effects["mine"]
    with pytest.raises(InputError) as ei:
        eff.contribution({"m_x": 0, "m_y": 0, "m_z": 0}, np.zeros((2, 3)), {})
    assert str(ei.value).startswith(f"{fx}:4: effect 'mine' failed: it called sys.exit('bye')")


def test_threads_cannot_share_an_output(tmp_path):
    out = tmp_path / "o.json"
    errors: list[str] = []
    gate = threading.Barrier(4)
    others_refused = threading.Event()  # the writer holds its output until the three others tried

    def write(k: int) -> None:
        gate.wait()
        try:
            with atomic_output(out) as tmp:
                tmp.write_text(str(k) * 1000)
                others_refused.wait(30.0)
        except InputError as exc:
            errors.append(str(exc))
            if len(errors) == 3:
                others_refused.set()

    ts = [threading.Thread(target=write, args=(k,)) for k in range(4)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    text = out.read_text()
    assert len(set(text)) == 1 and len(text) == 1000  # one writer's whole file
    assert len(errors) == 3 and all("another process" in e for e in errors)
