"""accellog against the autocalibration peers (issue 44, item 7): actipy's calibrate_gravity (van Hees
et al. 2014, the GGIR method) on the same unlabelled runs, scored on held-out orientations and
temperatures against the truth.

Emulated runs (the real path: emulator -> driver -> recorder -> MCAP, pose labels removed), one chip
(MPU-9250 noise 300 ug/rtHz; bias +-60 mg, scale +-3 %, lower-triangular misalignment +-1 %, a linear
bias tempco +-1.5 mg/degC: every term an orientation-free fit can see, so the sensor frame is the
truth's frame):

- diverse: a carried device, 24 stops spread over the sphere (faces, edges, corners), 25 s each;
- few:     10 stops (faces and four corners), 25 s each;
- level:   a ground robot, 30 stops of 12 s parked on slopes tilted <= 15 deg (robot_path 'parked'), its
           biases aged 3-8 mg since a six-face lab calibration at 25 degC (the prior of the
           'accellog --prior LAB' rows);
each at 25 degC ("no") and warming 20 -> 36 degC ("warm-up"). Held out: 500 orientations uniform on
the sphere (diverse, few) or z-up within 15 deg (level: where the robot lives), at 25 degC or
uniform over 20-36 degC; |f| error = RMS(|f_corrected| - 1 g), vector error = RMS|f_corrected -
f_true| (mg); its own 1 sigma: the vector error a calibration expects of itself on those points, its
parameter covariance propagated through its correction (own_sigma_mg; accellog's and the lab's;
terms held at their nominal value, sigma 0 in the file, are not counted).

Real: imucal's hand-held Ferraris session (a real 16-bit IMU, six faces held 4-7 s each, rotations
between; `accellog import imucal`, labels removed): each method fitted to the whole recording's stops
if it accepts it, scored on the second half of each face (only |f|: the true directions are not
known; six stops leave no orientation to hold out); beside them accellog's labelled six-face fit
of the same recording as a reference (not an autocalibration).

Methods: accellog `fit RUN -o CAL` (orientation-free: stops detected; `--add temp_bias` on warm-ups;
`--prior LAB.json` where said); actipy `calibrate_gravity` with its defaults (10 s windows, >= 50
still windows, every axis past +-0.3 g, skipped when the initial error is < 10 mg) and with the
window limit lowered to 4 ("limit 4"); "none": the raw reading; level runs: the lab calibration alone. A method that refuses scores as
"none" and says why.

    python benchmarks/bench_peers.py [--write]

--write puts the table into benchmarks/RESULTS.md (between PEERS_START and PEERS_END; run_all.py
keeps it). Needs actipy (pip install -e '.[bench]').
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import os
import tempfile
import warnings
from pathlib import Path

import numpy as np
from run_all import PEERS_END, PEERS_START, write_section

from accellog.acquire.emulator.sensor_model import AccelErrors
from accellog.calibrate.calfile.calibration import load_calibration
from accellog.cli import main
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session
from accellog.store.writer import write_session

REPO = Path(__file__).resolve().parents[1]
DIVERSE = (
    "+z,-z,+x,-x,+y,-y,+x+y,-x-y,+x-y,-x+y,+x+z,-x-z,+x-z,-x+z,+y+z,-y-z,+y-z,-y+z,"
    "+x+y+z,-x-y+z,+x-y-z,-x+y-z,+x+y-z,-x-y-z"
)
FEW = "+z,-z,+x,-x,+y,-y,+x+y+z,-x-y+z,+x-y-z,-x+y-z"
WARM = {"kind": "warmup", "T_start": 20.0, "T_end": 36.0, "tau_s": 200.0}
CONST = {"kind": "constant", "T": 25.0}
AGED_G = (0.005, -0.008, 0.003)
N_HELD = 500


def chip(seed: int = 11) -> AccelErrors:
    """The emulated chip (module doc): lower-triangular misalignment, linear tempco, MPU noise."""
    rng = np.random.default_rng(seed)
    cross = np.zeros((3, 3))
    cross[np.tril_indices(3, -1)] = rng.uniform(-0.01, 0.01, 3)
    return AccelErrors(
        bias_g=rng.uniform(-1, 1, 3) * [0.06, 0.06, 0.08],
        scale=rng.uniform(-0.03, 0.03, 3),
        cross_axis=cross,
        temp_bias_g_per_degC=rng.uniform(-1.5e-3, 1.5e-3, 3),
        noise_density_g_per_rtHz=np.full(3, 300e-6),
    )


def overrides(e: AccelErrors) -> dict:
    """The scenario's [set] table for chip e (errors 'perfect' plus these)."""
    names = ("bias_g", "scale", "cross_axis", "temp_bias_g_per_degC", "noise_density_g_per_rtHz")
    return {k: np.asarray(getattr(e, k)).tolist() for k in names}


