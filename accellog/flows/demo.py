"""`accellog demo`: the whole story on the emulated chip, in about ten seconds.

1. Record (simulated clock, same driver and MCAP path as hardware) a six-position calibration
   session, static sessions, 24-pose sessions on two temperature paths and a robot run, all from
   one emulated MPU-9250 with datasheet-typical errors.
2. Fit the seed's Models 1-3 (with uncertainties), evaluate them on a static test (the seed's
   Tables 4 and 5), fit the drift polynomial on one static session and apply it to the other (the
   seed's final table).
3. Moving robot at 38 degC: strapdown tracks with ZUPT against the true path; Model 3, fitted at
   25 degC: its gyro bias is off at 38 degC and its accelerometer part alone ends about where raw ends.
4. Workbench: a 24-pose session recorded while the chip heats and cools; ``diagnose`` finds what
   Model 3 is missing, it is added, and the error falls: on the calibration data, on a held-out
   session at another temperature, on a hot static test (ladder table) and on the robot.
5. Everything goes to one .rrd with a saved blueprint (one tab per chapter).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from accellog.calibrate.diagnosis.diagnose import Diagnosis
from accellog.calibrate.observe.segment import observations
from accellog.core.session import ObsTable
from accellog.flows.simulate import Scenario, simulate
from accellog.flows.stages import DriftOutcome, run_drift, run_evaluate, run_fit
from accellog.flows.workbench import BASE_STEPS, discover, ladder_rows, log_ladder, steps_for
from accellog.navigate.track_eval import accel_corrector, gyro_corrector, run_session_tracks
from accellog.present.rrd.demo_layout import DemoData, demo_blueprint
from accellog.present.rrd.recording import RunRecording
from accellog.present.tables import (
    displacement_table,
    drift_table,
    ladder_table,
    params_table,
    print_tables,
    static_means_table,
)
from accellog.present.views import (
    log_diagnosis,
    log_evaluations,
    log_fit,
    log_session,
    log_track_runs,
    table_markdown,
)
from accellog.store.atomic import folder_output
from accellog.store.reader import read_session

CHIP_SEED = 7
"""One emulated chip for every session of the demo (its error parameters come from this seed)."""


@dataclass
class DemoResult:
    """Everything the demo computed (write_rrd turns it into a recording)."""

    out_dir: Path
    rrd: Path | None
    fits: dict = field(default_factory=dict)
    evals: list = field(default_factory=list)
    drift_evals: list = field(default_factory=list)
    drift: DriftOutcome | None = None
    final_rows: list = field(default_factory=list)
    ladder: list = field(default_factory=list)
    discovered: list[str] = field(default_factory=list)
    tracks: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)
    sessions: dict = field(default_factory=dict)
    """name -> Session of every simulated session."""
    diagnoses: list = field(default_factory=list)
    """Workbench diagnoses, one per discovery step."""
    workbench_obs: ObsTable | None = None
    """Observations (ObsTable) of the warm-up session the workbench diagnosed."""


def _sessions(out: Path, quick: bool, progress=None) -> dict[str, Path]:
    """The demo's sessions, simulated into out; progress(done, total sessions) after each."""
    hold = 15.0 if quick else 30.0
    # Heating then a fan: temperature goes up and down, so temperature effects are not confounded
    # with time (a single warm-up curve cannot tell temp_bias from warmup or time_drift).
    warm = {"kind": "points", "t_s": [0.0, 120.0, 250.0, 420.0], "T": [22.0, 40.0, 28.0, 36.0]}
    warm2 = {"kind": "points", "t_s": [0.0, 100.0, 260.0, 420.0], "T": [30.0, 44.0, 33.0, 41.0]}
    specs = {
        "calibration": Scenario(protocol="six", hold_s=hold, chip_seed=CHIP_SEED, seed=1),
        "static_drift": Scenario(protocol="+z", hold_s=62.0, chip_seed=CHIP_SEED, seed=2),
        "static_test": Scenario(protocol="+z", hold_s=62.0, chip_seed=CHIP_SEED, seed=3),
        "warmup_24": Scenario(
            protocol="24",
            hold_s=10.0 if quick else 15.0,
            move_s=2.0,
            chip_seed=CHIP_SEED,
            seed=4,
            temperature=warm,
        ),
        "heldout_24": Scenario(
            protocol="24",
            hold_s=10.0 if quick else 15.0,
            move_s=2.0,
            chip_seed=CHIP_SEED,
            seed=5,
            temperature=warm2,
        ),
        "static_hot": Scenario(
            protocol="+z",
            hold_s=62.0,
            chip_seed=CHIP_SEED,
            seed=6,
            temperature={"kind": "constant", "T": 40.0},
        ),
        "robot": Scenario(
            motion="robot", chip_seed=CHIP_SEED, seed=8, temperature={"kind": "constant", "T": 38.0}
        ),
    }
    paths = {}
    for k, (name, sc) in enumerate(specs.items()):
        if progress is not None:
            progress(k, len(specs))
        p = out / f"{name}.mcap"
        simulate(sc, p, force=True)  # the demo regenerates its own folder
        paths[name] = p
    if progress is not None:
        progress(len(specs), len(specs))
    return paths


