"""Make the README screenshots: `accellog demo`'s recording (one picture per tab) and the seed study,
opened in the web viewer in headless Chromium.

    python tools/screenshot.py [--tabs 0 2 3] [--out docs/images]

The seed-study picture is a real pipeline run on the capstone final trial (../shared/data): models 1-3 fitted on the
six-position table (residuals per pose), the drift model fitted on the 60 s static test, and the
test's displacement tracks of every calibration side by side (accellog.flows.replay.compare).

The README's pictures (docs/images/demo.png, workbench.png, robot.png: the demo's static-test,
workbench and robot tabs) come from here; each is re-saved with at most 256 colours to stay small.
Needs chromium (apt) and websockets (pip). --native uses `rerun --headless --screenshot-to` instead
(needs a Vulkan driver such as mesa-vulkan-drivers).
"""

from __future__ import annotations

import argparse
import io
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
os.environ.setdefault("RERUN_ANALYTICS", "0")

from accellog.flows.pipeline import run_drift, run_fit  # noqa: E402
from accellog.flows.replay import compare  # noqa: E402
from accellog.present.rrd.recording import RunRecording  # noqa: E402
from accellog.store.importers import import_capstone  # noqa: E402


def build_demo(data: Path, rrd: Path) -> None:
    """Seed study -> .rrd: residuals of models 1-3, parameter table, tracks with and without drift model."""
    ft = data / "capstone" / "final_trial"
    table, test = ft / "six_position_data.csv", ft / "six_position_test_data.csv"
    if not table.is_file():
        raise SystemExit(f"capstone data not found under {data} (use --data)")
    session = import_capstone(test)
    with RunRecording(f"save:{rrd}", recording_id="accellog-demo") as rec:
        res = _seed_study(rec, table, test, session)
    for t in res.tracks:
        print(f"{t.label:16s} final displacement {t.final_m.round(3).tolist()} m")


def _seed_study(rec: RunRecording, table: Path, test: Path, session):
    """Fits, drift model and compare() of the capstone final trial, logged to rec."""
    cals, labels = [], []
    rows = ["| model | chi2/dof | rms (mg) | b_x (g) | b_y (g) | b_z (g) |", "|---|---|---|---|---|---|"]
    for model in ("model1", "model2", "model3"):
        out = run_fit(table, model, gravity="seed", weighted=False, local_gravity_mps2=9.797)
        fit = out.fit
        rec.log_residuals(model, out.obs.pose_names, out.obs.meas_g, fit.predicted_g)
        idx = [fit.param_names.index(f"b_{a}") for a in "xyz"]
        b, sb = fit.theta[idx], fit.sigma[idx]
        rows.append(
            f"| {model} | {fit.chi2_dof:.3g} | {1000 * fit.rms_g:.2f} | "
            + " | ".join(f"{b[i]:+.5f} +- {sb[i]:.5f}" for i in range(3))
            + " |"
        )
        cals.append(out.cal)
        labels.append(model)
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "model3.json"
        cals[-1].save(p)
        drift = run_drift(test, p).cal
    cals.append(drift)
    labels.append("model3 + drift")
    rec.log_document(
        "calibration/seed final trial", "### Seed final trial, unweighted fits\n\n" + "\n".join(rows) + "\n"
    )
    return compare(session, cals, labels=labels, recording=rec, up_sensor="+z")


TAB_NAMES = {0: "demo", 1: "calibration", 2: "workbench", 3: "robot"}


def shoot(rrd: Path, png: Path, size: tuple[int, int], native: bool) -> None:
    if native:
        from accellog.present.viewer import free_port, rerun_binary, rerun_env

        cmd = [rerun_binary(), "--headless", "--bind", "127.0.0.1", "--port", str(free_port())]
        cmd += ["--window-size", f"{size[0]}x{size[1]}", "--screenshot-to", str(png), str(rrd)]
        subprocess.run(cmd, check=True, env=rerun_env(), timeout=120)
        return
    from accellog.present.viewer import screenshot_rrd

    stats = screenshot_rrd(rrd, png, size=size, wait_s=240.0)
    kb = shrink_png(png)
    print(f"{png}: {stats.colors} colours, {100 * stats.non_background:.0f}% drawn, {kb} KB")


def shrink_png(png: Path) -> int:
    """Re-save png with at most 256 colours (median cut, no dithering: flat UI colours and text stay
    sharp), atomically; returns its size in KB. A screenshot of 1400x900 goes from ~250 to ~100 KB."""
    from PIL import Image

    from accellog.store.atomic import write_bytes_atomic

    img = Image.open(png).convert("RGB")
    buf = io.BytesIO()
    img.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(
        buf, "PNG", optimize=True
    )
    if buf.tell() < png.stat().st_size:
        write_bytes_atomic(png, buf.getvalue())
    return png.stat().st_size // 1024


def main() -> None:
    ap = argparse.ArgumentParser(
        description="README screenshots: `accellog demo` recordings (one per tab) "
        "and the seed study (capstone data) in the web viewer, headless."
    )
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data")
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "images")
    ap.add_argument(
        "--tabs",
        type=int,
        nargs="*",
        default=[0, 2, 3],
        help="demo tabs (0 static test, 1 calibration, 2 workbench, 3 robot)",
    )
    ap.add_argument("--no-capstone", action="store_true", help="skip the seed-study picture")
    ap.add_argument("--size", default="1400x900")
    ap.add_argument("--native", action="store_true", help="native viewer with --screenshot-to (Vulkan)")
    a = ap.parse_args()
    w, h = (int(v) for v in a.size.split("x"))
    a.out.mkdir(parents=True, exist_ok=True)
    from rich.console import Console

    from accellog.flows.demo import run_demo, write_rrd

    with tempfile.TemporaryDirectory() as d:
        if a.tabs:  # one demo run; one recording per tab (they differ only in the tab shown first)
            res = run_demo(Path(d) / "demo", rrd=None, console=Console(file=io.StringIO()))
        for tab in a.tabs:
            rrd = Path(d) / f"demo_tab{tab}.rrd"
            write_rrd(res, rrd, first_tab=tab)
            shoot(rrd, a.out / f"{TAB_NAMES[tab]}.png", (w, h), a.native)
        if not a.no_capstone:
            rrd = Path(d) / "capstone.rrd"
            build_demo(a.data, rrd)
            shoot(rrd, a.out / "capstone.png", (w, h), a.native)


if __name__ == "__main__":
    main()