def record(path: Path, e: AccelErrors, temperature: dict, seed: int, **motion) -> Path:
    """An emulated session of chip e written without its pose labels (a run's log has none)."""
    sc = Scenario(**motion, sample_rate_hz=200.0, errors="perfect", set=overrides(e), seed=seed,
                  temperature=temperature)  # fmt: skip
    labelled = path.with_suffix(".labelled.mcap")
    simulate(sc, labelled, force=True)
    write_session(path, dataclasses.replace(read_session(labelled), poses=[]))
    labelled.unlink()
    return path


def held_out(where: str, warm: bool, seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """N_HELD held-out (up vectors (n,3), temperatures (n,) degC): module doc."""
    rng = np.random.default_rng(seed)
    if where == "sphere":
        ups = rng.standard_normal((N_HELD, 3))
        ups /= np.linalg.norm(ups, axis=1, keepdims=True)
    else:
        tilt, az = np.deg2rad(rng.uniform(0, 15, N_HELD)), rng.uniform(0, 2 * np.pi, N_HELD)
        ups = np.c_[np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)]
    temp = rng.uniform(20.0, 36.0, N_HELD) if warm else np.full(N_HELD, 25.0)
    return ups, temp


def quiet_main(args: list[str]) -> tuple[int, str]:
    """accellog's CLI in this process, its output kept: (exit code, last stderr line)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(args)
    lines = [x for x in err.getvalue().splitlines() if x.strip()]
    return rc, (lines[-1].removeprefix("accellog: error: ") if lines else "")


def accellog_fit(run: Path, cal: Path, warm: bool, prior: Path | None = None):
    """(status, correct(reading, T) or None, the Calibration or None) of `accellog fit RUN` (module doc)."""
    args = ["fit", str(run), "-o", str(cal), "--force"] + (["--add", "temp_bias"] if warm else [])
    rc, err = quiet_main(args + (["--prior", str(prior)] if prior else []))
    if rc != 0:  # the message's first clause, without the run's (temporary) path
        err = err.split(": ", 1)[-1] if err.startswith(str(run)) else err
        return f"refuses: {err.split(': ')[0].split(';')[0]}", None, None
    c = load_calibration(cal)
    held = [t for t in c.terms if not np.any(np.asarray(c.sigma)[c.model.slices[t]] > 0)]  # fixed: sigma 0
    status = (
        "fitted "
        + "+".join(t for t in c.terms if t not in held)
        + (f" ({'+'.join(held)} held)" if held else "")
    )
    weak = json.loads(cal.read_text())["fit"]["warnings"]
    weak = [w.split(": ")[1].split(" (")[0] for w in weak if w.startswith("weakly determined")]
    return (
        status + (f"; weakly determined: {weak[0]}" if weak else ""),
        lambda a, t: c.correct(a, {"temp_degC": t}),
        c,
    )


def own_sigma_mg(c, reading: np.ndarray, temp: np.ndarray) -> float:
    """The calibration's own 1 sigma of the vector error on the held-out points (mg):
    sqrt(mean_i tr(J_i C J_i^T)), J_i = d correct(reading_i, T_i) / d theta by central differences,
    C its parameter covariance (parameters held fixed, sigma 0, add nothing)."""
    th, cov = np.asarray(c.theta, float), np.asarray(c.cov, float)
    free = np.flatnonzero(np.diag(cov) > 0)
    drv = {"temp_degC": np.asarray(temp, float)}
    cols = []
    for k in free:
        h = 1e-3 * np.sqrt(cov[k, k])
        up, down = th.copy(), th.copy()
        up[k] += h
        down[k] -= h
        cols.append((c.model.correct(up, reading, drv) - c.model.correct(down, reading, drv)) / (2 * h))
    J = np.stack(cols, axis=-1)  # (n, 3, free)
    var = np.einsum("nap,pq,naq->n", J, cov[np.ix_(free, free)], J)
    return 1e3 * float(np.sqrt(np.mean(var)))


def actipy_fit(session, min_windows: int | None = None):
    """(status, correct(reading, T) or None) of actipy's calibrate_gravity on the session's samples."""
    import pandas as pd
    from actipy.processing import calibrate_gravity

    idx = pd.Timestamp("2026-01-01") + pd.to_timedelta(session.t_s, unit="s")
    df = pd.DataFrame(session.accel_g, columns=["x", "y", "z"], index=idx)
    warm = session.temp_degC is not None and np.ptp(session.temp_degC) > 1.0
    if warm:
        df["temperature"] = session.temp_degC
    kw = {} if min_windows is None else {"calib_min_samples": min_windows}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, info = calibrate_gravity(df, **kw)
    n = info.get("CalibNumSamples", 0)
    if not info.get("CalibOK"):
        lim = 50 if min_windows is None else min_windows
        why = f"{n} still 10-s windows < {lim}" if n < lim else "an axis not past +-0.3 g, or error >= 10 mg"
        return f"refuses: {why}", None, None
    if not info.get("CalibNumIters"):
        return f"skips: initial error {info['CalibErrorBefore(mg)']:.1f} mg < 10 mg", None, None
    b = np.array([info[f"Calib{a}Intercept"] for a in "xyz"])
    s = np.array([info[f"Calib{a}Slope"] for a in "xyz"])
    bt = np.array([info.get(f"Calib{a}SlopeT", 0.0) for a in "xyz"])
    return f"fitted ({n} windows)", lambda a, t: b + s * a + bt * np.asarray(t)[:, None], None


def score(correct, reading: np.ndarray, temp: np.ndarray, ups: np.ndarray | None):
    """(|f| error, vector error or nan) in mg of correct (None: the raw reading)."""
    f = reading if correct is None else correct(reading, temp)
    norm = 1e3 * float(np.sqrt(np.mean((np.linalg.norm(f, axis=1) - 1.0) ** 2)))
    vec = np.nan if ups is None else 1e3 * float(np.sqrt(np.mean(np.sum((f - ups) ** 2, axis=1))))
    return norm, vec


def methods(run: Path, d: Path, warm: bool, prior: Path | None, labelled: Path | None = None):
    """[(method, status, correct, Calibration or None)] for one run (labelled: the run with its
    labels, a reference fit)."""
    s = read_session(run)
    out = [("none", "-", None, None), ("accellog", *accellog_fit(run, d / "cal.json", warm))]
    if labelled is not None:
        out.append(("accellog, labelled (reference)", *accellog_fit(labelled, d / "cal_lab.json", warm)))
    if prior is not None:
        lab = load_calibration(prior)
        out.append(("lab calibration alone", "six faces at 25 degC", lambda a, t: lab.correct(a), lab))
        out.append(("accellog --prior LAB", *accellog_fit(run, d / "cal_prior.json", warm, prior)))
    out += [("actipy", *actipy_fit(s)), ("actipy (limit 4)", *actipy_fit(s, 4))]
    return out


def emulated_rows(d: Path) -> list[dict]:
    e = chip()
    aged = dataclasses.replace(e, bias_g=e.bias_g + np.array(AGED_G))
    lab = d / "lab.mcap"
    simulate(Scenario(protocol="six", hold_s=20.0, sample_rate_hz=200.0, errors="perfect", set=overrides(e),
                      temperature=CONST), lab, force=True)  # fmt: skip
    assert quiet_main(["fit", str(lab), "-o", str(d / "lab.json"), "--force"])[0] == 0
    rows = []
    for name, motion, truth, where in (
        ("diverse (24 stops)", {"protocol": DIVERSE, "hold_s": 25.0}, e, "sphere"),
        ("few (10 stops)", {"protocol": FEW, "hold_s": 25.0}, e, "sphere"),
        (
            "level (30 stops <= 15 deg)",
            {"motion": "robot", "robot_path": "parked", "hold_s": 12.0},
            aged,
            "z-up <= 15 deg",
        ),
    ):
        for warm in (False, True):
            run = record(d / "run.mcap", truth, WARM if warm else CONST, seed=21, **motion)
            ups, temp = held_out("sphere" if where == "sphere" else "robot", warm)
            reading = truth.apply(ups, temp, np.zeros(len(temp)))
            prior = d / "lab.json" if truth is aged else None
            for method, status, corr, cal in methods(run, d, warm, prior):
                norm, vec = score(corr, reading, temp, ups)
                own = np.nan if cal is None else own_sigma_mg(cal, reading, temp)
                rows.append({"run": name, "temperature": "warm-up 20-36" if warm else "25 degC",
                             "held_out": where, "method": method, "status": status, "norm_mg": norm,
                             "vector_mg": vec, "own_sigma_mg": own})  # fmt: skip
                print(
                    f"{name:28s} {rows[-1]['temperature']:14s} {method:22s} {norm:8.2f} {vec:8.2f} {own:8.3f}  {status}"
                )
    return rows


def real_rows(d: Path, data: Path) -> list[dict]:
    """imucal's hand-held session (module doc)."""
    labelled = d / "imucal.mcap"
    assert quiet_main(["import", "imucal", str(data / "example_ferraris_session.csv"), "-o", str(labelled),
                       "--force"])[0] == 0  # fmt: skip
    s = read_session(labelled)
    run = write_session(d / "imucal_run.mcap", dataclasses.replace(s, poses=[]))
    half = np.concatenate(
        [np.flatnonzero((s.t_s >= 0.5 * (p.start_s + p.end_s)) & (s.t_s < p.end_s)) for p in s.poses]
    )
    reading, temp = s.accel_g[half], np.full(half.size, 25.0)
    rows = []
    for method, status, corr, _ in methods(run, d, False, None, labelled):
        norm, vec = score(corr, reading, temp, None)
        rows.append({"run": "real: imucal hand-held (6 faces)", "temperature": "room", "held_out":
                     "2nd half of each face", "method": method, "status": status, "norm_mg": norm,
                     "vector_mg": vec, "own_sigma_mg": np.nan})  # fmt: skip
        print(f"{'imucal':28s} {'room':14s} {method:22s} {norm:8.2f} {'-':>8s}  {status}")
    return rows