def run_demo(
    out_dir: Path,
    *,
    rrd: Path | None,
    quick: bool = False,
    console: Console | None = None,
    first_tab: int = 0,
    progress=None,
) -> DemoResult:
    """Run the demo, print its tables, write sessions / calibrations / .rrd under out_dir.

    first_tab: the blueprint tab shown when the recording opens (0 static test, 1 calibration,
    2 workbench, 3 robot). progress(done, total): the sessions simulated by the first step."""

    con = console or Console(width=None if sys.stdout.isatty() else 120)
    with folder_output(out_dir) as out:  # a folder the demo made goes if it fails (a full disk)
        res = DemoResult(out_dir=out, rrd=rrd)
        t0 = time.perf_counter()
        _record_stage(res, out, quick, con, t0, progress)
        _seed_stage(res, out, con)
        first = _robot_stage(res, con)
        _workbench_stage(res, first, con)

        if rrd is not None:
            t4 = time.perf_counter()
            write_rrd(res, rrd, first_tab)
            res.seconds["rrd"] = time.perf_counter() - t4
            con.print(f"wrote {rrd} (open it with: accellog view {rrd})")
        con.print(f"sessions and calibrations in {out}/ ; total {time.perf_counter() - t0:.1f} s")
    return res


def _record_stage(res: DemoResult, out: Path, quick: bool, con: Console, t0: float, progress=None) -> None:
    """1. the demo's sessions from the emulated MPU-9250 (res.sessions)."""
    con.rule("[bold]1. record sessions from the emulated MPU-9250 (simulated clock)")
    paths = _sessions(out, quick, progress)
    S = res.sessions = {k: read_session(p) for k, p in paths.items()}
    res.seconds["simulate"] = time.perf_counter() - t0
    for k, s in S.items():
        con.print(
            f"  {paths[k].name}: {s.n} samples, {s.t_s[-1]:.0f} s, {len(s.poses)} holds, {s.lost_samples()} lost"
        )


def _seed_stage(res: DemoResult, out: Path, con: Console) -> None:
    """2. the seed's procedure: Models 1-3 (res.fits), static test (res.evals), drift model (res.drift)."""
    S = res.sessions
    con.rule("[bold]2. the seed's procedure: Models 1-3, static test, drift model")
    t1 = time.perf_counter()
    cal_obs = observations(S["calibration"])
    for m in ("model1", "model2", "model3"):
        res.fits[m] = run_fit(S["calibration"], m, obs=cal_obs)
        res.fits[m].cal.save(out / f"cal_{m}.json")
    print_tables([params_table(res.fits["model3"].cal, title="Model 3 parameters (± 1σ, Cramér-Rao)")], con)
    cals = [res.fits[m].cal for m in ("model1", "model2", "model3")]
    res.evals = run_evaluate(S["static_test"], cals, labels=["Model 1", "Model 2", "Model 3"])
    print_tables(
        [static_means_table(res.evals, "Table 4: static test, mean residual after calibration")], con
    )
    print_tables([displacement_table(res.evals, 60.0, title="Table 5: integrated displacement at 60 s")], con)
    res.drift = run_drift(S["static_drift"], res.fits["model3"].cal)
    res.drift.cal.save(out / "cal_model3_drift.json")
    res.drift_evals = ev_d = run_evaluate(
        S["static_test"], [res.fits["model3"].cal, res.drift.cal], labels=["Model 3", "Model 3 + drift"]
    )
    raw, m3, m3d = ev_d
    res.final_rows = [
        ("No calibration", raw.disp_end_m),
        ("Model 3", m3.disp_end_m),
        (
            "Model 3 and displacement model",
            m3d.disp_end_drift_m if m3d.disp_end_drift_m is not None else m3d.disp_end_m,
        ),
    ]
    tbl, qtbl = drift_table(res.final_rows, m3.t_end_s, res.drift.drift)
    print_tables([tbl, qtbl], con)
    res.seconds["seed procedure"] = time.perf_counter() - t1


def _robot_stage(res: DemoResult, con: Console) -> list:
    """3. the moving robot with Model 3: its strapdown tracks with ZUPT (raw and Model 3 returned).

    The raw track takes its gyro bias from the first second at rest (at 38 degC); Model 3's track
    its calibration's gyro part (fitted at 25 degC); a third row gives Model 3's accelerometer part
    the raw track's gyro, so that each part's share of the error shows."""
    con.rule("[bold]3. a moving robot at 38 °C: strapdown tracks with ZUPT vs the true path")
    t3 = time.perf_counter()
    robot = res.sessions["robot"]
    m3 = res.fits["model3"].cal
    alone = "Model 3 accel, gyro bias at rest"
    runs = run_session_tracks(robot, {"Model 3": m3, alone: accel_corrector(m3, robot)}, use_zupt=True)
    print_tables([_robot_table(runs, robot, "raw: gyro bias from the first second at rest")], con)
    gyro = gyro_corrector(m3, robot)
    if gyro is not None and robot.gyro_dps is not None:  # what Model 3's gyro reads at the first rest
        rest = robot.gyro_dps[robot.t_s <= robot.t_s[0] + 1.0]
        off = float(np.linalg.norm(gyro(rest).mean(axis=0)))
        con.print(
            f"  Model 3 was fitted at 25 °C. At 38 °C its gyro bias is {off:.2g} °/s off, which tilts the "
            "track and leaks gravity into it, and its accelerometer part alone ends about where raw ends: "
            "both drift with temperature. What is Model 3 missing?"
        )
    res.seconds["robot"] = time.perf_counter() - t3
    return [r for r in runs if r.name != alone]


def _workbench_stage(res: DemoResult, first: list, con: Console) -> None:
    """4. the workbench on the warm-up session (res.diagnoses, res.ladder) and the robot again (res.tracks)."""
    S = res.sessions
    robot = S["robot"]
    con.rule("[bold]4. workbench: heating and cooling reveal what Model 3 is missing")
    t2 = time.perf_counter()
    obs = observations(S["warmup_24"])
    held = observations(S["heldout_24"])

    def said(d: object) -> None:
        assert isinstance(d, Diagnosis)  # discover() calls on_step with each step's Diagnosis
        con.print(f"  {d.verdict}")

    found = discover(obs, "model3", heldout=[held], on_step=said)
    diags = res.diagnoses = found.diagnoses
    res.workbench_obs = obs
    res.discovered = list(found.added)
    con.print(f"  held out: {found.verdict}")
    for a in diags[-1].advice[:3]:
        con.print(f"  advice: {a}")
    rows = ladder_rows(S["warmup_24"], obs, steps_for(found), heldout=held, static_test=S["static_hot"])
    res.ladder = rows
    table = ladder_table(rows, title="watch the error fall: each step of model building")
    table.caption = (
        "held-out: a 24-pose session of the same chip on another temperature path; "
        "drift: |displacement| of a 60 s static test at 40 °C"
    )
    print_tables([table], con)
    # the robot again, with the model the workbench found (its gyro part carries the temperature terms)
    res.tracks = first + run_session_tracks(robot, {rows[-1].model: rows[-1].fit.cal}, use_zupt=True)[1:]
    print_tables([_robot_table(res.tracks, robot, "and with the model the workbench found")], con)
    res.seconds["workbench"] = time.perf_counter() - t2