def section(rows: list[dict], command: str) -> str:
    out = [PEERS_START, "## Peers: autocalibration from stops (benchmarks/bench_peers.py)", "",
           f"Generated by `{command}` (runs, held-out sets and methods: the script's doc). Errors in mg on "
           "the held-out set; a method that refuses or skips scores as the raw reading; its own 1σ: the "
           "vector error the calibration expects of itself there (its covariance propagated; terms held at "
           "their nominal value, σ 0 in the file, are not counted).", "",
           "| run | temperature | held out | method | \\|f\\| error (mg) | vector error (mg) | its own 1σ (mg) "
           "| status |",
           "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        vec = "-" if np.isnan(r["vector_mg"]) else f"{r['vector_mg']:.3g}"
        own = "-" if np.isnan(r["own_sigma_mg"]) or np.isnan(r["vector_mg"]) else f"{r['own_sigma_mg']:.3g}"
        status = r["status"].replace("|", "/")
        out.append(f"| {r['run']} | {r['temperature']} | {r['held_out']} | {r['method']} | {r['norm_mg']:.3g} "
                   f"| {vec} | {own} | {status} |")  # fmt: skip
    return "\n".join([*out, PEERS_END]) + "\n"


def run() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="write the table into benchmarks/RESULTS.md")
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "imucal",
                    help="folder of imucal's example_ferraris_session.csv")  # fmt: skip
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rows = emulated_rows(Path(tmp))
        if (a.data / "example_ferraris_session.csv").exists():
            rows += real_rows(Path(tmp), a.data)
    if a.write:
        write_section(section(rows, "python benchmarks/bench_peers.py --write"), PEERS_START, PEERS_END)
        print("wrote the peers section of benchmarks/RESULTS.md")


if __name__ == "__main__":
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    run()