def _robot_table(runs, robot, note: str) -> Table:
    """Final / RMS position error (m) of robot tracks against the truth, with and without ZUPT."""
    tt = Table(title=f"robot run ({robot.t_s[-1]:.0f} s at 38 °C): position error against the truth ({note})")
    for c in ("calibration", "final (m)", "RMS (m)", "final without ZUPT (m)", "ZUPT stops"):
        tt.add_column(c, justify="left" if c == "calibration" else "right", overflow="fold")
    for r in runs:
        e0 = r.error_without_zupt.final_error_m if r.error_without_zupt is not None else float("nan")
        tt.add_row(
            r.name,
            f"{r.error.final_error_m:.3g}",
            f"{r.error.rms_error_m:.3g}",
            f"{e0:.3g}",
            str(r.error.zupt_stops),
        )
    return tt


def write_rrd(res: DemoResult, path: Path, first_tab: int = 0) -> None:
    """The demo's recording of res at path, opening on tab first_tab (see demo_layout)."""

    S, diags, obs = res.sessions, res.diagnoses, res.workbench_obs
    assert res.drift is not None and obs is not None  # run() computed both before the recording
    bp = demo_blueprint(_layout_data(res), first=first_tab)
    with RunRecording(f"save:{path}", recording_id="accellog-demo", blueprint=bp) as rec:
        log_session(rec, S["calibration"], calibrations={"Model 3": res.fits["model3"].cal})
        for m, fo in res.fits.items():
            log_fit(rec, fo, m)
        log_evaluations(rec, res.evals)
        m3d = res.drift_evals[-1]
        rec.log_track("test/Model 3 + drift model", m3d.t_s, m3d.disp_drift_series_m)
        tbl, qtbl = drift_table(res.final_rows, res.evals[0].t_end_s, res.drift.drift)
        rec.log_document(
            "results/drift model", table_markdown(tbl) + "\n" + (table_markdown(qtbl) if qtbl else "")
        )
        for i, d in enumerate(diags):
            log_diagnosis(rec, d, obs, label=f"step {i + 1}")
        log_ladder(rec, res.ladder, obs)
        log_track_runs(rec, res.tracks, S["robot"].truth)


def _layout_data(res: DemoResult) -> DemoData:
    """The series the demo's views are framed on (the same arrays write_rrd logs)."""
    data = DemoData(n_diagnoses=len(res.diagnoses))
    cal = res.sessions.get("calibration")
    if cal is not None and cal.temp_degC is not None:
        data.calibration_temperature = [(cal.t_s, cal.temp_degC)]
    t_ref = None
    for ev in res.evals:
        if ev.t_s is not None and ev.disp_series_m is not None:
            data.static_tracks[ev.label] = (ev.t_s, ev.disp_series_m)
            t_ref = ev.t_s
    m3d = res.drift_evals[-1]
    data.static_tracks["Model 3 + drift model"] = (m3d.t_s, m3d.disp_drift_series_m)
    if t_ref is not None:
        data.static_tracks["truth (at rest)"] = (t_ref[[0, -1]], np.zeros((2, 3)))
    truth = res.sessions["robot"].truth
    if truth is not None:
        data.robot_tracks["truth"] = (truth.t_s, truth.position_m)
    for r in res.tracks:
        t, p = r.track.t_s, r.track.position_m
        data.robot_tracks[r.name] = (t, p)
        if truth is not None:
            ref = np.column_stack([np.interp(t, truth.t_s, truth.position_m[:, i]) for i in range(3)])
            data.robot_errors[r.name] = (t, np.linalg.norm(p - ref, axis=1))
    if res.workbench_obs is not None:
        t = np.asarray(res.workbench_obs.t_s, dtype=np.float64)
        last = len(res.ladder) - 1  # the steps log_ladder plots: the start model and the final one
        data.workbench_residuals = [
            (t, 1000.0 * np.asarray(r.residual_g))
            for i, r in enumerate(res.ladder)
            if r.residual_g is not None and (i == last or (not r.added and r.model not in BASE_STEPS))
        ]
        if res.workbench_obs.temp_degC is not None:
            data.workbench_driver = [(t, np.asarray(res.workbench_obs.temp_degC, dtype=np.float64))]
    return data
